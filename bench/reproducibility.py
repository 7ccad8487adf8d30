"""Measure the reproducibility contract's tolerances on this machine.

Run: ``.venv/bin/python bench/reproducibility.py [--bags static_10s.mcap ...]`` (``make
reproducibility``). Regenerates the example bags with their ``make bags`` commands, each
in a subprocess under several dispatches -- native, numpy without its AVX2 loops, other
OpenBLAS kernels, numba compiled for a generic x86-64, all three at once -- and the
native run twice. Checks that the two native runs are byte-identical, then compares every
run with the committed bag and with the native run under ``test/bag_helpers.py``
(structure exactly) and prints, per comparison, the worst float difference of each kind
in the unit of its tolerance, and the tolerances in force. Prints Markdown
(bench/results/reproducibility.md).
"""

import argparse
import hashlib
import os
from pathlib import Path
import platform
import subprocess
import sys
import tempfile
import time

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / 'test'))

from bag_helpers import (  # noqa: E402
    BAGS,
    compare_bags,
    make_bags_commands,
    OTHER_DISPATCH,
    TOLERANCES,
)

DISPATCHES = {
    'native': {},
    'native again': {},
    'numpy X86_V3 off': {'NPY_DISABLE_CPU_FEATURES': 'X86_V3'},
    'OpenBLAS Sandybridge': {'OPENBLAS_CORETYPE': 'Sandybridge'},
    'OpenBLAS Prescott': {'OPENBLAS_CORETYPE': 'Prescott'},
    'numba generic': {'NUMBA_CPU_NAME': 'generic'},
    'all three (OTHER_DISPATCH)': OTHER_DISPATCH,
}
KINDS = ('raw', 'estimate', 'derived')
UNITS = {'raw': 'abs', 'estimate': 'x SE', 'derived': 'rel'}


def generate(name, env_overrides, directory):
    """Write bag ``name`` with its ``make bags`` command under ``env_overrides``."""
    directory.mkdir(parents=True, exist_ok=True)
    out = directory / name
    env = {**os.environ, **env_overrides}
    command = [sys.executable, '-m', 'qfa_ros.cli.sim', *make_bags_commands()[name],
               '--out', str(out)]
    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL, cwd=REPO)
    return out


def worst(differences):
    """Return ``{kind: (count, worst scaled difference, where)}``."""
    result = {}
    for kind in KINDS:
        chosen = [d for d in differences if d.kind == kind]
        if chosen:
            top = max(chosen, key=lambda d: d.scaled)
            result[kind] = (len(chosen), top.scaled, top.where)
    return result


def cpu_model():
    """Return the CPU model name and whether it has AVX2, FMA and AVX-512F (Linux)."""
    try:
        text = Path('/proc/cpuinfo').read_text()
    except OSError:
        return platform.processor() or '?'
    model = next((line.split(':', 1)[1].strip() for line in text.splitlines()
                  if line.startswith('model name')), '?')
    flags = next((line.split(':', 1)[1].split() for line in text.splitlines()
                  if line.startswith('flags')), [])
    present = [name for name in ('avx2', 'fma', 'avx512f') if name in flags]
    return f'{model} ({", ".join(present) or "no AVX2"})'


def sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cell(summary, kind):
    if kind not in summary:
        return '0'
    count, value, _ = summary[kind]
    return f'{value:.3g} ({count})'


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bags', nargs='+', default=sorted(make_bags_commands()))
    args = parser.parse_args()
    print(f'Machine: {platform.machine()}, {cpu_model()}; '
          f'{os.cpu_count()} cores. Cells: worst difference in the unit of its tolerance '
          f'(number of differing floats); tolerances: raw {TOLERANCES["raw"]:g} abs, '
          f'estimate {TOLERANCES["estimate"]:g} x SE, derived {TOLERANCES["derived"]:g} rel.'
          '\n')
    header = ['bag', 'dispatch', 'compared with', 'bytes'] + [
        f'{kind} ({UNITS[kind]})' for kind in KINDS] + ['s']
    print('| ' + ' | '.join(header) + ' |')
    print('|' + '---|' * len(header))
    overall = dict.fromkeys(KINDS, (0.0, ''))
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.bags:
            runs = {}
            for label, env in DISPATCHES.items():
                started = time.perf_counter()
                runs[label] = generate(name, env, Path(scratch) / label.replace(' ', '_'))
                seconds = time.perf_counter() - started
                for reference, path in (('committed', BAGS / name), ('native', runs['native'])):
                    if label == 'native' and reference == 'native':
                        continue
                    same = sha256(runs[label]) == sha256(path)
                    summary = worst(compare_bags(runs[label], path))
                    for kind, (_, value, where) in summary.items():
                        if value > overall[kind][0]:
                            overall[kind] = (value, f'{name} {label} vs {reference}: {where}')
                    row = [name, label, reference, 'identical' if same else 'differ'] + [
                        cell(summary, kind) for kind in KINDS] + [f'{seconds:.0f}']
                    print('| ' + ' | '.join(row) + ' |', flush=True)
    print('\nWorst differences:')
    for kind in KINDS:
        value, where = overall[kind]
        print(f'- {kind}: {value:.3g} {UNITS[kind]} (tolerance {TOLERANCES[kind]:g}) {where}')
    beyond = [kind for kind in KINDS if overall[kind][0] > TOLERANCES[kind]]
    return 1 if beyond else 0


if __name__ == '__main__':
    sys.exit(main())
