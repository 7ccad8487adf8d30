"""A node that always answers and always stops: churn, SIGINT/SIGTERM, a hung teardown."""

import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

from diagnostic_msgs.msg import DiagnosticArray
from node_helpers import Client, domain_id, ImuCollector, NODE, NodeProcess, ROOT
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger

# "Within a few seconds": the node's budget is 2 s to close, 2 s for the middleware;
# the rest is slack for a loaded machine.
STOP_DEADLINE_S = 10.0
CHURN_PARTICIPANTS = 300
CHURN_BUDGET_S = 45.0


@pytest.fixture
def busy_core():
    """Keep one core busy for the duration of the test."""
    spinner = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    yield
    spinner.kill()
    spinner.wait()


def churn(domain, count, budget_s):
    """
    Create and destroy up to ``count`` participants, each subscribing to ``imu/data_raw``.

    Each lives between 0 and 60 ms after its node is up, so that the node discovers some
    fully, some half way and some not at all before they leave. Returns how many ran.
    """
    qos = QoSProfile(depth=5, reliability=ReliabilityPolicy.BEST_EFFORT)
    deadline = time.monotonic() + budget_s
    done = 0
    for index in range(count):
        if time.monotonic() > deadline:
            break
        context = Context()
        rclpy.init(context=context, domain_id=domain)
        try:
            node = Node(f'churn_{index}', context=context)
            node.create_subscription(Imu, 'imu/data_raw', lambda message: None, qos)
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            until = time.monotonic() + (index % 4) * 0.02
            while time.monotonic() < until:
                executor.spin_once(timeout_sec=0.01)
            executor.shutdown()
            node.destroy_node()
        finally:
            rclpy.try_shutdown(context=context)
        done += 1
    return done


def stop_and_time(node, signum):
    """Send ``signum``; return (exit status, seconds until the process ended)."""
    started = time.monotonic()
    status = node.stop(signum, timeout=STOP_DEADLINE_S)
    return status, time.monotonic() - started


def test_node_answers_and_streams_after_hundreds_of_participants(tmp_path, busy_core):
    domain = domain_id('churn')
    node = NodeProcess(domain, tmp_path, {'qos_overrides./imu/data_raw.publisher.depth': 1000,
                                          'output_dir': str(tmp_path)})
    try:
        client = Client(domain)
        imu = ImuCollector(client)
        client.spin_until(lambda: len(imu.samples) > 100, 60, 'the first samples')
        client.close()
        ran = churn(domain, CHURN_PARTICIPANTS, CHURN_BUDGET_S)
        assert ran >= 150, f'only {ran} participants in {CHURN_BUDGET_S} s'
        assert node.process.poll() is None, node.log()
        # A newcomer after the churn finds the node, gets samples and a parameter answer.
        client = Client(domain)
        try:
            client.spin_until(lambda: NODE in client.node.get_node_names(), 30,
                              'the node in the graph')
            imu = ImuCollector(client)
            client.spin_until(lambda: len(imu.samples) > 500, 30, 'samples after the churn')
            assert client.get_parameters(['sample_rate_hz']) == [1000.0]
        finally:
            client.close()
        status, seconds = stop_and_time(node, signal.SIGINT)
    except BaseException:
        node.stop(signal.SIGKILL)
        raise
    assert status == 0, node.log()
    assert seconds < STOP_DEADLINE_S
    assert 'calibration state and recording closed' in node.log()


def test_integers_typed_for_doubles_at_start_are_stored_as_doubles(tmp_path):
    # The parameters file is JSON: 1000 and [1, 2, 3] reach rclpy as integers.
    domain = domain_id('typed')
    node = NodeProcess(domain, tmp_path, {'sample_rate_hz': 1000, 'diagnostics_rate_hz': 2,
                                          'drift.feedback_ppm': [1, 2, 3],
                                          'output_dir': str(tmp_path)})
    client = Client(domain)
    try:
        values = client.get_parameters(
            ['sample_rate_hz', 'diagnostics_rate_hz', 'drift.feedback_ppm'], timeout=60.0)
    finally:
        client.close()
        status = node.stop(signal.SIGINT)
    assert values[:2] == [1000.0, 2.0] and all(type(v) is float for v in values[:2])
    assert list(values[2]) == [1.0, 2.0, 3.0] and all(type(v) is float for v in values[2])
    assert status == 0, node.log()


def test_other_types_typed_for_doubles_at_start_are_refused(tmp_path):
    node = NodeProcess(domain_id('typed'), tmp_path, {'sample_rate_hz': 'fast',
                                                      'output_dir': str(tmp_path)})
    assert node.wait(timeout=60.0) != 0
    assert "'sample_rate_hz' to 'fast' of type 'STRING', expecting type 'DOUBLE'" in node.log()


def test_sigterm_during_a_realtime_schedule_stops_within_seconds(tmp_path):
    domain = domain_id('stop-schedule')
    node = NodeProcess(domain, tmp_path, {
        'estimation.realtime': True, 'state_file': str(tmp_path / 'state.json'),
        'output_dir': str(tmp_path), 'recorder.enabled': True,
        'recorder.directory': str(tmp_path / 'recordings')})
    client = Client(domain)
    try:
        diagnostics = []
        client.subscribe(DiagnosticArray, '/diagnostics', diagnostics.append, depth=10)
        future = client.call_async(Trigger, f'{NODE}/capture_reference', Trigger.Request())

        def schedule_running():
            return any(kv.key == 'schedule running' and kv.value == 'reference'
                       for array in diagnostics[-1:] for status in array.status
                       for kv in status.values)
        client.spin_until(schedule_running, 30, 'the schedule running')
        status, seconds = stop_and_time(node, signal.SIGTERM)
        assert not future.done() or not future.result().success
    except BaseException:
        node.stop(signal.SIGKILL)
        raise
    finally:
        client.close()
    assert status == 0, node.log()
    assert seconds < STOP_DEADLINE_S
    # The recording was finished: a rosbag2 bag directory, no half-written file.
    recordings = tmp_path / 'recordings'
    assert list(recordings.glob('*/metadata.yaml')), node.log()
    assert not list(recordings.glob('**/*.part'))


HUNG_TEARDOWN = textwrap.dedent("""
    import ctypes, sys, time
    from pathlib import Path
    import rclpy
    from qfa_ros.cli.node import shut_down

    class Node:
        def close(self, timeout_s):
            Path(sys.argv[1]).write_text('closed')
        def get_logger(self):
            return rclpy.logging.get_logger('hung')
        def destroy_node(self):
            if sys.argv[2] == 'gil':
                ctypes.PyDLL(None).sleep(60)  # blocks holding the interpreter lock
            else:
                time.sleep(60)

    class Executor:
        def shutdown(self, timeout_sec):
            pass

    shut_down(Node(), Executor(), middleware_timeout_s=0.5)
    print('returned')
""")


@pytest.mark.parametrize('hang, expected_status, words', [
    ('sleep', 3, 'middleware shutdown hung'),
    ('gil', 1, 'Timeout'),
])
def test_a_hung_middleware_teardown_ends_in_a_hard_exit_after_the_writes(
        tmp_path, hang, expected_status, words):
    marker = tmp_path / 'closed'
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    started = time.monotonic()
    completed = subprocess.run([sys.executable, '-c', HUNG_TEARDOWN, str(marker), hang],
                               env=env, capture_output=True, text=True, timeout=30)
    assert time.monotonic() - started < 25
    assert completed.returncode == expected_status, completed.stderr
    assert words in completed.stderr
    assert 'returned' not in completed.stdout
    assert Path(marker).read_text() == 'closed'


def start_line(node, client):
    """Return the node's one start-up line about its calibration state, once logged."""
    def logged():
        return [line for line in node.log().splitlines() if 'calibration state ' in line
                and 'to start fresh' in line]
    client.spin_until(logged, 60, 'the start-up line')
    return logged()


def test_after_the_setup_warm_up_neither_make_run_nor_make_sim_compiles(tmp_path,
                                                                         monkeypatch):
    # make setup runs qfa_ros.cli.warm_cache: a fresh clone's first start then loads every
    # kernel from numba's cache instead of compiling for seconds before its first sample.
    monkeypatch.setenv('NUMBA_CACHE_DIR', str(tmp_path / 'numba'))  # empty, as when cloned
    monkeypatch.setenv('NUMBA_DEBUG_CACHE', '1')
    warm = subprocess.run([sys.executable, '-m', 'qfa_ros.cli.warm_cache'], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert warm.returncode == 0, warm.stderr
    assert 'data saved' in warm.stdout
    simulated = subprocess.run([sys.executable, '-m', 'qfa_ros.cli.sim', 'static',
                                '--duration', '1'], cwd=ROOT, capture_output=True, text=True,
                               timeout=300)
    assert simulated.returncode == 0, simulated.stderr
    assert 'data loaded' in simulated.stdout and 'data saved' not in simulated.stdout
    domain = domain_id('warm-cache')
    node = NodeProcess(domain, tmp_path / 'node', {
        'state_file': str(tmp_path / 'calibration.json'), 'output_dir': str(tmp_path)})
    client = Client(domain)
    try:
        start_line(node, client)  # logged once the first samples are published
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()
    assert 'data loaded' in node.log() and 'data saved' not in node.log()


def test_start_up_lines_come_even_when_no_sample_is_due(tmp_path):
    # The start-up lines wait for the first samples (off their path), but not for ever: with
    # the topic input and nothing publishing it no sample is due, and they still come.
    domain = domain_id('start-line-no-sample')
    node = NodeProcess(domain, tmp_path, {'state_file': str(tmp_path / 'calibration.json'),
                                          'output_dir': str(tmp_path), 'input.mode': 'topic'})
    client = Client(domain)
    try:
        collector = ImuCollector(client)
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert 'Hz on imu/data_raw' in node.log() and 'input topic' in node.log()
        assert not collector.samples
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()


def test_start_up_says_which_state_it_loaded_and_state_fresh_ignores_it(tmp_path):
    from std_msgs.msg import Bool

    state_file = tmp_path / 'calibration.json'
    parameters = {'state_file': str(state_file), 'output_dir': str(tmp_path),
                  'estimation.realtime': False}

    def session(name, extra):
        domain = domain_id(f'start-line-{name}')
        node = NodeProcess(domain, tmp_path / name, {**parameters, **extra})
        client = Client(domain)
        flags = []
        client.subscribe(Bool, f'{NODE}/is_calibrated', flags.append, latched=True)
        return node, client, flags

    # A new user's first session: nothing stored, then a calibration.
    node, client, flags = session('first', {})
    try:
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert f'fresh (no state file at {state_file})' in lines[0]
        assert 'compensation off' in lines[0] and 'unit drawn, seed 1' in lines[0]
        for service in ('capture_reference', 'self_calibrate'):
            response = client.call(Trigger, f'{NODE}/{service}', Trigger.Request(), 120)
            assert response.success, response.message
        client.spin_until(lambda: flags and flags[-1].data, 30, 'is_calibrated true')
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()
    stored = state_file.read_text()

    # The next start (make run again) is compensated, and says so in one line.
    node, client, flags = session('second', {})
    try:
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert f'calibration state loaded from {state_file}: compensation on' in lines[0]
        assert 'state.fresh:=true' in lines[0]
        client.spin_until(lambda: flags, 30, 'is_calibrated')
        assert flags[-1].data is True
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()

    # state.fresh: the stored file is neither loaded nor touched; the sensor is bare.
    node, client, flags = session('fresh', {'state.fresh': True})
    try:
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert f'fresh (state.fresh: {state_file} not loaded)' in lines[0]
        assert 'compensation off (nothing stored)' in lines[0]
        client.spin_until(lambda: flags, 30, 'is_calibrated')
        assert flags[-1].data is False
        response = client.call(Trigger, f'{NODE}/estimate_feedback_gain', Trigger.Request())
        assert not response.success and 'reference' in response.message
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()
    assert state_file.read_text() == stored
