"""
Offline simulator: ``qfa-sim SCENARIO [--duration S] [--seed N] [--out FILE.mcap]``.

Runs without ROS or DDS, as fast as it can. Bags start at ``--start-time`` (default
2026-01-01T00:00:00Z, :data:`SIM_START_NS`): a realistic date on
a timeline, the same for every run. ``qfa-sim trajectory --motion drive``
(or ``--trajectory-file poses.csv``) moves the full IMU (QFA accelerometers and gyros)
along a trajectory on the WGS-84 Earth and writes the stream with its ground truth
(nav_msgs/Odometry on ``/truth/odometry`` in the ENU tangent plane of the start, whose
geodetic origin is on ``/truth/origin``, docs/ins.md) so that an INS can be scored.
"""

import argparse
import contextlib
import dataclasses
import datetime
import functools
import gc
import math
import os
import sys
import time

import numpy as np
from tqdm import tqdm

from qfa_ros.calibration.schedule import sensor_time_ns
from qfa_ros.cli.interrupt import stops_quietly
from qfa_ros.model import motion_scripts
from qfa_ros.model.allan import allan_deviation_of_phase
from qfa_ros.model.checks import is_finite
from qfa_ros.model.constants import DEG_PER_HOUR, MICRO_G
from qfa_ros.model.design import LinearLoop
from qfa_ros.model.drawn_unit import draw_unit
from qfa_ros.model.error_profiles import ERROR_PROFILES, PaperRoom, sensor_config
from qfa_ros.model.error_truth import error_truth
from qfa_ros.model.noise_figures import emulated_config
from qfa_ros.model.parallel import run_chains
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES, QfaTriad
from qfa_ros.model.triad_config import TriadConfig

CHUNK_SECONDS = 30.0
"""Sensor time per chunk of the static and trajectory scenarios [s]: long enough for the
axes' threads and for the next chunk's preparation to overlap a chunk's loops."""
IMU_ERRORS_PERIOD_S = 10.0
"""Period of ``/truth/imu_errors`` in trajectory bags [s] (the errors move slowly)."""
SIM_START_NS = 1_767_225_600_000_000_000
"""Default start of simulated recordings: 2026-01-01T00:00:00Z [ns since the epoch].

A fixed, documented instant rather than 0 (1970 on Foxglove's and ``ros2 bag info``'s
timelines) or the wall clock (a bag would differ from run to run): same seed, same bag.
Defined here, not in the bag layer, so that ``qfa-sim static`` does not load the MCAP
writer it does not use.
"""

def scenario_bag(args, config, **options):
    """Return a :class:`ScenarioBag` of ``options`` for ``--out``; a null context without it."""
    if args.out is None:
        return contextlib.nullcontext()
    # Imported where used, as the calibration modules below: a scenario loads only what
    # it runs (the MCAP writer and scipy.optimize cost start-up time).
    from qfa_ros.bag.scenario_bag import ScenarioBag
    return ScenarioBag(args.out, config, **options)


def static_sensor():
    """
    Return (config, profile) of the node's default sensor as the nominal unit.

    The node's defaults with ``unit.draw: false`` and ``thermal.ambient_profile: constant``
    (the node's default room wanders; a noise summary wants a still ambient): the thermal
    model on (constant 25 degC ambient, the body at ambient, so the zero bias is the double
    exponential's value at 25 degC and the error profile's temperature coefficients act on
    a zero temperature change), default noise and gyros, level at the default location
    (latitude 45 deg: WGS-84 normal gravity and the Earth rate). Not the drawn unit the
    node publishes by default: its deterministic errors (turn-on bias, misalignment times
    g, K2) would hide the noise figures this summary reports; ``qfa-sim temperature-cycle``
    simulates drawn units. ``test_loop_model`` checks that this equals the node's parameters.
    """
    # The node's room correlation too (unused by a constant ambient): the node's config.
    return (TriadConfig(thermal=ThermalConfig(ambient_profile='constant',
                                              room_correlation_s=PaperRoom.room_correlation_s)),
            motion_scripts.static(45.0, 0.0, 0.0, yaw=0.0))


def with_imu_noise(config, args):
    """Return ``config`` with the noise of ``--imu-yaml`` (read in :func:`main`), if any."""
    if args.imu_noise is None:
        return config
    return emulated_config(config, args.imu_noise)


def run_static(args, out=None):
    """
    Run the default sensor, level and static, for ``args.duration`` s and summarize it.

    The summary is the accelerometers'. The gyros run only when ``--out`` writes them:
    their random streams are keyed apart from the loops', so every accelerometer number
    is the same with or without them (``test_static_summary_does_not_depend_on_the_gyros``)
    and computing outputs nobody reads would cost about 5 % of the run.
    """
    out = out or sys.stdout
    config, profile = static_sensor()
    config = with_imu_noise(sensor_config(args.error_profile, config), args)
    if args.out is None:
        config = dataclasses.replace(config, gyro=None)
    triad = QfaTriad(config, rng=args.seed, profile=profile, start_ns=args.start_ns)
    rate = int(round(config.sample_rate_hz))
    chunk = int(round(CHUNK_SECONDS * config.sample_rate_hz))
    total = int(round(args.duration * config.sample_rate_hz))
    # Per axis, the phase of (accel - reference) for the Allan deviation (one row, the
    # only array of the run's length) and the sums of its first two powers.
    # Refused before it is allocated: with memory overcommitted, an array larger than the
    # machine is granted and the run killed when it fills it, hours later.
    needed = len(AXES) * (total + 1) * 8
    try:
        if needed > os.sysconf('SC_PHYS_PAGES') * os.sysconf('SC_PAGE_SIZE'):
            raise MemoryError
        phase = np.zeros((len(AXES), total + 1))
    except MemoryError:
        print(f'qfa-sim: --duration {args.duration:g} s needs {needed / 2 ** 30:.3g} GiB for '
              'the Allan deviation of the static summary, more than there is; simulate less',
              file=sys.stderr)
        return 2
    reference = None
    sums = np.zeros((2, len(AXES)))
    truth = np.zeros(len(AXES))
    saturated = np.zeros(len(AXES), dtype=np.int64)
    temperature = 0.0
    done = 0
    rate_variance = None if triad.gyro is None else triad.gyro.variance()
    with scenario_bag(args, config, rate_variance=rate_variance) as bag, \
            tqdm(total=args.duration, unit='s', desc='qfa-sim static', disable=None,
                 leave=False) as progress:
        if bag:
            bag.write_phase('static', sensor_time_ns(triad))
        for part in triad.run_chunks(total, chunk):
            n = len(part.stamps_ns)
            if reference is None:
                reference = part.accel.mean(axis=0)
            centered = part.accel - reference
            sums += (centered.sum(axis=0), (centered * centered).sum(axis=0))
            np.cumsum(centered.T, axis=1, out=phase[:, done + 1:done + n + 1])
            phase[:, done + 1:done + n + 1] += phase[:, done:done + 1]
            truth += part.truth.sum(axis=0)
            saturated += part.saturated.sum(axis=0)
            temperature += part.temperature.sum()
            if bag:
                bag.write_imu(part)
                # 1 Hz: the end of every second, and the last sample of the run.
                index = np.arange(done, done + n)
                marks = ((index + 1) % rate == 0) | (index == total - 1)
                bag.write_temperature(part.stamps_ns[marks], part.temperature[marks])
            done += n
            progress.update(n / config.sample_rate_hz)
    count = max(total, 1)
    mean = sums[0] / count
    std = np.sqrt(np.maximum(sums[1] / count - mean ** 2, 0.0))
    offset = np.zeros(len(AXES)) if reference is None else reference
    print_summary(triad, phase, offset + mean, std, truth / count, saturated,
                  temperature / count, out)
    return 0


def build_trajectory(args):
    """Return the :class:`~qfa_ros.model.trajectory.Trajectory` the arguments name."""
    if args.trajectory_file:
        return motion_scripts.load_csv(args.trajectory_file)
    return motion_scripts.SCRIPTS[args.motion](
        latitude_deg=args.latitude, longitude_deg=args.longitude, height_m=args.height,
        yaw=math.radians(args.yaw))


def trajectory_chunks(triad, total, chunk, with_errors):
    """
    Yield the trajectory's output chunks; with ``with_errors``, stop between them.

    Error truth is read from the triad between chunks (``/truth/imu_errors`` every
    :data:`IMU_ERRORS_PERIOD_S`), which :meth:`QfaTriad.run_chunks` does not allow (it
    runs the next chunk while the caller handles one); the numbers are the same.
    """
    if not with_errors:
        yield from triad.run_chunks(total, chunk)
        return
    step = int(round(IMU_ERRORS_PERIOD_S * triad.config.sample_rate_hz))
    for start in range(0, total, step):
        yield triad.run(min(step, total - start))


def run_trajectory(args, out=None):
    """Move the full IMU along a trajectory; write the stream and its ground truth."""
    out = out or sys.stdout
    try:
        motion = build_trajectory(args)
    except (OSError, ValueError) as error:
        print(f'qfa-sim: {error}', file=sys.stderr)
        return 2
    duration = args.duration if args.duration is not None else max(motion.duration, 60.0)
    config = with_imu_noise(
        sensor_config(args.error_profile, TriadConfig(sample_rate_hz=args.rate)), args)
    triad = QfaTriad(config, rng=args.seed, profile=motion, start_ns=args.start_ns)
    chunk = int(round(CHUNK_SECONDS * config.sample_rate_hz))
    total = int(round(duration * config.sample_rate_hz))
    truth_every = max(1, int(round(config.sample_rate_hz / args.truth_rate)))
    accel_error = np.zeros(3)
    gyro_error = np.zeros(3)
    done = 0
    with scenario_bag(args, config, rate_variance=triad.gyro.variance(),
                      truth_frame_id='enu_origin') as bag:
        if bag:
            bag.write_phase(motion.name, args.start_ns)
            origin = motion.kinematics(np.array([motion.start]))
            bag.write_origin(args.start_ns, math.degrees(origin['latitude'][0]),
                             math.degrees(origin['longitude'][0]), origin['height'][0])
        for part in trajectory_chunks(triad, total, chunk, bag is not None):
            accel_error += (part.accel - part.truth).sum(axis=0)
            gyro_error += (part.gyro - part.rate_truth).sum(axis=0)
            if bag:
                bag.write_imu(part)
                # The triad is at the chunk's end: the errors it holds there.
                end_s = (int(part.stamps_ns[-1]) - args.start_ns) / 1e9
                bag.write_imu_errors(part.stamps_ns[-1], error_truth(
                    triad, motion.evaluate(np.array([end_s]))[0]))
                index = done + np.arange(len(part.stamps_ns))
                picked = (index + 1) % truth_every == 0
                if picked.any():
                    stamps = part.stamps_ns[picked]
                    # The trajectory runs on sensor time; the stamps start at --start-time.
                    bag.write_truth(stamps, *motion.local_pose((stamps - args.start_ns) / 1e9))
                bag.write_temperature(part.stamps_ns[-1:], part.temperature[-1:])
            done += len(part.stamps_ns)
    end = motion.local_pose(np.array([duration]))[0][0]
    print(f'qfa-sim trajectory: {motion.name}, {duration:g} s at {config.sample_rate_hz:g} Hz '
          f'(loop {config.loop_rate_hz:g} Hz), seed {args.seed}', file=out)
    print(f'end position in the start ENU plane: E {end[0]:.1f} m, N {end[1]:.1f} m, '
          f'U {end[2]:.1f} m', file=out)
    print(f'{"axis":>4} {"accel error ug":>15} {"gyro error deg/h":>17}', file=out)
    for i, name in enumerate(AXES):
        print(f'{name:>4} {accel_error[i] / total / MICRO_G:15.2f} '
              f'{gyro_error[i] / total / DEG_PER_HOUR:17.4f}', file=out)
    if args.out is not None:
        print(f'wrote {args.out}: /imu/data_raw (Imu with angular velocity), '
              f'/truth/odometry at {config.sample_rate_hz / truth_every:g} Hz, /truth/origin, '
              f'/truth/imu_errors every {IMU_ERRORS_PERIOD_S:g} s',
              file=out)
    return 0


def run_paper_2019(args, out=None):
    """Follow Ran et al. 2019, section IV-A for ``args.trials`` trials and print its tables."""
    from qfa_ros.calibration.experiments import format_paper_tables, paper_experiment
    out = out or sys.stdout
    with scenario_bag(args, TriadConfig()) as bag:
        trials = paper_experiment(seed=args.seed, trials=args.trials, recorder=bag,
                                  start_ns=args.start_ns)
    print(format_paper_tables(trials), file=out)
    return 0


def allan_summary(phase, sample_period):
    """
    Return (ADEV at 1 s, minimum ADEV, its tau [s]) from one axis's phase.

    Computed once, at octave-spaced tau plus tau = 1 s (NaN where the series is too
    short), on the published (decimated) stream; see
    :func:`qfa_ros.model.allan.allan_deviation_of_phase`.
    """
    if len(phase) < 4:
        return float('nan'), float('nan'), float('nan')
    taus, adev = allan_deviation_of_phase(phase, sample_period)
    _, at_one = allan_deviation_of_phase(phase, sample_period, taus=[1.0])
    at_one = at_one[0] if len(at_one) else float('nan')
    k = int(np.argmin(adev))
    return at_one, adev[k], taus[k]


def print_summary(triad, phase, mean, std, truth, saturated, temperature, out):
    """
    Print per-axis mean, error vs truth, std, Allan deviation and saturation counts.

    ``phase`` is (3, n + 1), the running sum of each axis's output minus a constant
    [m/s^2 per sample]; ``mean``, ``std``, ``truth`` (the mean true specific force)
    per axis [m/s^2]; the thermal zero bias at the mean body ``temperature`` [degC] is
    printed beside the error it explains.
    """
    config = triad.config
    loop = triad.axes[0]
    crossover, phase_margin, gain_margin, bandwidth = LinearLoop(
        config.hardware, loop.controller, config.loop_rate_hz).margins()
    duration = (phase.shape[1] - 1) / config.sample_rate_hz
    stats = [None] * len(AXES)

    def job(i):
        stats[i] = allan_summary(phase[i], triad.sample_period)

    # The axes' passes release the GIL: they share the cores like the simulation.
    run_chains([[functools.partial(job, i)] for i in range(len(AXES))], triad.workers)
    if triad.thermal is not None:
        zero_bias = triad.thermal.zero_bias(temperature) / MICRO_G
        sensor = (f'thermal model on, body {temperature:.2f} degC, '
                  f'{config.thermal.ambient_profile} ambient')
    else:
        zero_bias = np.zeros(len(AXES))
        sensor = 'thermal model off'
    print(f'qfa-sim: {duration:g} s of sensor time at {config.sample_rate_hz:g} Hz '
          f'(loop {config.loop_rate_hz:g} Hz); {sensor}', file=out)
    print(f'loop: k(D(z)) = {loop.controller.gain:.4f}, crossover {crossover:.0f} Hz, '
          f'phase margin {phase_margin:.1f} deg, gain margin {gain_margin:.1f} dB, '
          f'bandwidth {bandwidth:.0f} Hz', file=out)
    header = (f'{"axis":>4} {"mean m/s^2":>14} {"error ug":>10} {"bias(T) ug":>10} '
              f'{"std ug":>9} {"ADEV(1s) ug":>12} {"ADEV min ug":>12} {"at tau s":>9} '
              f'{"saturated":>9}')
    print(header, file=out)
    for i, name in enumerate(AXES):
        at_one, minimum, tau_min = stats[i]
        error = (mean[i] - truth[i]) / MICRO_G
        print(f'{name:>4} {mean[i]:14.8f} {error:10.2f} {zero_bias[i]:10.2f} '
              f'{std[i] / MICRO_G:9.2f} {at_one / MICRO_G:12.3f} {minimum / MICRO_G:12.3f} '
              f'{tau_min:9.3g} {int(saturated[i]):9d}', file=out)


def run_temperature_cycle(args, out=None):
    """Calibrate the drawn unit of ``--seed`` in six positions, verify on another cycle.

    The calibration is the chamber program of ``--duration`` seconds (plateaus, tumbling
    head, soak back); the verification a sine chamber cycle of 4/3 that period with the
    head tumbling in the reverse order (not the calibration's profile). A progress bar
    shows on a terminal.
    """
    from qfa_ros.calibration.schedule import run_schedule
    from qfa_ros.calibration.state import CalibrationState
    from qfa_ros.calibration.temperature import temperature_schedule, TemperatureSettings
    from qfa_ros.calibration.verification import verify_cycle
    out = out or sys.stdout
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='constant'))
    unit = draw_unit(args.seed)
    triad = unit.triad(config, rng=args.seed, start_ns=args.start_ns)
    settings = TemperatureSettings(period_s=args.duration)
    verify_s = 4.0 * args.duration / 3.0
    with scenario_bag(args, triad.config) as bag:
        # The schedule's own phases and fraction (its length depends on the soaks).
        result = run_schedule(triad, temperature_schedule(triad, CalibrationState(), settings),
                              progress='calibration')
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
    'trajectory': run_trajectory,
}


def build_parser():
    """Return the command-line parser."""
    parser = argparse.ArgumentParser(
        prog='qfa-sim', description='Run the QFA triad model offline, as fast as it can.')
    parser.add_argument('scenario', choices=sorted(SCENARIOS), help='what to simulate')
    parser.add_argument('--duration', type=float, default=None,
                        help='sensor time to simulate [s] (static: default 60; '
                             'temperature-cycle: the cycle period, default 3600; '
                             'trajectory: its length, at least 60)')
    parser.add_argument('--seed', type=int, default=0, help='random seed (default 0)')
    parser.add_argument('--trials', type=int, default=6,
                        help='paper-2019: number of trials (default 6, as Ran et al. 2019)')
    motion = parser.add_argument_group('trajectory scenario')
    motion.add_argument('--motion', choices=sorted(motion_scripts.SCRIPTS), default='drive',
                        help='built-in motion script (default drive)')
    motion.add_argument('--trajectory-file', metavar='POSES.csv',
                        help='CSV of time_s, latitude_deg, longitude_deg, height_m, '
                             'roll_deg, pitch_deg, yaw_deg (instead of --motion)')
    motion.add_argument('--latitude', type=float, default=45.0, help='[deg] (default 45)')
    motion.add_argument('--longitude', type=float, default=0.0, help='[deg] (default 0)')
    motion.add_argument('--height', type=float, default=0.0, help='[m] (default 0)')
    motion.add_argument('--yaw', type=float, default=90.0,
                        help='initial heading, ENU yaw [deg] (default 90: x north)')
    motion.add_argument('--rate', type=float, default=1000.0,
                        help='IMU sample rate [Hz] (default 1000; 10 kHz / rate integer)')
    motion.add_argument('--truth-rate', type=float, default=100.0,
                        help='ground-truth odometry rate [Hz] (default 100)')
    parser.add_argument('--imu-yaml', metavar='IMU.yaml',
                        help="static, trajectory: emulate a Kalibr imu.yaml's noise densities "
                             'and random walks (the QFA loop and the rest of the sensor kept; '
                             'docs/ins.md)')
    parser.add_argument('--error-profile', choices=ERROR_PROFILES, default='paper',
                        help='static, trajectory: paper (default, the sensor with its errors) '
                             'or ideal (every error source off; docs/ins.md)')
    parser.add_argument('--out', metavar='FILE.mcap',
                        help='write the scenario as a rosbag2-compatible MCAP file')
    parser.add_argument('--start-time', type=parse_start_time, default=SIM_START_NS,
                        dest='start_ns', metavar='ISO8601',
                        help='time of the first sample in the bag (default '
                             '2026-01-01T00:00:00Z; UTC when no offset is given)')
    return parser


def parse_start_time(text):
    """Return ``text`` (ISO 8601; UTC unless it names an offset) in ns since the epoch."""
    try:
        moment = datetime.datetime.fromisoformat(text.replace('Z', '+00:00'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an ISO 8601 time: {text!r}') from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=datetime.timezone.utc)
    epoch = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
    time_ns = (moment - epoch) // datetime.timedelta(microseconds=1) * 1000
    # A bag's times are unsigned (MCAP) and the stamps int64 nanoseconds.
    if not 0 <= time_ns < 2 ** 63:
        raise argparse.ArgumentTypeError(f'{text!r} is not between 1970 and 2262')
    return time_ns


def option_problem(args):
    """Return what is wrong with the numeric options of ``args`` (one line), or None."""
    if args.duration is not None and not (is_finite(args.duration) and args.duration > 0):
        return f'--duration must be a positive finite number of seconds, got {args.duration}'
    if args.start_ns + (args.duration or 0.0) * 1e9 >= 2 ** 63:
        return (f'--duration {args.duration:g} s from --start-time ends after 2262 (int64 '
                'nanoseconds)')
    if args.trials < 1:
        return '--trials must be at least 1'
    if args.seed < 0:
        return f'--seed must be non-negative, got {args.seed}'
    if args.scenario == 'temperature-cycle':
        from qfa_ros.calibration.temperature import TemperatureSettings
        try:
            TemperatureSettings(period_s=args.duration)
        except ValueError as error:
            return f'--duration: {error}'
    if args.scenario == 'trajectory':
        try:
            TriadConfig(sample_rate_hz=args.rate)
        except ValueError as error:
            return f'--rate: {error}'
        if not (is_finite(args.truth_rate) and args.truth_rate > 0):
            return f'--truth-rate must be a positive finite number of Hz, got {args.truth_rate}'
        if not is_finite(args.yaw):
            return f'--yaw must be a finite number of degrees, got {args.yaw}'
    return None


@stops_quietly('qfa-sim')
def main(argv=None):
    """Run the simulator command line."""
    args = build_parser().parse_args(argv)
    if args.duration is None and args.scenario != 'trajectory':
        args.duration = 3600.0 if args.scenario == 'temperature-cycle' else 60.0
    problem = option_problem(args)
    if problem:
        print(f'qfa-sim: {problem}', file=sys.stderr)
        return 2
    if args.error_profile != 'paper' and args.scenario not in ('static', 'trajectory'):
        print(f'qfa-sim: --error-profile {args.error_profile} applies to static and trajectory '
              f'(the {args.scenario} scenario estimates the errors it needs)', file=sys.stderr)
        return 2
    args.imu_noise = None
    if args.imu_yaml is not None:
        if args.scenario not in ('static', 'trajectory'):
            print(f'qfa-sim: --imu-yaml applies to static and trajectory (the {args.scenario} '
                  'scenario runs the sensor it estimates)', file=sys.stderr)
            return 2
        from qfa_ros.calibration.kalibr_yaml import load_imu_yaml
        try:
            args.imu_noise = load_imu_yaml(args.imu_yaml)
            # Below the loop's own floor: refused now, not in the scenario.
            with_imu_noise(sensor_config(args.error_profile, TriadConfig()), args)
        except ValueError as error:
            print(f'qfa-sim: --imu-yaml: {error}', file=sys.stderr)
            return 2
    if args.out is not None and not args.out.endswith('.mcap'):
        print('qfa-sim: --out must name a .mcap file', file=sys.stderr)
        return 2
    start = time.perf_counter()
    # The imports and numba's first compile leave ~1e5 long-lived objects; a full
    # collection walks them all (~60 ms), so they are kept out of the run's collections.
    gc.freeze()
    try:
        status = SCENARIOS[args.scenario](args)
    except OSError as error:
        # --out: an existing file, a missing directory, a full disk.
        where = f'{error.filename}: ' if error.filename else ''
        print(f'qfa-sim: {where}{error.strerror or error}', file=sys.stderr)
        return 1
    finally:
        gc.unfreeze()
    print(f'wall time {time.perf_counter() - start:.2f} s', file=sys.stdout)
    return status


if __name__ == '__main__':
    sys.exit(main())
