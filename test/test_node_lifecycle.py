"""
A node that starts as it says and always stops: start-up lines, SIGINT/SIGTERM, hung teardown.

Participants coming and going by the hundred: ``bench/boundary_probes.py``.
"""

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
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from qfa_ros.calibration.state import AxisReference, CalibrationState
from qfa_ros.ros.model_settings import make_triad
from qfa_ros.ros.parameter_table import PARAMETERS
from qfa_ros.ros.state_store import StateStore

# "Within a few seconds": the node's budget is 2 s to close, 2 s for the middleware;
# the rest is slack for a loaded machine.
STOP_DEADLINE_S = 10.0


def stop_and_time(node, signum):
    """Send ``signum``; return (exit status, seconds until the process ended)."""
    started = time.monotonic()
    status = node.stop(signum, timeout=STOP_DEADLINE_S)
    return status, time.monotonic() - started


def test_other_types_typed_for_doubles_at_start_are_refused(tmp_path):
    node = NodeProcess(domain_id('typed'), tmp_path, {'sample_rate_hz': 'fast',
                                                      'output_dir': str(tmp_path)})
    assert node.wait(timeout=60.0) != 0
    assert "'sample_rate_hz' to 'fast' of type 'STRING', expecting type 'DOUBLE'" in node.log()


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


def test_start_up_lines_come_without_a_sample_then_a_first_calibration_is_stored(tmp_path):
    # A new user's first session. The start-up lines wait for the first samples (off their
    # path), but not for ever: with the topic input and nothing publishing it no sample is
    # due, and they still come. The parameters file is JSON: 1000 and [1, 2, 3] reach rclpy
    # as integers, and are stored as the doubles they mean.
    state_file = tmp_path / 'calibration.json'
    domain = domain_id('first-session')
    node = NodeProcess(domain, tmp_path / 'first', {
        'state_file': str(state_file), 'output_dir': str(tmp_path), 'input.mode': 'topic',
        'estimation.realtime': False, 'sample_rate_hz': 1000, 'diagnostics_rate_hz': 2,
        'drift.feedback_ppm': [1, 2, 3]})
    client = Client(domain)
    try:
        collector = ImuCollector(client)
        flags = []
        client.subscribe(Bool, f'{NODE}/is_calibrated', flags.append, latched=True)
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert 'Hz on imu/data_raw' in node.log() and 'input topic' in node.log()
        assert not collector.samples
        assert f'fresh (no state file at {state_file})' in lines[0]
        assert 'compensation off' in lines[0] and 'unit drawn, seed 1' in lines[0]
        values = client.get_parameters(
            ['sample_rate_hz', 'diagnostics_rate_hz', 'drift.feedback_ppm'], timeout=60.0)
        assert values[:2] == [1000.0, 2.0] and all(type(v) is float for v in values[:2])
        assert list(values[2]) == [1.0, 2.0, 3.0] and all(type(v) is float for v in values[2])
        # Then a static input and a calibration, stored.
        assert client.set_parameters({'input.mode': 'static'})[0].successful
        for service in ('capture_reference', 'self_calibrate'):
            response = client.call(Trigger, f'{NODE}/{service}', Trigger.Request(), 120)
            assert response.success, response.message
        client.spin_until(lambda: flags and flags[-1].data, 30, 'is_calibrated true')
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()
    assert state_file.exists()


def test_the_next_start_loads_it_a_sigterm_in_a_schedule_stops_and_state_fresh_ignores_it(
        tmp_path):
    # What a first session stored (the test above runs one): references and the words, the
    # compensation on; one copy for the next start, one for a start with state.fresh, the
    # two nodes started at once (their start-ups overlap).
    state_file = tmp_path / 'calibration.json'
    fresh_file = tmp_path / 'calibration_fresh.json'
    triad = make_triad({spec.name: spec.default for spec in PARAMETERS})
    StateStore(str(state_file)).save(CalibrationState(
        references=[AxisReference(73.4, -71739.0, 25.0) for _ in range(3)],
        controller_gain=[loop.controller.gain for loop in triad.axes],
        n_vref=[loop.n_vref for loop in triad.axes]), True)
    stored = state_file.read_text()
    fresh_file.write_text(stored)

    def session(name, extra):
        domain = domain_id(f'start-line-{name}')
        node = NodeProcess(domain, tmp_path / name, {'output_dir': str(tmp_path), **extra})
        client = Client(domain)
        flags = []
        client.subscribe(Bool, f'{NODE}/is_calibrated', flags.append, latched=True)
        return node, client, flags

    # The next start (make run again) is compensated, and says so in one line. A realtime
    # schedule running, SIGTERM stops it within seconds and finishes the recording.
    node, client, flags = session('second', {
        'state_file': str(state_file), 'estimation.realtime': True, 'recorder.enabled': True,
        'recorder.directory': str(tmp_path / 'recordings')})
    fresh = session('fresh', {'state_file': str(fresh_file), 'state.fresh': True})
    try:
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert f'calibration state loaded from {state_file}: compensation on' in lines[0]
        assert 'state.fresh:=true' in lines[0]
        client.spin_until(lambda: flags, 30, 'is_calibrated')
        assert flags[-1].data is True
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
        fresh[0].stop(signal.SIGKILL)
        fresh[1].close()
        raise
    finally:
        client.close()
    second = node

    # state.fresh: the stored file is neither loaded nor touched; the sensor is bare.
    node, client, flags = fresh
    try:
        lines = start_line(node, client)
        assert len(lines) == 1, node.log()
        assert f'fresh (state.fresh: {fresh_file} not loaded)' in lines[0]
        assert 'compensation off (nothing stored)' in lines[0]
        client.spin_until(lambda: flags, 30, 'is_calibrated')
        assert flags[-1].data is False
        response = client.call(Trigger, f'{NODE}/estimate_feedback_gain', Trigger.Request())
        assert not response.success and 'reference' in response.message
    finally:
        client.close()
        assert node.stop(signal.SIGINT) == 0, node.log()
    assert fresh_file.read_text() == stored

    assert status == 0, second.log()
    assert seconds < STOP_DEADLINE_S
    # The recording was finished: a rosbag2 bag directory, no half-written file.
    recordings = tmp_path / 'recordings'
    assert list(recordings.glob('*/metadata.yaml')), second.log()
    assert not list(recordings.glob('**/*.part'))
