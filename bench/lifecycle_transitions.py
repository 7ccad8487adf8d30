"""The managed node's transition table: each transition, its effect and its time.

Run (the table in ``bench/results/lifecycle_39.md``)::

    .venv/bin/python bench/lifecycle_transitions.py --starts 3 --cycles 3 --domain 190

``--starts`` processes of ``qfa_lifecycle_node`` are started one after the other, fresh
(``output_dir`` and ``state_file`` in an empty temporary directory, the flight recorder
on unless ``--no-recorder``, every other parameter at its default), on a ROS domain of
their own with the localhost-only discovery and the node's Fast DDS profile, with this
interpreter (so a venv of the Jazzy wheels measures Jazzy). This process is the other
participant: it asks for every transition through ``~/change_state``
(``lifecycle_msgs/srv/ChangeState``) and times each call, from the request to the answer
(wall time), ``--cycles`` times per process:

    configure, activate, deactivate, activate, deactivate during a running
    capture_reference (which it cancels), cleanup

then configure, activate and shutdown once per process. A ``~/get_state`` call beside
each cycle times a service round trip with no work behind it. A SensorDataQoS subscriber
(best effort, depth 5) on ``imu/data_raw`` measures, per activation, the time from the
request to the first sample received, and checks that no sample stamped after a
deactivation's answer (and before the next activation) arrives. The table gives the
median and the largest of each; the load average is printed beside it (the times are
wall times: on a busy machine they grow with the load).
"""

import argparse
import importlib.metadata
import json
import os
from pathlib import Path
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = Path(__file__).resolve().parents[1]
PROFILES_FILE = ROOT / 'config' / 'fastdds_discovery.xml'
NODE = 'qfa_node'

EFFECTS = {
    'configure (first)': 'parameters checked, trajectory and state files read, model built, '
                         'entities created, recording opened, sensor thread started '
                         '(nothing published)',
    'configure (again)': 'the same after a cleanup (modules loaded, numba kernels cached)',
    'activate': 'lifecycle publishers enabled, publishing from the first sample stamped '
                'after the transition, timers and services live',
    'deactivate': 'publishing stopped (none after the answer), the recording file finished '
                  '(recorder on), services answer inactive; the sensor runs on',
    'deactivate (schedule running)': 'the same, the running capture_reference cancelled and '
                                     'the sensor restored as ~/cancel does',
    'cleanup': 'sensor thread stopped, state saved, recording finished, entities removed',
    'shutdown (from active)': 'deactivate and cleanup in one, finalized',
    'get_state (reference)': 'a lifecycle service round trip with nothing behind it',
    'activate to first sample': 'from the activate request to the first sample received',
}


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--starts', type=int, default=3, help='node processes (default 3)')
    parser.add_argument('--cycles', type=int, default=3,
                        help='configure ... cleanup cycles per process (default 3)')
    parser.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID',
                                                                         '190')))
    parser.add_argument('--no-recorder', action='store_true',
                        help='leave the flight recorder off (default: on)')
    return parser.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('FASTDDS_DEFAULT_PROFILES_FILE', str(PROFILES_FILE))
    # Imported once the environment is set: rclpy reads it at init.
    from lifecycle_msgs.srv import ChangeState, GetState
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu
    from std_srvs.srv import Trigger

    rclpy.init()
    client_node = rclpy.create_node('lifecycle_bench')
    executor = SingleThreadedExecutor()
    executor.add_node(client_node)
    received = []  # (stamp ns, wall time received ns)
    client_node.create_subscription(
        Imu, '/imu/data_raw', lambda m: received.append(
            (m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec, time.time_ns())),
        qos_profile_sensor_data)
    clients = {}

    def call(srv_type, name, request, timeout=120.0):
        if name not in clients:
            clients[name] = client_node.create_client(srv_type, f'/{NODE}/{name}')
        client = clients[name]
        deadline = time.monotonic() + timeout
        while not client.service_is_ready():
            if time.monotonic() > deadline:
                raise TimeoutError(f'service {name}')
            executor.spin_once(timeout_sec=0.05)
        started = time.perf_counter()
        future = client.call_async(request)
        while not future.done():
            if time.monotonic() > deadline:
                raise TimeoutError(f'answer of {name}')
            executor.spin_once(timeout_sec=0.01)
        return future, time.perf_counter() - started

    def wait_for_node(timeout=120.0):
        """Return once this node answers get_state (a request sent before the match is lost)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                call(GetState, 'get_state', GetState.Request(), timeout=5.0)
                return
            except TimeoutError:
                if time.monotonic() > deadline:
                    raise

    times = {name: [] for name in EFFECTS}
    violations = []

    def change(label, key):
        request = ChangeState.Request()
        request.transition.label = label
        future, seconds = call(ChangeState, 'change_state', request)
        if not future.result().success:
            raise RuntimeError(f'{label} refused')
        times[key].append(seconds)
        return time.time_ns()

    def spin_for(seconds):
        until = time.monotonic() + seconds
        while time.monotonic() < until:
            executor.spin_once(timeout_sec=0.01)

    def activate():
        asked = time.time_ns()
        change('activate', 'activate')
        deadline = time.monotonic() + 30.0
        while not any(stamp >= asked for stamp, _ in received):
            if time.monotonic() > deadline:
                raise TimeoutError('no sample after activate')
            executor.spin_once(timeout_sec=0.005)
        first = min(arrived for stamp, arrived in received if stamp >= asked)
        times['activate to first sample'].append((first - asked) / 1e9)
        spin_for(0.5)

    def deactivate(key):
        answered = change('deactivate', key)
        spin_for(0.3)  # what is still in flight arrives; nothing stamped later may
        violations.extend(stamp for stamp, _ in received if stamp > answered)
        received.clear()

    for start in range(args.starts):
        directory = Path(tempfile.mkdtemp(prefix='qfa_lifecycle_bench_'))
        params = directory / 'params.yaml'
        params.write_text(json.dumps({NODE: {'ros__parameters': {
            'output_dir': str(directory), 'state_file': str(directory / 'state.json'),
            'recorder.enabled': not args.no_recorder}}}))
        log = open(directory / 'node.log', 'w')
        process = subprocess.Popen(
            [sys.executable, '-c', 'import sys; from qfa_ros.cli.node import lifecycle_main; '
             'sys.exit(lifecycle_main())', '--ros-args', '--params-file', str(params)],
            env={**os.environ, 'PYTHONPATH': str(ROOT)}, stdout=log, stderr=subprocess.STDOUT)
        try:
            wait_for_node()
            for cycle in range(args.cycles):
                change('configure', 'configure (first)' if cycle == 0 else 'configure (again)')
                times['get_state (reference)'].append(
                    call(GetState, 'get_state', GetState.Request())[1])
                activate()
                deactivate('deactivate')
                activate()
                call(Trigger, 'cancel', Trigger.Request())  # the service matched
                client = clients.setdefault('capture_reference', client_node.create_client(
                    Trigger, f'/{NODE}/capture_reference'))
                while not client.service_is_ready():
                    executor.spin_once(timeout_sec=0.05)
                schedule = client.call_async(Trigger.Request())
                busy, _ = call(Trigger, 'capture_reference', Trigger.Request())
                if not busy.result().message.startswith('busy'):
                    raise RuntimeError(f'no schedule running: {busy.result().message}')
                deactivate('deactivate (schedule running)')
                while not schedule.done():
                    executor.spin_once(timeout_sec=0.01)
                change('cleanup', 'cleanup')
                # The unit's services go with it: new clients for the next configuration's.
                for name in ('capture_reference', 'cancel'):
                    client_node.destroy_client(clients.pop(name))
            change('configure', 'configure (again)')
            activate()
            change('shutdown', 'shutdown (from active)')
            print(f'start {start + 1}/{args.starts} done', file=sys.stderr, flush=True)
        finally:
            # The next process gets clients of its own: these matched this one's services.
            for client in clients.values():
                client_node.destroy_client(client)
            clients.clear()
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            log.close()
            shutil.rmtree(directory, ignore_errors=True)

    load = os.getloadavg()[0]
    try:
        rclpy_version = f'ros-rclpy {importlib.metadata.version("ros-rclpy")}'
    except importlib.metadata.PackageNotFoundError:
        rclpy_version = 'rclpy of a ROS 2 installation'
    command = ' '.join([os.path.relpath(sys.executable, ROOT), *sys.argv])
    print(f'`{command}` ({rclpy_version}; flight recorder '
          f'{"off" if args.no_recorder else "on"}; load average {load:.2f} at the end)\n')
    print('| transition | effect | n | median [ms] | max [ms] |')
    print('|---|---|---:|---:|---:|')
    for name, effect in EFFECTS.items():
        values = times[name]
        print(f'| {name} | {effect} | {len(values)} | {statistics.median(values) * 1e3:.1f} | '
              f'{max(values) * 1e3:.1f} |')
    print(f'\nSamples stamped after a deactivate answer received: {len(violations)}')
    executor.shutdown()
    client_node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
