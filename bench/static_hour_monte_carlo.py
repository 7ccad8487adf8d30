"""Check the noise band of the static-hour drift test by Monte Carlo.

Run: ``.venv/bin/python bench/static_hour_monte_carlo.py [--draws N]`` (from the
repository root). Each draw is one default gyro unit (``GyroConfig()``, its own seed)
at rest, level, x north at 45 deg for one hour at 10 Hz with ideal accelerometers, through
the independent strapdown mechanization of ``test/strapdown.py`` (height held). Prints,
at 20, 40 and 60 minutes, the ratio of the draws' standard deviation of the east and
north position and the psi angles to the standard deviation that ``test/ins_errors.py``
propagates from the configuration (1 within the sampling error ``1/sqrt(2 N)``). 150
draws take about two minutes.
"""

import argparse
import math
from pathlib import Path
import sys

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))
import ins_errors  # noqa: E402
import strapdown  # noqa: E402

from qfa_ros.model import trajectories as tr  # noqa: E402
from qfa_ros.model.gyro import GyroConfig, GyroTriad  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--draws', type=int, default=150)
    args = parser.parse_args()
    rate_hz, gyro = 10.0, GyroConfig()
    static = tr.static(45.0, yaw=math.pi / 2)
    k = static.kinematics(np.array([0.0]))
    dcm, rate_b, force_b = k['dcm'][0], k['angular_rate'][0], k['specific_force'][0]
    times = np.arange(60.0, 3600.0 + 1, 60.0)
    model = ins_errors.StaticErrorModel(
        k['latitude'][0], dcm, np.zeros(3), np.zeros(3),
        ins_errors.gyro_constant_variance(gyro, rate_b, force_b), gyro=gyro)
    _, std = model.propagate(times)
    n = int(3600 * rate_hz)
    index = (times * rate_hz).astype(int) - 1
    force, truth_dcm = np.tile(force_b, (n, 1)), np.tile(dcm, (n, 1, 1))
    at = np.full(n, 1.0)
    errors = []
    for seed in tqdm(range(args.draws), disable=not sys.stderr.isatty()):
        rate, _ = GyroTriad(gyro, rate_hz, np.random.default_rng(1000 + seed)).run(
            np.tile(rate_b, (n, 1)), force, np.full(n, gyro.reference_c))
        positions, dcms, _ = strapdown.navigate(
            rate, force, 1.0 / rate_hz, k['latitude'][0], k['longitude'][0], k['height'][0],
            k['velocity'][0], dcm, hold_height=True)
        position = strapdown.position_error(positions, at * k['latitude'][0],
                                            at * k['longitude'][0], at * k['height'][0])
        attitude = strapdown.attitude_error(dcms, truth_dcm)
        errors.append(np.column_stack([position[index, :2], -attitude[index] @ dcm.T]))
    ratio = np.array(errors).std(axis=0) / std
    print(f'| minute | east | north | psi_E | psi_N | psi_U |  ({args.draws} draws, '
          f'sampling error {1 / math.sqrt(2 * args.draws):.2f})')
    print('|---|---|---|---|---|---|')
    for minute in (20, 40, 60):
        values = ' | '.join(f'{v:.3f}' for v in ratio[minute - 1])
        print(f'| {minute} | {values} |')


if __name__ == '__main__':
    main()
