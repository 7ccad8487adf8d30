"""Navigation error of drawn units before and after self-calibration, by a strapdown INS.

Run: ``PYTHONPATH=. .venv/bin/python bench/nav_error.py [--units 20] [--first-seed 0]
[--jobs 2] [--minutes 60] [--figure docs/figures/nav_error.png] [--save DIR]``;
``--save DIR --tabulate`` tabulates the units an interrupted run saved.

Each unit is the drawn unit of its seed (``qfa_ros.model.drawn_unit``) with Ran et al.'s component
temperature coefficients (``sensor.error_profile: paper``) and the default gyros, in a
constant 25 degC ambient, its loops at 10 kHz, published at 100 Hz. In the factory it gets
``calibrate_temperature`` (the default chamber program: bias, scale factor,
misalignment and K2 compensated in fixed point) and ``capture_reference``. That triad is
copied (the same noise from there on) into four cases:

* ``drifted``: the feedback gain drifts by a draw uniform in +-1000 ppm per axis and the
  forward gain by +-500 ppm (the magnitudes of the node's services test), not corrected;
* ``self-calibrated``: the same drift, then ``self_calibrate`` at rest (the default
  schedules), then navigation;
* ``temperature, uncompensated``: no drift, the temperature compensation switched off,
  and the ambient ramps +10 degC over the hour from the start of navigation;
* ``temperature, compensated``: the same ramp with the factory compensation on.

Each case navigates the 10-minute vehicle drive (then at rest) and a static hour (level, x
north, 45 deg) with the tests' strapdown mechanization (``test/strapdown.py``, written
apart from the emulator), height held (a height aid: the free vertical channel diverges).
The INS is aligned as a real one is: roll and pitch by levelling on the first 15 s at rest
(the accelerometers' mean, which absorbs their constant horizontal bias into the tilt),
heading true (a perfect gyrocompass). Reported: the horizontal position error [m] after 10
and 60 minutes, mean and maximum over the units, and the height error of the same stream
navigated with a free vertical channel after 5 and 10 minutes (where the z axis's scale
factor acts on g). Prints Markdown; writes the figure.
"""

import argparse
from concurrent.futures import ProcessPoolExecutor
import copy
import math
from pathlib import Path
import sys

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))
import strapdown  # noqa: E402

from qfa_ros.calibration.estimation import capture_reference, self_calibrate  # noqa: E402
from qfa_ros.calibration.schedule import run_schedule  # noqa: E402
from qfa_ros.calibration.state import CalibrationState  # noqa: E402
from qfa_ros.calibration.temperature import temperature_calibration  # noqa: E402
from qfa_ros.model import motion_scripts as tr  # noqa: E402
from qfa_ros.model.drawn_unit import draw_unit  # noqa: E402
from qfa_ros.model.error_profiles import ErrorProfile  # noqa: E402
from qfa_ros.model.thermal import ThermalConfig  # noqa: E402
from qfa_ros.model.triad_config import TriadConfig  # noqa: E402

RATE_HZ = 100.0
LEVEL_S = 15.0
CASES = ('drifted', 'self-calibrated', 'temperature, uncompensated',
         'temperature, compensated')
MOTIONS = ('drive', 'static')
RAMP_C = 10.0
FEEDBACK_PPM, FORWARD_PPM = 1000.0, 500.0


def factory_unit(seed):
    """Return (triad, state) of the unit of ``seed`` after its factory calibration."""
    config = TriadConfig(sample_rate_hz=RATE_HZ,
                         thermal=ThermalConfig(ambient_profile='constant', ambient_c=25.0))
    rest = tr.static(45.0, yaw=math.pi / 2)
    triad = draw_unit(seed).triad(config, rng=seed, profile=rest)
    ErrorProfile().apply(triad)
    state = CalibrationState()
    run_schedule(triad, temperature_calibration(triad, state))
    run_schedule(triad, capture_reference(triad, state))
    return triad, state


def levelled_attitude(force, dcm):
    """Return ``dcm`` (body to ENU) tilted so that the mean specific force ``force`` is up."""
    up = dcm @ force
    up = up / np.linalg.norm(up)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sine = np.linalg.norm(axis)
    if sine < 1e-15:
        return dcm
    angle = math.atan2(sine, up[2])
    k = axis / sine
    skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    rotation = np.eye(3) + math.sin(angle) * skew + (1 - math.cos(angle)) * skew @ skew
    return rotation @ dcm


def navigate(triad, motion, minutes):
    """
    Move ``triad`` along ``motion`` for ``minutes``; return two errors per sample [m].

    The horizontal error with the height held, and the height error of the free vertical
    channel (no height aid; it diverges, so only its first minutes mean anything).
    """
    start = triad.time
    path = motion.shifted(start)
    triad.profile = path
    n = int(round(minutes * 60.0 * RATE_HZ))
    accel, rate = np.empty((n, 3)), np.empty((n, 3))
    done = 0
    for part in triad.run_chunks(n, int(60 * RATE_HZ)):
        k = len(part.accel)
        accel[done:done + k], rate[done:done + k] = part.accel, part.gyro
        done += k
    k0 = path.kinematics(np.array([start]))
    level = int(LEVEL_S * RATE_HZ)
    dcm = levelled_attitude(accel[:level].mean(axis=0), k0['dcm'][0])
    truth = path.kinematics(start + np.arange(1, n + 1) / RATE_HZ)
    errors = []
    for held in (True, False):
        positions, _, _ = strapdown.navigate(rate, accel, 1.0 / RATE_HZ, k0['latitude'][0],
                                             k0['longitude'][0], k0['height'][0],
                                             k0['velocity'][0], dcm, hold_height=held)
        errors.append(strapdown.position_error(positions, truth['latitude'],
                                               truth['longitude'], truth['height']))
    return np.hypot(errors[0][:, 0], errors[0][:, 1]), np.abs(errors[1][:, 2])


def run_unit(seed, minutes):
    """Return {(case, motion): horizontal error per minute (minutes,)} of one unit."""
    base, state = factory_unit(seed)
    rng = np.random.default_rng([0x6E6176, seed])
    feedback = rng.uniform(-FEEDBACK_PPM, FEEDBACK_PPM, 3)
    forward = rng.uniform(-FORWARD_PPM, FORWARD_PPM, 3)
    motions = {'drive': tr.vehicle_drive(), 'static': tr.static(45.0, yaw=math.pi / 2)}
    every = int(60 * RATE_HZ)
    results = {}
    for case in CASES:
        for name, motion in motions.items():
            triad = copy.deepcopy(base)
            case_state = copy.deepcopy(state)
            if case in ('drifted', 'self-calibrated'):
                for axis in range(3):
                    triad.drift.set_step(axis, 'k_vi', feedback[axis] * 1e-6)
                    triad.drift.set_step(axis, 'k_amp', forward[axis] * 1e-6)
                if case == 'self-calibrated':
                    run_schedule(triad, self_calibrate(triad, case_state))
            else:
                triad.temperature_compensation = case.endswith(', compensated')
                triad.thermal.set_ambient(ambient_profile='ramp', ambient_c=25.0,
                                          ramp_rate_c_per_s=RAMP_C / 3600.0,
                                          ramp_limits_c=(25.0, 25.0 + RAMP_C))
            horizontal, vertical = navigate(triad, motion, minutes)
            results[(case, name)] = horizontal[every - 1::every]
            results[(case, f'{name}, free height')] = vertical[every - 1::every]
    return results


def figure(minutes, table, path):
    """Draw the mean horizontal error per minute of every case and motion."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    t = np.arange(1, minutes + 1)
    for ax, motion in zip(axes, MOTIONS):
        for case in CASES:
            ax.semilogy(t, np.mean(table[(case, motion)], axis=0), label=case)
        ax.set_title(f'{"10-minute drive, then at rest" if motion == "drive" else "static"}')
        ax.set_xlabel('time [min]')
        ax.grid(True, which='both', alpha=0.3)
    axes[0].set_ylabel('mean horizontal position error [m]')
    axes[1].legend(fontsize=8)
    units = len(next(iter(table.values())))
    fig.suptitle(f'Strapdown INS on the emulated IMU: {units} drawn units, levelled, '
                 'height held')
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    """Run the units, print the table, draw the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--units', type=int, default=20)
    parser.add_argument('--first-seed', type=int, default=0)
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--minutes', type=int, default=60)
    parser.add_argument('--figure', default=str(ROOT / 'docs' / 'figures' / 'nav_error.png'))
    parser.add_argument('--save', metavar='DIR',
                        help='save the errors of each unit (unit_SEED.npz) as it finishes')
    parser.add_argument('--tabulate', action='store_true',
                        help='only tabulate the units saved in --save DIR')
    args = parser.parse_args()
    seeds = list(range(args.first_seed, args.first_seed + args.units))
    table = {}
    if args.tabulate:
        # The units a (possibly interrupted) run saved: only those are tabulated.
        files = sorted(Path(args.save).glob('unit_*.npz'))
        seeds = [int(f.stem.split('_')[1]) for f in files]
        for f in files:
            with np.load(f) as data:
                for key in data.files:
                    table.setdefault(tuple(key.split('|')), []).append(data[key])
    else:
        with ProcessPoolExecutor(args.jobs) as pool:
            for seed, result in zip(seeds, pool.map(run_unit, seeds,
                                                    [args.minutes] * len(seeds))):
                for key, value in result.items():
                    table.setdefault(key, []).append(value)
                if args.save:
                    Path(args.save).mkdir(parents=True, exist_ok=True)
                    np.savez(Path(args.save) / f'unit_{seed:04d}.npz',
                             **{'|'.join(key): value for key, value in result.items()})
                print(f'unit {seed} done', file=sys.stderr, flush=True)
    marks = [m for m in (10, 60) if m <= args.minutes]
    print(f'{len(seeds)} units (seeds {seeds[0]}..{seeds[-1]}), {args.minutes} min\n')
    header = ' | '.join(f'{m} min mean | {m} min max' for m in marks)
    print(f'| case | motion | {header} |')
    print('|---|---|' + '---|---|' * len(marks))
    for motion in MOTIONS:
        for case in CASES:
            errors = np.array(table[(case, motion)])
            cells = ' | '.join(f'{errors[:, m - 1].mean():.1f} | {errors[:, m - 1].max():.1f}'
                               for m in marks)
            print(f'| {case} | {motion} | {cells} |')
    if (CASES[0], 'drive, free height') in table and args.minutes >= 10:
        print('\nHeight error of the free vertical channel (no height aid) [m]\n')
        print('| case | drive 5 min mean | drive 10 min mean | static 5 min mean | '
              'static 10 min mean |')
        print('|---|---|---|---|---|')
        for case in CASES:
            cells = ' | '.join(
                f'{np.mean(table[(case, f"{motion}, free height")], axis=0)[m - 1]:.1f}'
                for motion in MOTIONS for m in (5, 10))
            print(f'| {case} | {cells} |')
    if args.figure:
        figure(args.minutes, table, args.figure)
        print(f'\nfigure: {args.figure}')


if __name__ == '__main__':
    main()
