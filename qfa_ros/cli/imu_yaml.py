"""
``qfa-report imu-yaml CONFIG|BAG [--out imu.yaml] [--max-tau S]``: noise figures for VIO/INS.

Writes an ``imu.yaml`` in the conventions of Kalibr, OpenVINS and allan_variance_ros
(``accelerometer_noise_density`` [m/s^2/sqrt(Hz)], ``accelerometer_random_walk``
[m/s^3/sqrt(Hz)], ``gyroscope_noise_density`` [rad/s/sqrt(Hz)], ``gyroscope_random_walk``
[rad/s^2/sqrt(Hz)], ``update_rate`` [Hz], ``rostopic``) from a node parameter file (what
its noise model implies) or from a recorded static bag (what the stream measures), both
read off the Allan deviation as allan_variance_ros does
(:mod:`qfa_ros.model.imu_noise`; ``docs/ins.md``).
"""

import argparse
from pathlib import Path
import sys

import numpy as np
import yaml

from qfa_ros.model.imu_noise import implied_figures, MAX_TAU, measured_figures

TOPIC = '/imu/data_raw'
KEYS = ('accelerometer_noise_density', 'accelerometer_random_walk',
        'gyroscope_noise_density', 'gyroscope_random_walk')


def config_figures(path, max_tau=MAX_TAU):
    """Return (figures, comment lines) of a node parameter file (``config/qfa.yaml`` form)."""
    from qfa_ros.ros.params import PARAMETERS, triad_config
    document = yaml.safe_load(Path(path).read_text()) or {}
    values = {spec.name: spec.default for spec in PARAMETERS}
    for section in document.values():
        if isinstance(section, dict):
            values.update(section.get('ros__parameters', {}) or {})
    config = triad_config(values)
    figures = implied_figures(config, max_tau)
    figures['update_rate'] = float(config.sample_rate_hz)
    figures['rostopic'] = TOPIC
    return figures, [f'from the noise model of {path} (sensor.error_profile '
                     f'{values["sensor.error_profile"]}), read off its Allan deviation '
                     f'0.1..{max_tau:g} s as allan_variance_ros does']


def bag_figures(path, topic=TOPIC, max_tau=MAX_TAU):
    """Return (figures, comment lines) measured on the Imu stream of a static bag."""
    from qfa_ros.bag.imu_series import read_imu
    stamps, accel, rate = read_imu(path, topic)
    if len(stamps) < 1000:
        raise ValueError(f'{path}: {len(stamps)} samples on {topic}; a static record of '
                         'minutes is needed')
    period = float(np.median(np.diff(stamps))) / 1e9
    if np.all(np.isnan(rate)) or not np.any(rate):
        rate = None
    figures, uncertainty, used = measured_figures(accel, rate, period, max_tau)
    figures['update_rate'] = round(1.0 / period, 6)
    figures['rostopic'] = topic
    lines = [f'measured on {topic} of {path}: {len(stamps)} samples, '
             f'{len(stamps) * period:.0f} s; Allan deviation 0.1..{used:g} s, worst axis']
    lines += [f'{key}: relative uncertainty <= {value:.2f} (1 sigma)'
              for key, value in uncertainty.items()]
    return figures, lines


def imu_yaml_text(figures, comments):
    """Return the ``imu.yaml`` text of ``figures`` with ``comments`` on top."""
    lines = ['# imu.yaml (Kalibr / OpenVINS / allan_variance_ros conventions), qfa-report '
             'imu-yaml']
    lines += [f'# {line}' for line in comments]
    for key in KEYS + ('update_rate', 'rostopic'):
        if key in figures:
            value = figures[key]
            lines.append(f"{key}: '{value}'" if isinstance(value, str)
                         else f'{key}: {float(value)!r}')
    return '\n'.join(lines) + '\n'


def main(argv=None):
    """Run ``qfa-report imu-yaml``; return the exit status."""
    parser = argparse.ArgumentParser(
        prog='qfa-report imu-yaml',
        description='Write an imu.yaml (Kalibr/OpenVINS/allan_variance_ros noise figures) '
                    'from a node parameter file or a recorded static bag.')
    parser.add_argument('source', metavar='CONFIG|BAG',
                        help='node parameter YAML (e.g. config/qfa.yaml) or a static .mcap')
    parser.add_argument('--out', metavar='FILE', help='write here (default: print)')
    parser.add_argument('--topic', default=TOPIC, help=f'Imu topic of a bag (default {TOPIC})')
    parser.add_argument('--max-tau', type=float, default=MAX_TAU,
                        help='longest averaging time of the fits [s] (default 1000, as '
                             'allan_variance_ros; a bag uses at most a tenth of its length)')
    args = parser.parse_args(argv)
    source = Path(args.source)
    if not source.exists():
        print(f'qfa-report: no such file: {source}', file=sys.stderr)
        return 1
    try:
        if source.suffix == '.mcap':
            figures, comments = bag_figures(source, args.topic, args.max_tau)
        else:
            figures, comments = config_figures(source, args.max_tau)
    except (OSError, ValueError, yaml.YAMLError) as error:
        print(f'qfa-report: {error}', file=sys.stderr)
        return 1
    text = imu_yaml_text(figures, comments)
    if args.out:
        Path(args.out).write_text(text)
        print(args.out)
    else:
        print(text, end='')
    return 0
