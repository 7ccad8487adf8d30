"""
What configure/activate/deactivate/cleanup cycles leave behind in ``qfa_lifecycle_node``.

Run (the tables in ``bench/results/lifecycle_cycles.md``)::

    ROS_DOMAIN_ID=<id> .venv/bin/python bench/lifecycle_cycles.py --cycles 1000 \
        --out bench/results/lifecycle_cycles.md
    ROS_DOMAIN_ID=<id> .venv-jazzy/bin/python bench/lifecycle_cycles.py --cycles 1000 \
        --out bench/results/lifecycle_cycles.md

Starts one ``qfa_lifecycle_node`` process with this interpreter (so the Jazzy venv measures
Jazzy), the flight recorder on, ``output_dir`` and ``state_file`` in a fresh temporary
directory, on a ROS domain of its own with the localhost-only discovery. This process is
the manager: through ``~/change_state`` it configures, activates, captures a reference
(``estimation.realtime`` false: the state file then holds one), deactivates and cleans up
once, then runs ``--cycles`` cycles of configure, activate, ``--active-s`` of publishing,
deactivate, cleanup (the ``--active-s`` start once this process received ``--samples``
samples of the activation). After each cleanup it reads the node's resident memory (``VmRSS``),
threads and open descriptors from ``/proc``. Reported: the least-squares slope of each
after ``--warm-up`` cycles (and the growth it projects over 1000 cycles), the median of
the last 50 cycles against the first 50 after the warm-up; every bag directory read back
with rosbags (``imu/data_raw`` stamps on the 1 kHz grid, none missing within a period);
the state file byte for byte as after the capture; the node's exit status and its log.
"""

import argparse
import datetime
import importlib.metadata
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'test'))
sys.path.insert(0, str(ROOT / 'bench'))

from boundary_probes import write_section  # noqa: E402

PERIOD_NS = 1_000_000
IMU_TOPIC = '/imu/data_raw'


def proc_status(pid):
    """Return (RSS [MiB], threads, open descriptors) of process ``pid``."""
    fields = {}
    with open(f'/proc/{pid}/status') as status:
        for line in status:
            key, _, value = line.partition(':')
            fields[key] = value.split()
    return (int(fields['VmRSS'][0]) / 1024, int(fields['Threads'][0]),
            len(os.listdir(f'/proc/{pid}/fd')))


def read_bags(recordings):
    """
    Return (bags, readable, samples, bags with a sample missing or off the grid).

    The first bag, the capture's, holds the pause of its schedule (the stream is withheld
    meanwhile): only the grid counts there.
    """
    from rosbags.highlevel import AnyReader
    bags = sorted(path for path in recordings.iterdir() if path.is_dir())
    readable = samples = broken = 0
    for index, bag in enumerate(bags):
        try:
            with AnyReader([bag]) as reader:
                connections = [c for c in reader.connections if c.topic == IMU_TOPIC]
                stamps = []
                for connection, _, raw in reader.messages(connections=connections) \
                        if connections else ():
                    stamp = reader.deserialize(raw, connection.msgtype).header.stamp
                    stamps.append(stamp.sec * 1_000_000_000 + stamp.nanosec)
        except Exception as error:
            print(f'{bag.name}: not readable: {error}', file=sys.stderr)
            continue
        readable += 1
        samples += len(stamps)
        steps = np.diff(np.array(stamps, dtype=np.int64))
        if np.any(steps % PERIOD_NS) or (index and np.any(steps != PERIOD_NS)):
            broken += 1
    return len(bags), readable, samples, broken


def slope(values, start):
    """Return the least-squares slope of ``values[start:]`` per cycle."""
    y = np.asarray(values[start:], dtype=float)
    return float(np.polyfit(np.arange(len(y)), y, 1)[0]) if len(y) > 1 else 0.0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--cycles', type=int, default=1000)
    parser.add_argument('--warm-up', type=int, default=100,
                        help='cycles left out of the slopes (default 100)')
    parser.add_argument('--active-s', type=float, default=0.05,
                        help='publishing time per cycle [s] (default 0.05)')
    parser.add_argument('--samples', type=int, default=10,
                        help='samples received after each activate before --active-s runs')
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', 77)))
    parser.add_argument('--out', type=Path, help='write the section into this file')
    args = parser.parse_args(argv)
    os.environ['QFA_TEST_DOMAINS'] = f'{args.domain}-{args.domain}'
    from lifecycle_msgs.srv import ChangeState
    from node_helpers import Client, NodeProcess
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu
    from std_srvs.srv import Trigger

    from qfa_ros.ros.distro import ros_distribution
    from qfa_ros.ros.state_store import StateStore

    distribution = ros_distribution()
    load_start = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix='qfa_cycles_') as scratch:
        out = Path(scratch) / 'out'
        node = NodeProcess(args.domain, scratch, {
            'output_dir': str(out), 'state_file': str(out / 'state.json'),
            'recorder.enabled': True, 'estimation.realtime': False}, managed=True)
        client = Client(args.domain)
        received = []
        client.node.create_subscription(Imu, 'imu/data_raw', lambda message: received.append(1),
                                        qos_profile_sensor_data)
        rows = []
        try:
            def change(label):
                request = ChangeState.Request()
                request.transition.label = label
                response = client.call(ChangeState, '/qfa_node/change_state', request, 120.0)
                if not response.success:
                    raise SystemExit(f'{label} failed: {node.log()[-3000:]}')

            change('configure')
            change('activate')
            answer = client.call(Trigger, '/qfa_node/capture_reference', Trigger.Request(),
                                 120.0)
            if not answer.success:
                raise SystemExit(f'capture_reference: {answer.message}')
            change('deactivate')
            change('cleanup')
            state = (out / 'state.json').read_bytes()
            started = time.monotonic()
            for cycle in range(args.cycles):
                change('configure')
                count = len(received)
                change('activate')
                client.spin_until(lambda: len(received) >= count + args.samples, 30.0,
                                  f'{args.samples} samples after activate')
                client.spin_for(args.active_s)
                change('deactivate')
                change('cleanup')
                rows.append((time.monotonic() - started, *proc_status(node.pid)))
                if cycle % 100 == 0:
                    print(f'cycle {cycle}: RSS {rows[-1][1]:.1f} MiB, threads {rows[-1][2]}, '
                          f'descriptors {rows[-1][3]}', flush=True)
            seconds = time.monotonic() - started
        finally:
            client.close()
            status = node.stop(signal.SIGTERM, timeout=60.0)
        log = node.log()
        bags, readable, samples, broken = read_bags(out / 'recordings')
        stored = StateStore(str(out / 'state.json'))
        loaded, _ = stored.load()
        state_intact = (out / 'state.json').read_bytes() == state and loaded.has_reference
        errors = [line for line in log.splitlines() if '[ERROR]' in line or 'Traceback' in line]
        # A gap in a period is a stall the node says it had: samples it skipped (held up
        # past the catch-up bound) or messages its publishing thread dropped over 1 s late.
        stalls = [line for line in log.splitlines() if 'skipped: the node was held up' in line
                  or 'messages dropped unpublished' in line]
    rss = [row[1] for row in rows]
    threads = [row[2] for row in rows]
    fds = [row[3] for row in rows]
    start = min(args.warm_up, len(rows) - 1)
    after = rss[start:]
    median_growth = float(np.median(after[-50:]) - np.median(after[:50]))
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    rclpy_version = importlib.metadata.version('ros-rclpy') if distribution else '?'
    interpreter = Path(sys.executable)
    if interpreter.is_relative_to(ROOT):
        interpreter = interpreter.relative_to(ROOT)
    lines = [f'## {distribution.capitalize() if distribution else "Unknown"}', '',
             f'`ROS_DOMAIN_ID={args.domain} {interpreter} '
             f'bench/lifecycle_cycles.py --cycles {args.cycles} --warm-up {args.warm_up} '
             f'--active-s {args.active_s:g} --samples {args.samples} '
             '--out bench/results/lifecycle_cycles.md`', '',
             f'{datetime.date.today()}, commit {commit} (+ working tree), ros-rclpy '
             f'{rclpy_version}, load average {load_start[0]:.1f} at the start, '
             f'{os.getloadavg()[0]:.1f} at the end; {args.cycles} cycles in {seconds:.0f} s '
             f'({seconds / args.cycles:.2f} s each).', '',
             f'| after cycle {start} | slope per cycle | over 1000 cycles | first | last '
             '| min … max |', '|---|---:|---:|---:|---:|---|',
             f'| RSS [MiB] | {slope(rss, start):+.5f} | {1000 * slope(rss, start):+.2f} | '
             f'{after[0]:.1f} | {after[-1]:.1f} | {min(after):.1f} … {max(after):.1f} |',
             f'| threads | {slope(threads, start):+.5f} | {1000 * slope(threads, start):+.1f} '
             f'| {threads[start]} | {threads[-1]} | {min(threads[start:])} … '
             f'{max(threads[start:])} |',
             f'| open descriptors | {slope(fds, start):+.5f} | {1000 * slope(fds, start):+.1f} '
             f'| {fds[start]} | {fds[-1]} | {min(fds[start:])} … {max(fds[start:])} |', '',
             f'RSS, median of the last 50 cycles against the first 50 after cycle {start}: '
             f'{median_growth:+.2f} MiB. RSS over the warm-up: {rss[0]:.1f} MiB after cycle '
             f'0, {rss[start]:.1f} after cycle {start}.', '',
             f'Bag directories: {bags} for {args.cycles + 1} configurations, readable by rosbags '
             f'{readable}; {samples} `imu/data_raw` samples; directories with a sample missing '
             f'or off the 1 kHz grid within their period: {broken} (stalls the node logged, '
             f'samples skipped or dropped late: {len(stalls)}). State file as after the '
             f'capture, loaded with its references: {state_intact}. Node exit status '
             f'{status}; ERROR or traceback lines in its log: {len(errors)}.', '',
             'RSS [MiB] after every 100th cycle: '
             + ', '.join(f'{rss[k]:.1f}' for k in range(0, len(rss), 100)) + '.']
    lines += [f'    {line}' for line in errors[:5]]
    text = '\n'.join(lines)
    print(text)
    if args.out:
        write_section(args.out, lines[0], text, title=TITLE)


TITLE = ('# Configure/cleanup cycles of `qfa_lifecycle_node` (issue 43): what each cycle '
         'leaves behind')


if __name__ == '__main__':
    main()
