"""
The temperature calibration judged through the node, as a user would (issue 45).

Starts ``qfa_node`` (no parameter file but the overrides: ``sample_rate_hz``,
``estimation.realtime``, ``unit.seed``, ``seed``, a constant ambient, ``thermal.sensor_tau_s:
8``, every file in a scratch directory) and, from another process, through ROS alone:
waits for the first ``imu/data_raw`` samples (a ``SensorDataQoS`` subscriber: best effort,
depth 5, single-threaded executor), calls ``~/calibrate_temperature`` ``--delay`` s later,
then per plateau of ``temperature_c`` (-27, 8, 41, 64 degC) waits ``--plateau-wait`` s
and, with the compensation off, then on (``~/set_compensation``), sets each attitude of
:data:`~qfa_ros.calibration.verification.ATTITUDES` through ``input.roll``/``input.pitch``
and averages the samples stamped from ``--settle`` s after the change for ``--average`` s.
Judged as the offline verification is: zero drift is the peak to peak over the plateaus
per attitude and axis, the scale factor each axis's +-g pair against the input's g.

``--offline`` runs the same procedure on the model in this process
(:func:`~qfa_ros.calibration.verification.verify_attitudes`, the plateau wait as its
soak, the call at sample ``--call-sample``, which the node's trace gives for its own
call): the offline path with the node's exact parameters. ``--seed 1 --plateau-wait
80`` with either is the earlier offline bench's (``bench/results/unit_218566.md``).

Each node runs with its client in a worker process of its own on its own ROS domain
(``--domains``, default ``QFA_TEST_DOMAINS``); ``--nodes`` side by side; ``--python``
chooses the venv (distribution) of node and client; ``--busy`` keeps one core busy with
a spinning process meanwhile; ``--param NAME=VALUE`` passes more node parameters (e.g. a
shorter ``temperature_calibration.period_s``). ``--draw N`` draws N unit seeds
(``--draw-seed``) instead of ``--unit``. Prints Markdown; ``--jsonl`` appends every run.

    nice -n 10 .venv/bin/python bench/temperature_node.py --unit 218566 --delay 0.2
"""

import argparse
import json
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))

from node_helpers import node_environment, ROOT  # noqa: E402

from qfa_ros.calibration.verification import ATTITUDES, SCALE_PAIRS  # noqa: E402
from qfa_ros.model.constants import MICRO_G, PPM, STANDARD_GRAVITY  # noqa: E402

PLATEAUS_C = (-27.0, 8.0, 41.0, 64.0)
ZERO_LIMIT_UG = 30.0
SCALE_LIMIT_PPM = 20.0
NODE_TIMEOUT_S = 7200.0


def node_parameters(args, unit, seed, directory):
    """Return the node's parameter overrides for one run (the rest at their defaults)."""
    values = {'sample_rate_hz': args.rate, 'estimation.realtime': args.realtime,
              'unit.seed': unit, 'seed': seed, 'thermal.ambient_profile': 'constant',
              'thermal.sensor_tau_s': 8.0, 'output_dir': str(directory),
              'trace_dir': str(directory / 'traces'),
              'state_file': str(directory / 'calibration.json')}
    for item in args.param:
        name, _, text = item.partition('=')
        values[name] = json.loads(text)
    return values


def expected_force(values, roll, pitch):
    """Return the specific force [m/s^2] the node's static input gives at an attitude."""
    from qfa_ros.ros.model_settings import static_profile
    from qfa_ros.ros.parameter_table import PARAMETERS
    full = {spec.name: spec.default for spec in PARAMETERS}
    full.update(values)
    full.update({'input.roll': roll, 'input.pitch': pitch})
    return static_profile(full).sample_means(0.0, 1.0 / full['sample_rate_hz'], 1)[0][0]


def judge(error, g):
    """Return zero drift p2p [ug] (attitude, axis), scale error [ppm] (plateau, axis)."""
    names = [name for name, *_ in ATTITUDES]
    zero = np.ptp(error, axis=0) / MICRO_G
    scale = np.zeros((error.shape[0], 3))
    for axis, (up, down) in enumerate(SCALE_PAIRS):
        i, j = names.index(up), names.index(down)
        scale[:, axis] = (error[:, i, axis] - error[:, j, axis]) / (2.0 * g) / PPM
    return zero, scale


def window_mean(client, imu, settle_s, average_s, rate):
    """
    Return (mean x/y/z, received fraction) of ``average_s`` worth of samples.

    The first ``average_s * rate`` samples stamped from ``settle_s`` on: a subscriber on a
    busy machine loses some (best effort, depth 5), so the window stretches until it has
    them (the input is static). The fraction is how many of the samples stamped in the
    stretched window arrived.
    """
    count = max(1, round(average_s * rate))
    imu.clear(time.time_ns() + int(settle_s * 1e9))
    client.spin_until(lambda: len(imu.samples) >= count, 60.0, f'{count} samples',
                      progress=lambda: len(imu.samples))
    kept = np.array(imu.samples[:count])
    span = (kept[-1, 0] - kept[0, 0]) * 1e-9 * rate + 1
    return kept[:, 1:].mean(axis=0), count / span


def trace_facts(directory, rate):
    """
    Return what the node's trace of the calibration says.

    The sample the schedule started at (``call_sample``: the model's stamps start at 0)
    and the probe lag it estimated [s].
    """
    from diagnostic_msgs.msg import DiagnosticArray
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message

    from qfa_ros.bag.trace_writer import key_values_to_dict

    facts = {}
    for path in sorted((directory / 'traces').glob('qfa_temperature_*.mcap')):
        with open(path, 'rb') as stream:
            for _, channel, message in make_reader(stream).iter_messages():
                if channel.topic.endswith('/settings'):
                    facts['call_sample'] = round(message.log_time * rate / 1e9)
                elif channel.topic.endswith('/result'):
                    status = deserialize_message(message.data, DiagnosticArray).status[0]
                    values = key_values_to_dict(status.values)
                    facts['probe_lag_s'] = values.get('temperature.probe_lag_s')
    return facts


def run_node(args, unit, seed, domain, directory):
    """Run the procedure against a node process; return the run's record."""
    from node_helpers import Client, ImuCollector, NODE, NodeProcess
    from rclpy.qos import qos_profile_sensor_data
    from std_srvs.srv import SetBool, Trigger

    values = node_parameters(args, unit, seed, directory)
    started = time.monotonic()
    command = None
    if args.tree:
        # Another source tree's node (an export of an earlier commit): its package first.
        command = [args.python, '-c', f'import runpy, sys; sys.path.insert(0, {args.tree!r}); '
                   "runpy.run_module('qfa_ros.cli.node', run_name='__main__', alter_sys=True)"]
    node = NodeProcess(domain, directory, values, python=args.python, command=command)
    client = Client(domain)
    record = {'unit': unit, 'seed': seed, 'domain': domain, 'python': args.python}
    try:
        imu = ImuCollector(client, qos=qos_profile_sensor_data)
        # The service found first: the call leaves as soon as the first sample is in.
        calibrate = client.client(Trigger, f'/{NODE}/calibrate_temperature')
        client.spin_until(calibrate.service_is_ready, 120.0, 'the calibration service')
        client.spin_until(lambda: imu.samples, 120.0, 'the first sample')
        record['first_sample_s'] = time.monotonic() - started
        client.spin_for(args.delay)
        called = time.monotonic()
        answer = client.call(Trigger, f'/{NODE}/calibrate_temperature', Trigger.Request(),
                             timeout=NODE_TIMEOUT_S)
        record['calibration_wall_s'] = time.monotonic() - called
        record['answer'] = answer.message
        if not answer.success:
            return record
        record.update(trace_facts(directory, args.rate))
        state = json.loads((directory / 'calibration.json').read_text())
        record['reference_tc_ppm'] = state.get('state', state).get('reference_tc_ppm')
        error = np.zeros((2, len(PLATEAUS_C), len(ATTITUDES), 3))
        fractions = []
        for t, chamber_c in enumerate(PLATEAUS_C):
            client.set_parameters({'temperature_c': chamber_c})
            client.spin_for(args.plateau_wait)
            for c, on in enumerate((False, True)):
                if args.compensated_only and not on:
                    error[c, t] = np.nan
                    continue
                client.call(SetBool, f'/{NODE}/set_compensation', SetBool.Request(data=on))
                for a, (_, roll, pitch) in enumerate(ATTITUDES):
                    results = client.set_parameters({'input.roll': roll, 'input.pitch': pitch})
                    if not all(r.successful for r in results):
                        raise RuntimeError(f'attitude refused: {results}')
                    mean, fraction = window_mean(client, imu, args.settle, args.average,
                                                 args.rate)
                    error[c, t, a] = mean - expected_force(values, roll, pitch)
                    fractions.append(fraction)
        record['error'] = error.tolist()
        record['received_min'] = min(fractions)
        record['received'] = fractions
        record['g'] = float(np.linalg.norm(expected_force(values, 0.0, 0.0)))
    finally:
        client.close()
        node.stop()
        log = node.log()
        record['skipped_warnings'] = log.count('skipped')
        record['node_log_tail'] = log[-2000:] if 'error' not in record else ''
    return record


def run_offline(args, unit, seed, call_sample):
    """Run the same procedure on the model in this process, with the node's parameters."""
    from qfa_ros.calibration.schedule import run_schedule
    from qfa_ros.calibration.state import CalibrationState
    from qfa_ros.calibration.temperature import temperature_calibration
    from qfa_ros.calibration.verification import verify_attitudes
    from qfa_ros.ros.model_settings import make_triad, temperature_settings
    from qfa_ros.ros.parameter_table import PARAMETERS

    with tempfile.TemporaryDirectory() as scratch:
        values = {spec.name: spec.default for spec in PARAMETERS}
        values.update(node_parameters(args, unit, seed, Path(scratch)))
    triad = make_triad(values)
    if call_sample:
        triad.run(call_sample)
    state = CalibrationState()
    started = time.process_time()
    results = run_schedule(triad, temperature_calibration(triad, state,
                                                          temperature_settings(values)))
    record = {'unit': unit, 'seed': seed, 'offline': True, 'call_sample': call_sample,
              'answer': results[0].summary(),
              'probe_lag_s': results[0].probe_lag_s,
              'reference_tc_ppm': state.reference_tc_ppm}
    verification = verify_attitudes(triad, PLATEAUS_C, soak_s=args.plateau_wait,
                                     average_s=args.average, settle_s=args.settle)
    record['calibration_cpu_s'] = time.process_time() - started
    # Offline the input is known exactly: the error is output minus truth (compensated).
    error = np.full((2, len(PLATEAUS_C), len(ATTITUDES), 3), np.nan)
    error[1] = verification.error
    record['error'] = error.tolist()
    record['g'] = STANDARD_GRAVITY
    return record


def summarize(record):
    """Add the judged figures (compensation on) to a record; return it."""
    if 'error' not in record:
        record['passed'] = False
        return record
    error = np.array(record['error'])
    zero, scale = judge(error[1], record['g'])
    record['zero_worst_ug'] = zero.max(axis=0).tolist()
    record['zero_ug'] = zero.tolist()
    record['scale_ppm'] = scale.tolist()
    record['scale_max_ppm'] = np.abs(scale).max(axis=0).tolist()
    record['scale_p2p_ppm'] = np.ptp(scale, axis=0).tolist()
    record['level_z_ug'] = (error[1, :, 0, 2] / MICRO_G).tolist()
    record['passed'] = bool(zero.max() <= ZERO_LIMIT_UG
                            and max(record['scale_max_ppm']) <= SCALE_LIMIT_PPM
                            and max(record['scale_p2p_ppm']) <= SCALE_LIMIT_PPM)
    return record


def worker_command(args, unit, seed, domain, out):
    """Return the command of a worker process that runs one node and its client."""
    command = [args.python, str(Path(__file__).resolve()), '--worker', str(out),
               '--unit', str(unit), '--seed', str(seed), '--domains', f'{domain}-{domain}',
               '--rate', repr(args.rate), '--delay', repr(args.delay),
               '--plateau-wait', repr(args.plateau_wait), '--average', repr(args.average),
               '--settle', repr(args.settle), '--python', args.python]
    if args.realtime:
        command.append('--realtime')
    if args.compensated_only:
        command.append('--compensated-only')
    if args.tree:
        command += ['--tree', args.tree]
    for item in args.param:
        command += ['--param', item]
    return command


def run_all(args, runs):
    """Run every (unit, seed) on ``--nodes`` worker processes; yield each record."""
    low, high = (int(v) for v in args.domains.split('-'))
    free = list(range(low, high + 1))[:args.nodes]
    pending, running = list(runs), {}
    scratch = Path(tempfile.mkdtemp(prefix='temperature_node_'))
    while pending or running:
        while pending and free:
            unit, seed = pending.pop(0)
            domain = free.pop(0)
            out = scratch / f'{unit}_{seed}_{domain}.json'
            log = open(out.with_suffix('.log'), 'w')
            # Another venv's worker gets the environment its own shell would give it.
            process = subprocess.Popen(worker_command(args, unit, seed, domain, out),
                                       stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                                       env=node_environment(domain, args.python))
            running[process] = (unit, seed, domain, out, log)
        time.sleep(1.0)
        for process in [p for p in running if p.poll() is not None]:
            unit, seed, domain, out, log = running.pop(process)
            log.close()
            free.append(domain)
            if out.exists():
                yield json.loads(out.read_text())
            else:
                yield {'unit': unit, 'seed': seed, 'domain': domain, 'passed': False,
                       'answer': 'worker failed: ' + out.with_suffix('.log').read_text()[-1500:]}


def drawn_units(count, seed):
    """Return ``count`` unit seeds drawn from their own named stream."""
    rng = np.random.default_rng([0x74656D70, seed])
    return [int(v) for v in rng.integers(0, 2 ** 31, size=count)]


def fmt(values, digits=1):
    return ' / '.join(f'{v:.{digits}f}' for v in values)


def report(args, records, load):
    """Print the Markdown report of ``records``."""
    mode = 'offline (model in the bench process)' if args.offline else \
        f'through the node ({Path(args.python).parents[1].name}' + \
        (f', tree {args.tree})' if args.tree else ')')
    print(f'\n{mode}; {args.rate:g} Hz, realtime {args.realtime}, delay {args.delay:g} s, '
          f'plateau wait {args.plateau_wait:g} s, busy core {args.busy}, nodes {args.nodes}, '
          f'params {args.param or "-"}; load {load}\n')
    print('| unit | seed | first sample [s] | call at sample | call [s] | I_ref TC x/y/z '
          '[ppm/degC] | worst zero drift x/y/z [ug] | SF max x/y/z [ppm] | SF p2p x/y/z '
          '[ppm] | level z per plateau [ug] | samples received (least) | pass |')
    print('|' + '---|' * 12)
    for r in records:
        if 'zero_worst_ug' not in r:
            print(f'| {r["unit"]} | {r["seed"]} | failed: {r.get("answer", "")[:300]} |')
            continue
        tc = r.get('reference_tc_ppm') or []
        print(f'| {r["unit"]} | {r["seed"]} | {r.get("first_sample_s", math.nan):.2f} | '
              f'{r.get("call_sample", "?")} | '
              f'{r.get("calibration_wall_s", r.get("calibration_cpu_s", math.nan)):.0f} | '
              f'{fmt(tc, 2)} | {fmt(r["zero_worst_ug"])} | {fmt(r["scale_max_ppm"])} | '
              f'{fmt(r["scale_p2p_ppm"])} | {fmt(r["level_z_ug"])} | '
              f'{r.get("received_min", math.nan):.3f} | {"yes" if r["passed"] else "NO"} |')
    judged = [r for r in records if 'zero_worst_ug' in r]
    if len(records) > 1:
        passed = sum(r['passed'] for r in records)
        print(f'\n{passed} of {len(records)} within {ZERO_LIMIT_UG:g} ug zero drift and '
              f'{SCALE_LIMIT_PPM:g} ppm scale factor (max and p2p, every axis and attitude)')
        if judged:
            zero = np.array([r['zero_worst_ug'] for r in judged])
            scale = np.array([np.maximum(r['scale_max_ppm'], r['scale_p2p_ppm'])
                              for r in judged])
            print(f'worst zero drift x/y/z {fmt(zero.max(axis=0))} ug (median '
                  f'{fmt(np.median(zero, axis=0))}); worst SF x/y/z {fmt(scale.max(axis=0))} '
                  f'ppm (median {fmt(np.median(scale, axis=0))})')


def parse(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--unit', type=int, action='append', default=[])
    parser.add_argument('--draw', type=int, default=0, help='draw this many unit seeds')
    parser.add_argument('--draw-seed', type=int, default=45)
    parser.add_argument('--seed', type=int, help='noise seed (default: unit seed + 1)')
    parser.add_argument('--delay', type=float, default=0.0,
                        help='s after the first sample before the call')
    parser.add_argument('--realtime', action='store_true', help='estimation.realtime true')
    parser.add_argument('--rate', type=float, default=200.0, help='sample_rate_hz')
    parser.add_argument('--plateau-wait', type=float, default=45.0)
    parser.add_argument('--average', type=float, default=1.5)
    parser.add_argument('--settle', type=float, default=0.5)
    parser.add_argument('--compensated-only', action='store_true',
                        help='skip the attitudes with the compensation off')
    parser.add_argument('--busy', action='store_true', help='keep one core busy meanwhile')
    parser.add_argument('--python', default=str(ROOT / '.venv' / 'bin' / 'python'))
    parser.add_argument('--nodes', type=int, default=1, help='nodes side by side')
    parser.add_argument('--domains', default=os.environ.get('QFA_TEST_DOMAINS', '101-130'))
    parser.add_argument('--param', action='append', default=[], help='NAME=JSON value')
    parser.add_argument('--tree', help="run this source tree's node (an export of a commit)")
    parser.add_argument('--offline', action='store_true')
    parser.add_argument('--call-sample', type=int, action='append', default=[],
                        help='offline: the sample index the call lands on (repeat to scan)')
    parser.add_argument('--jsonl', help='append every run record to this file')
    parser.add_argument('--worker', help=argparse.SUPPRESS)
    return parser.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    units = args.unit + drawn_units(args.draw, args.draw_seed)
    runs = [(unit, unit + 1 if args.seed is None else args.seed) for unit in units]
    if args.worker:
        domain = int(args.domains.split('-')[0])
        with tempfile.TemporaryDirectory(prefix='qfa45_') as scratch:
            record = run_node(args, *runs[0], domain, Path(scratch))
        Path(args.worker).write_text(json.dumps(record))
        return 0
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass']) if args.busy else None
    records = []
    try:
        source = (run_offline(args, *run, sample) for run in runs
                  for sample in args.call_sample or [0]) if args.offline \
            else run_all(args, runs)
        for record in source:
            records.append(summarize(record))
            print(f'# {record["unit"]}: worst {record.get("zero_worst_ug")} SF max '
                  f'{record.get("scale_max_ppm")}', file=sys.stderr, flush=True)
            if args.jsonl:
                with open(args.jsonl, 'a') as out:
                    out.write(json.dumps({**record, 'args': vars(args)}) + '\n')
    finally:
        if busy is not None:
            busy.send_signal(signal.SIGTERM)
            busy.wait()
    report(args, records, os.getloadavg())
    return 0


if __name__ == '__main__':
    sys.exit(main())
