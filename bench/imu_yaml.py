"""The imu.yaml of the node's configuration against one measured on a 1 h static bag.

Run: ``PYTHONPATH=. .venv/bin/python bench/imu_yaml.py [--seconds 3600] [--seed 7]``.

``qfa-sim static --duration SECONDS --seed SEED --out BAG`` (the node's noise and gyros,
nominal unit, constant ambient), then ``qfa-report imu-yaml BAG`` and ``qfa-report
imu-yaml config/qfa.yaml --max-tau`` the range the bag allows (a tenth of its length).
Prints Markdown: both figures, their ratio and the estimator's 1-sigma bound.
"""

import argparse
import math
from pathlib import Path
import subprocess
import sys
import tempfile

import yaml

ROOT = Path(__file__).resolve().parents[1]
KEYS = ('accelerometer_noise_density', 'accelerometer_random_walk',
        'gyroscope_noise_density', 'gyroscope_random_walk')


def run(*args):
    """Run a console entry point of the package; return its standard output."""
    return subprocess.run([sys.executable, '-c', 'import sys; from qfa_ros.cli.' + args[0]
                           + ' import main; sys.exit(main(sys.argv[1:]))', *args[1:]],
                          check=True, capture_output=True, text=True, cwd=ROOT).stdout


def main():
    """Simulate, measure, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=3600.0)
    parser.add_argument('--seed', type=int, default=7)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as directory:
        bag = Path(directory) / 'static.mcap'
        run('sim', 'static', '--duration', str(args.seconds), '--seed', str(args.seed),
            '--out', str(bag))
        measured_text = run('report', 'imu-yaml', str(bag))
    max_tau = min(1000.0, args.seconds / 10.0)
    implied_text = run('report', 'imu-yaml', str(ROOT / 'config' / 'qfa.yaml'), '--max-tau',
                       str(max_tau))
    measured, implied = yaml.safe_load(measured_text), yaml.safe_load(implied_text)
    print(f'static bag {args.seconds:g} s, seed {args.seed}; Allan deviation 0.1..{max_tau:g} s'
          '\n')
    print('| figure | config/qfa.yaml | bag (worst axis) | bag / config | 1-sigma bound |')
    print('|---|---|---|---|---|')
    for key in KEYS:
        bound = float(measured_text.split(f'# {key}: relative uncertainty <= ')[1].split()[0])
        ratio = measured[key] / implied[key]
        print(f'| `{key}` | {implied[key]:.4g} | {measured[key]:.4g} | {ratio:.3f} | '
              f'{bound:.2f} ({abs(math.log(ratio)) / bound:.1f} sigma) |')


if __name__ == '__main__':
    main()
