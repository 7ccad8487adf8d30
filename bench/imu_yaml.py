"""imu.yaml against an independent Allan deviation (allantools) of long static bags.

Run: ``PYTHONPATH=. .venv/bin/python bench/imu_yaml.py [--seconds 3600] [--seed 7]``.

1. ``qfa-report imu-yaml config/qfa.yaml`` (Kalibr's definitions of the node's noise model)
   and ``qfa-sim static --duration SECONDS --seed SEED --out BAG`` (the node's noise and
   gyros, nominal unit, constant ambient): the Allan variance allantools measures on each
   axis of the bag over the one the figures predict, ``N^2 / tau + K^2 tau / 3``, and
   ``sigma(tau) sqrt(tau) / N``; then ``qfa-report imu-yaml BAG`` (allan_variance_ros's fit
   and the white density beside it) against the fit of the configuration's model curve
   over the same range, and against the configuration's figures.
2. The round trip: the Kalibr imu.yaml of ``test_imu_yaml`` through ``qfa-sim static
   --imu-yaml`` and ``qfa-report imu-yaml BAG``, the same comparisons.

Prints Markdown (the machine's load beside the wall time).
"""

import argparse
import math
import os
from pathlib import Path
import re
import subprocess
import sys
import tempfile
import time

import allantools
import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from qfa_ros.bag.imu_series import read_imu  # noqa: E402
from qfa_ros.cli.sim import static_sensor  # noqa: E402
from qfa_ros.model.noise_figures import (  # noqa: E402
    emulated_config,
    ImuNoiseFigures,
    KEYS,
    model_fit_figures,
)

TAUS = (0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
KALIBR_YAML = """\
accelerometer_noise_density: 2.0e-05
accelerometer_random_walk: 1.0e-04
gyroscope_noise_density: 1.0e-06
gyroscope_random_walk: 1.0e-06
"""


def run(*args):
    """Run a console entry point of the package; return its standard output."""
    return subprocess.run([sys.executable, '-c', 'import sys; from qfa_ros.cli.' + args[0]
                           + ' import main; sys.exit(main(sys.argv[1:]))', *args[1:]],
                          check=True, capture_output=True, text=True, cwd=ROOT).stdout


def parse(text):
    """Return (figures, {key: comment}) of an imu.yaml text."""
    comments = {line.split(':')[0]: line.split('#', 1)[1] for line in text.splitlines()
                if not line.startswith('#') and '#' in line}
    return yaml.safe_load(text), comments


def after(comment, pattern):
    """Return the number ``pattern`` (a regular expression with one group) finds."""
    return float(re.search(pattern, comment).group(1))


def allan_table(accel, rate, figures, duration):
    """Print, per tau, allantools' AVAR over the figures' prediction (mean of 3 axes)."""
    print('| tau s | accel AVAR meas / pred | accel sigma sqrt(tau) / N | gyro AVAR meas / '
          'pred | gyro sigma sqrt(tau) / N |')
    print('|---|---|---|---|---|')
    taus = np.array([t for t in TAUS if t <= duration / 10])
    rows = []
    for data, name in ((accel, 'accelerometer'), (rate, 'gyroscope')):
        white = figures[f'{name}_noise_density']
        walk = figures[f'{name}_random_walk']
        ratio, density = [], []
        for axis in range(3):
            used, adev, _, _ = allantools.oadev(data[:, axis], rate=1000.0, data_type='freq',
                                                taus=taus)
            ratio.append(adev ** 2 / (white ** 2 / used + walk ** 2 * used / 3))
            density.append(adev * np.sqrt(used) / white)
        rows.append((np.mean(ratio, axis=0), np.mean(density, axis=0)))
    for k, tau in enumerate(taus):
        print(f'| {tau:g} | {rows[0][0][k]:.3f} | {rows[0][1][k]:.3f} | {rows[1][0][k]:.3f} | '
              f'{rows[1][1][k]:.3f} |')


def fit_table(measured_text, figures, fit):
    """Print the bag's imu.yaml against the model's fit and the figures."""
    measured, comments = parse(measured_text)
    print('\n| figure | bag (allan_variance_ros fit, worst axis) | fit of the model curve | '
          'bag / model fit | 1-sigma bound | figure (Kalibr) | bag / figure |')
    print('|---|---|---|---|---|---|---|')
    for key in KEYS:
        bound = after(comments[key], r'relative uncertainty <= ([0-9.]+)')
        print(f'| `{key}` | {measured[key]:.4g} | {fit[key]:.4g} | '
              f'{measured[key] / fit[key]:.3f} | {bound:.2f} | {figures[key]:.4g} | '
              f'{measured[key] / figures[key]:.3f} |')
    for key in KEYS[::2]:
        if 'white noise at short tau' in comments[key]:
            white = after(comments[key], r'white noise at short tau \(.*\): ([0-9.e+-]+),')
            print(f"\n`{key}`: white noise at short tau in the bag's file {white:.4g}, "
                  f'the figure {figures[key]:.4g}: ratio {white / figures[key]:.3f}')


def case(title, bag, figures, fit, seconds):
    """Print one case: the Allan table and the fit table."""
    stamps, accel, rate = read_imu(bag)
    print(f'\n### {title}\n')
    allan_table(accel, rate, figures, seconds)
    fit_table(run('report', 'imu-yaml', str(bag)), figures, fit)


def main():
    """Simulate, measure, print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=3600.0)
    parser.add_argument('--seed', type=int, default=7)
    args = parser.parse_args()
    start = time.perf_counter()
    max_tau = min(1000.0, args.seconds / 10.0)
    config_text = run('report', 'imu-yaml', str(ROOT / 'config' / 'qfa.yaml'))
    figures, _ = parse(config_text)
    print(f'static bags of {args.seconds:g} s, seed {args.seed}; fits over 0.1..{max_tau:g} s; '
          f'load {os.getloadavg()[0]:.1f} at the start')
    print('\n```yaml\n' + config_text + '```')
    with tempfile.TemporaryDirectory() as directory:
        bag = Path(directory) / 'static.mcap'
        run('sim', 'static', '--duration', str(args.seconds), '--seed', str(args.seed),
            '--out', str(bag))
        config = static_sensor()[0]
        case("config/qfa.yaml against a static bag of the node's sensor", bag, figures,
             model_fit_figures(config, max_tau), args.seconds)
        source = Path(directory) / 'imu.yaml'
        source.write_text(KALIBR_YAML)
        bag = Path(directory) / 'round_trip.mcap'
        run('sim', 'static', '--duration', str(args.seconds), '--seed', str(args.seed),
            '--imu-yaml', str(source), '--out', str(bag))
        yaml_figures = yaml.safe_load(KALIBR_YAML)
        emulated = emulated_config(config, ImuNoiseFigures(**yaml_figures))
        case('round trip: a Kalibr imu.yaml through qfa-sim static --imu-yaml', bag,
             yaml_figures, model_fit_figures(emulated, max_tau), args.seconds)
    print(f'\nwall time {time.perf_counter() - start:.0f} s, load '
          f'{os.getloadavg()[0]:.1f} at the end')
    assert all(math.isfinite(v) for v in figures.values() if isinstance(v, float))


if __name__ == '__main__':
    main()
