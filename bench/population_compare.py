"""
Compare the same units of two temperature studies (e.g. the reduced loop against full rate).

Reads two fleet results (a Parquet file or an ``OUT.parquet.parts`` directory of finished
batches), matches units by ``unit_seed`` and prints, per unit and axis, the worst
zero-drift p2p and the scale-factor max |error| of both, and the largest differences::

    python bench/population_compare.py REDUCED.parquet FULL.parquet.parts
"""

import argparse
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

AXES = 'xyz'


def read(path):
    """Return the rows (dicts) of a results file or a parts directory, by unit seed."""
    path = Path(path)
    if path.is_dir():
        table = pa.concat_tables(pq.read_table(p) for p in sorted(path.glob('batch-*.parquet')))
    else:
        table = pq.read_table(path)
    return {row['unit_seed']: row for row in table.to_pylist()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('first')
    parser.add_argument('second')
    args = parser.parse_args()
    first, second = read(args.first), read(args.second)
    common = [seed for seed in second if seed in first]
    print(f'{len(common)} common units; first: {args.first}, second: {args.second}\n')
    print('| unit seed | zero drift worst x/y/z [ug] first | second | SF max x/y/z [ppm] '
          'first | second |')
    print('|---|---|---|---|---|')
    zd_diff, sf_diff = [], []
    for seed in common:
        a, b = first[seed], second[seed]
        zd = [[r[f'zd_max_ug_{x}'] for x in AXES] for r in (a, b)]
        sf = [[r[f'sf_max_ppm_{x}'] for x in AXES] for r in (a, b)]
        zd_diff += list(np.subtract(*zd))
        sf_diff += list(np.subtract(*sf))
        cells = [' / '.join(f'{v:.1f}' for v in values) for values in (*zd, *sf)]
        print(f'| {seed} | ' + ' | '.join(cells) + ' |')
    if common:
        print(f'\nfirst - second: zero drift mean {np.mean(zd_diff):+.1f} ug, largest '
              f'|difference| {np.max(np.abs(zd_diff)):.1f} ug; scale factor mean '
              f'{np.mean(sf_diff):+.1f} ppm, largest |difference| '
              f'{np.max(np.abs(sf_diff)):.1f} ppm')


if __name__ == '__main__':
    main()
