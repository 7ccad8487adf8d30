"""Offline simulator: ``qfa-sim SCENARIO [--duration S] [--seed N] [--out FILE.mcap]``.

Runs without ROS or DDS, as fast as it can.
"""

import argparse
import contextlib
import sys
import time

import numpy as np
from tqdm import tqdm

from qfa_ros.bag.scenario_bag import ScenarioBag
from qfa_ros.calibration.experiments import format_paper_tables, paper_experiment
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import (
    temperature_schedule,
    TemperatureSettings,
)
from qfa_ros.calibration.verification import verify_cycle
from qfa_ros.model.allan import allan_deviation
from qfa_ros.model.design import LinearLoop
from qfa_ros.model.noise import MICRO_G
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES, QfaTriad, TriadConfig
from qfa_ros.model.unit import draw_unit

CHUNK_SECONDS = 1.0


def scenario_bag(args, config):
    """Return a :class:`ScenarioBag` for ``--out``, or a null context without it."""
    if args.out is None:
        return contextlib.nullcontext()
    return ScenarioBag(args.out, config.noise, config.sample_rate_hz)


def run_static(args, out=None):
    """Run a level, static sensor for ``args.duration`` seconds and summarize it."""
    out = out or sys.stdout
    config = TriadConfig()
    triad = QfaTriad(config, rng=args.seed)
    chunk = int(round(CHUNK_SECONDS * config.sample_rate_hz))
    total = int(round(args.duration * config.sample_rate_hz))
    accel = np.empty((total, 3))
    truth = np.empty((total, 3))
    saturated = np.zeros(3, dtype=np.int64)
    done = 0
    with scenario_bag(args, config) as bag:
        if bag:
            bag.write_phase('static', 0)
        while done < total:
            part = triad.run(min(chunk, total - done))
            n = len(part.stamps_ns)
            accel[done:done + n] = part.accel
            truth[done:done + n] = part.truth
            saturated += part.saturated.sum(axis=0)
            done += n
            if bag:
                bag.write_imu(part)
                bag.write_temperature(part.stamps_ns[-1:], part.temperature[-1:])
    print_summary(triad, accel, truth, saturated, out)
    return 0


def run_paper_2019(args, out=None):
    """Follow seed 1 section IV-A for ``args.trials`` trials and print its tables."""
    out = out or sys.stdout
    with scenario_bag(args, TriadConfig()) as bag:
        trials = paper_experiment(seed=args.seed, trials=args.trials, recorder=bag)
    print(format_paper_tables(trials), file=out)
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


def run_temperature_cycle(args, out=None):
    """Calibrate the drawn unit of ``--seed`` in six positions, verify on another cycle.

    The calibration is the chamber program of ``--duration`` seconds (plateaus, tumbling
    head, soak back); the verification a sine chamber cycle of 4/3 that period with the
    head tumbling in the reverse order (not the calibration's profile). A progress bar
    shows on a terminal.
    """
    out = out or sys.stdout
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='constant'))
    unit = draw_unit(args.seed)
    triad = unit.triad(config, rng=args.seed)
    settings = TemperatureSettings(period_s=args.duration)
    verify_s = 4.0 * args.duration / 3.0
    with scenario_bag(args, triad.config) as bag:
        with tqdm(total=round(args.duration), unit='s', desc='calibration (sensor time)',
                  disable=None, file=sys.stderr) as bar:
            result = run_schedule(triad, temperature_schedule(triad, CalibrationState(),
                                                              settings),
                                  progress=bar.update)
        verify_ns = triad.stamp_ns(triad.sample_index)
        with tqdm(total=round(verify_s), unit='s', desc='verification (sensor time)',
                  disable=None, file=sys.stderr) as bar:
            verification = verify_cycle(triad, settings.low_c, settings.high_c, verify_s,
                                        progress=bar.update)
        if bag:
            bag.write_phase('calibration', result.start_ns)
            bag.write_temperature(result.blocks['time_ns'], result.blocks['temperature'])
            bag.write_trace(None, 'temperature', [result])
            bag.write_phase('verification', verify_ns)
    print(f'qfa-sim temperature-cycle: unit of seed {args.seed}; calibration '
          f'{settings.low_c:g}..{settings.high_c:g} degC plateaus, {args.duration:g} s, six '
          f'positions, {result.soak_s:.0f} s soak back; verification: sine cycle of '
          f'{verify_s:g} s, six positions, fixed-point compensation', file=out)
    print('| axis | bias fit RMSE ug | SF fit RMSE ppm | zero-drift p2p before ug | '
          'zero-drift p2p after ug (worst of six positions) | reduction | SF p2p before ppm '
          '| SF residual after ppm |', file=out)
    print('|---|---|---|---|---|---|---|---|', file=out)
    comp = result.compensation
    for i, name in enumerate(AXES):
        bias, scale = comp.bias[i], comp.scale[i]
        after = verification.zero_drift_p2p[:, i].max()
        print(f'| {name} | {bias.fit.rmse / MICRO_G:.2f} | {scale.fit.rmse * 1e6:.2f} | '
              f'{bias.p2p_before / MICRO_G:.1f} | {after / MICRO_G:.1f} | '
              f'{bias.p2p_before / after:.1f}x | {scale.p2p_before * 1e6:.0f} | '
              f'{verification.scale_residual[i] * 1e6:.1f} |', file=out)
    print('zero drift: p2p over 10 degC bins of (output - fixture input); SF residual: largest '
          '|scale-factor error| of the +-g pairs over the bins', file=out)
    return 0


SCENARIOS = {
    'static': run_static,
    'paper-2019': run_paper_2019,
    'temperature-cycle': run_temperature_cycle,
}


def build_parser():
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='qfa-sim', description='Run the QFA triad model offline, as fast as it can.')
    parser.add_argument('scenario', choices=sorted(SCENARIOS), help='what to simulate')
    parser.add_argument('--duration', type=float, default=None,
                        help='sensor time to simulate [s] (static: default 60; '
                             'temperature-cycle: the cycle period, default 3600)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--trials', type=int, default=6,
                        help='paper-2019: number of trials (default 6, as seed 1)')
    parser.add_argument('--out', metavar='FILE.mcap',
                        help='write the scenario as a rosbag2-compatible MCAP file')
    return parser


def main(argv=None):
    """Run the simulator command line."""
    args = build_parser().parse_args(argv)
    if args.duration is None:
        args.duration = 3600.0 if args.scenario == 'temperature-cycle' else 60.0
    if not args.duration > 0:
        print('qfa-sim: --duration must be positive', file=sys.stderr)
        return 2
    if args.trials < 1:
        print('qfa-sim: --trials must be at least 1', file=sys.stderr)
        return 2
    if args.out is not None and not args.out.endswith('.mcap'):
        print('qfa-sim: --out must name a .mcap file', file=sys.stderr)
        return 2
    start = time.perf_counter()
    status = SCENARIOS[args.scenario](args)
    print(f'wall time {time.perf_counter() - start:.2f} s', file=sys.stdout)
    return status


if __name__ == '__main__':
    sys.exit(main())
