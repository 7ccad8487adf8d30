"""
``qfa-report imu-yaml CONFIG|BAG [--out imu.yaml] [--max-tau S] [--topic T]``: noise figures.

Writes an ``imu.yaml`` in the conventions of Kalibr, OpenVINS and allan_variance_ros
(``accelerometer_noise_density`` [m/s^2/sqrt(Hz)], ``accelerometer_random_walk``
[m/s^3/sqrt(Hz)], ``gyroscope_noise_density`` [rad/s/sqrt(Hz)], ``gyroscope_random_walk``
[rad/s^2/sqrt(Hz)], ``update_rate`` [Hz], ``rostopic``), each line commented:

* from a node parameter file: Kalibr's definitions, exactly, from the noise model the
  parameters configure (with ``noise.imu_yaml``: the emulated file's);
* from a recorded static bag: allan_variance_ros's fit of the stream's Allan deviation,
  with the white-noise density at short tau beside it where the two differ.

``docs/ins.md`` and :mod:`qfa_ros.model.noise_figures` give the definitions.
"""

import argparse
import math
from pathlib import Path
import sys

import numpy as np
import yaml

from qfa_ros.calibration.kalibr_yaml import imu_yaml_text
from qfa_ros.model import noise_figures
from qfa_ros.model.noise_figures import drive_density, KEYS, MAX_TAU, SHORT_TAUS

TOPIC = '/imu/data_raw'
MAX_CONFIG_BYTES = 1 << 20
"""Largest node parameter file read [bytes] (``config/qfa.yaml`` is 30 KiB)."""


def _span(times):
    return f'T {min(times):g}..{max(times):g} s'


def config_figures(path):
    """Return (figures, comments, header) of a node parameter file (``config/qfa.yaml`` form).

    The figures are those of :func:`qfa_ros.model.noise_figures.config_figures`; a
    ``noise.imu_yaml`` the file names is read (relative to the working directory, as the
    node reads it) and emulated.
    """
    from qfa_ros.model.safe_files import read_regular_file
    from qfa_ros.ros.model_settings import load_imu_noise, triad_config
    from qfa_ros.ros.parameter_table import PARAMETERS
    try:
        document = yaml.safe_load(read_regular_file(path, MAX_CONFIG_BYTES)) or {}
    except (yaml.YAMLError, RecursionError):
        # PyYAML's messages quote the offending line.
        raise ValueError(f'{path}: not a YAML document') from None
    values = {spec.name: spec.default for spec in PARAMETERS}
    for section in (document.values() if isinstance(document, dict) else ()):
        if isinstance(section, dict):
            parameters = section.get('ros__parameters', {}) or {}
            if not isinstance(parameters, dict):
                raise ValueError(f'{path}: ros__parameters must be a mapping of parameters, '
                                 f'got {type(parameters).__name__}')
            values.update(parameters)
    emulated = load_imu_noise(values)
    config = triad_config(values, imu_noise=emulated)
    figures = noise_figures.config_figures(config).as_dict()
    noise, gyro = config.noise, config.gyro
    floor = noise_figures.loop_white_floor(config)
    comments = {'update_rate': 'sample_rate_hz of imu/data_raw',
                'rostopic': "the node's topic (under its namespace)"}
    if emulated is not None:
        source = f'noise.imu_yaml {values["noise.imu_yaml"]}'
        comments.update(dict.fromkeys(KEYS, f'emulated: {source}'))
    else:
        white = 'white noise of the published stream (sigma(tau) sqrt(tau) of its Allan ' \
            'deviation at short tau)'
        comments['accelerometer_noise_density'] = (
            f'{white}: the injected VRW {noise.noise_density:.4g}'
            + (f' and the ADC noise through the loop {floor:.2g}, in quadrature' if floor
               else '') if figures['accelerometer_noise_density'] else 'no white noise')
        comments['accelerometer_random_walk'] = _walk_comment(
            noise.random_walk, noise.bias_instability, noise.correlation_times, 'bias')
        if gyro is not None:
            comments['gyroscope_noise_density'] = 'angle random walk (white rate noise)' \
                if gyro.arw else 'no white noise'
            comments['gyroscope_random_walk'] = _walk_comment(
                gyro.rate_random_walk, gyro.bias_instability, gyro.correlation_times, 'rate')
    if gyro is None:
        comments['gyroscope_noise_density'] = comments['gyroscope_random_walk'] = \
            'no gyros (gyro.enabled false)'
    figures['update_rate'] = float(config.sample_rate_hz)
    figures['rostopic'] = TOPIC
    header = [f'from the noise model of {path} (sensor.error_profile '
              f'{values["sensor.error_profile"]}): Kalibr\'s definitions, exact (docs/ins.md); '
              'no fit, no tau range']
    return figures, comments, header


def _walk_comment(walk, bias_instability, correlation_times, kind):
    """Return what a configuration's random-walk figure is made of."""
    parts = []
    if walk:
        parts.append(f'{kind} random walk {walk:.4g}')
    if bias_instability:
        drive = drive_density(bias_instability, correlation_times)
        parts.append(f'driving density {drive:.4g} of the bias-instability Gauss-Markov '
                     f'processes ({_span(correlation_times)}), sqrt(sum 2 q^2/T): their '
                     f'random walk over windows << {min(correlation_times):g} s, an upper '
                     'bound beyond')
    return ('bias random walk: ' + ' with the '.join(parts)) if parts \
        else 'no bias process'


def bag_figures(path, topic=TOPIC, max_tau=MAX_TAU):
    """Return (figures, comments, header) measured on the Imu stream of a static bag."""
    from qfa_ros.bag.imu_series import read_imu
    stamps, accel, rate = read_imu(path, topic)
    if len(stamps) < 1000:
        raise ValueError(f'{path}: {len(stamps)} samples on {topic}; a static record of '
                         'minutes is needed')
    period = float(np.median(np.diff(stamps))) / 1e9
    if np.all(np.isnan(rate)) or not np.any(rate):
        rate = None
    measured = noise_figures.measured_figures(accel, rate, period, max_tau)
    figures = dict(measured.fit)
    comments = {}
    for key, value in measured.fit.items():
        bound = measured.fit_uncertainty[key]
        if key.endswith('noise_density'):
            line = (f'allan_variance_ros fit: slope -1/2 line through tau < 10 s read at 1 s, '
                    f'worst axis, relative uncertainty <= {bound:.2f} (1 sigma)')
            white, white_bound = measured.white[key], measured.white_uncertainty[key]
            if white > 0 and abs(math.log(value / white)) > 3 * math.hypot(bound,
                                                                           white_bound):
                line += (f'; white noise at short tau ({SHORT_TAUS[0]:g}..{SHORT_TAUS[1]:g} '
                         f's, sigma(tau) sqrt(tau)): {white:.4g}, relative uncertainty <= '
                         f'{white_bound:.3f}')
        else:
            line = (f'allan_variance_ros fit: slope +1/2 line through 0.1..'
                    f'{measured.max_tau:g} s read at 3 s, worst axis, relative uncertainty '
                    f'<= {bound:.2f} (1 sigma); depends on the tau range')
        comments[key] = line
    figures['update_rate'] = round(1.0 / period, 6)
    figures['rostopic'] = topic
    comments['update_rate'] = 'median sample interval of the bag'
    header = [f'measured on {topic} of {path}: {len(stamps)} samples, '
              f"{len(stamps) * period:.0f} s; allan_variance_ros's fit (scripts/analysis.py) "
              f'of the Allan deviation 0.1..{measured.max_tau:g} s']
    return figures, comments, header


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
    parser.add_argument('--max-tau', type=float, default=None,
                        help='a bag: longest averaging time of the fits [s] (default 1000, '
                             'as allan_variance_ros; at most a tenth of the bag)')
    args = parser.parse_args(argv)
    source = Path(args.source)
    if not source.exists():
        print(f'qfa-report: no such file: {source}', file=sys.stderr)
        return 1
    try:
        if source.suffix == '.mcap':
            figures, comments, header = bag_figures(
                source, args.topic, MAX_TAU if args.max_tau is None else args.max_tau)
        elif args.max_tau is not None:
            print("qfa-report: --max-tau applies to a bag: a configuration's figures are "
                  "its model's, read off no fit range", file=sys.stderr)
            return 1
        else:
            figures, comments, header = config_figures(source)
    except (OSError, ValueError, yaml.YAMLError) as error:
        print(f'qfa-report: {error}', file=sys.stderr)
        return 1
    text = imu_yaml_text(figures, comments, header)
    if args.out:
        try:
            Path(args.out).write_text(text)
        except OSError as error:
            print(f'qfa-report: --out {args.out}: {error.strerror or error}', file=sys.stderr)
            return 1
        print(args.out)
    else:
        print(text, end='')
    return 0
