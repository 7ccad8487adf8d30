"""Offline simulator: ``qfa-sim SCENARIO [--duration S] [--seed N]`` (no ROS, no DDS)."""

import argparse
import sys
import time

import numpy as np

from qfa_ros.allan import allan_deviation
from qfa_ros.design import LinearLoop
from qfa_ros.model import AXES, QfaTriad, TriadConfig
from qfa_ros.noise import MICRO_G

CHUNK_SECONDS = 1.0


def run_static(args, out=sys.stdout):
    """Run a level, static sensor for ``args.duration`` seconds and summarize it."""
    config = TriadConfig()
    triad = QfaTriad(config, rng=args.seed)
    chunk = int(round(CHUNK_SECONDS * config.sample_rate_hz))
    total = int(round(args.duration * config.sample_rate_hz))
    accel = np.empty((total, 3))
    truth = np.empty((total, 3))
    saturated = np.zeros(3, dtype=np.int64)
    done = 0
    while done < total:
        part = triad.run(min(chunk, total - done))
        n = len(part.stamps_ns)
        accel[done:done + n] = part.accel
        truth[done:done + n] = part.truth
        saturated += part.saturated.sum(axis=0)
        done += n
    print_summary(triad, accel, truth, saturated, out)
    return 0


def print_summary(triad, accel, truth, saturated, out):
    """Print per-axis mean, error vs truth, std, Allan deviation and saturation counts."""
    config = triad.config
    loop = triad.axes[0]
    crossover, phase_margin, gain_margin, bandwidth = LinearLoop(
        config.hardware, loop.controller, config.loop_rate_hz).margins()
    duration = len(accel) / config.sample_rate_hz
    print(f'qfa-sim: {duration:g} s of sensor time at {config.sample_rate_hz:g} Hz '
          f'(loop {config.loop_rate_hz:g} Hz)', file=out)
    print(f'loop: k(D(z)) = {loop.controller.gain:.4f}, crossover {crossover:.0f} Hz, '
          f'phase margin {phase_margin:.1f} deg, gain margin {gain_margin:.1f} dB, '
          f'bandwidth {bandwidth:.0f} Hz', file=out)
    header = (f'{"axis":>4} {"mean m/s^2":>14} {"error ug":>10} {"std ug":>9} '
              f'{"ADEV(1s) ug":>12} {"ADEV min ug":>12} {"at tau s":>9} {"saturated":>9}')
    print(header, file=out)
    for i, name in enumerate(AXES):
        mean = accel[:, i].mean()
        error = (mean - truth[:, i].mean()) / MICRO_G
        std = accel[:, i].std() / MICRO_G
        if len(accel) >= 30:
            taus, adev = allan_deviation(accel[:, i], triad.sample_period)
            at_one = np.interp(1.0, taus, adev) / MICRO_G if taus[-1] >= 1.0 else float('nan')
            k = int(np.argmin(adev))
            minimum, tau_min = adev[k] / MICRO_G, taus[k]
        else:
            at_one = minimum = tau_min = float('nan')
        print(f'{name:>4} {mean:14.8f} {error:10.2f} {std:9.2f} {at_one:12.3f} '
              f'{minimum:12.3f} {tau_min:9.3g} {int(saturated[i]):9d}', file=out)


SCENARIOS = {
    'static': run_static,
}


def build_parser():
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='qfa-sim', description='Run the QFA triad model offline, as fast as it can.')
    parser.add_argument('scenario', choices=sorted(SCENARIOS), help='what to simulate')
    parser.add_argument('--duration', type=float, default=60.0,
                        help='sensor time to simulate [s] (default 60)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    return parser


def main(argv=None):
    """Run the simulator command line."""
    args = build_parser().parse_args(argv)
    if not args.duration > 0:
        print('qfa-sim: --duration must be positive', file=sys.stderr)
        return 2
    start = time.perf_counter()
    status = SCENARIOS[args.scenario](args)
    print(f'wall time {time.perf_counter() - start:.2f} s', file=sys.stdout)
    return status


if __name__ == '__main__':
    sys.exit(main())
