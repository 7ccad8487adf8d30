"""What a stray participant can try on the node, and what the node refuses or undoes.

The attacks on the parameters, against both executables in every state, are the boundary's
(``test_node_fuzz.py``); these are the schedules, the disk, DDS Security and the bounds.
"""

import signal
import subprocess
import sys
import time
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from node_helpers import (
    Client,
    domain_id,
    ImuCollector,
    largest_schedule_values,
    node_environment,
    NodeProcess,
    RecordingNode,
    ROOT,
)
import pytest
from rosbags.highlevel import AnyReader
from std_srvs.srv import Trigger

from qfa_ros.ros import recording as recording_module
from qfa_ros.ros.bounds import (
    CHAMBER_WORST_S,
    confined_directory,
    MAX_SCHEDULE_LOOP_STEPS,
    SCHEDULE_WORST_S,
)
from qfa_ros.ros.parameter_checks import check_all
from qfa_ros.ros.parameter_table import PARAMETERS
from qfa_ros.ros.recording import FreeSpaceGuard, GUARD_BAND_BYTES, StreamRecording
from qfa_ros.ros.service_table import SCHEDULE_SERVICES

NODE = '/qfa_node'
STRING = b'\x00\x01\x00\x00\x02\x00\x00\x00'
"""CDR of std_msgs/String: encapsulation, then the length of one character and NUL."""
FORWARD_DRIFT_PPM = [500.0, -300.0, 200.0]
# Short realtime schedules: a forward sweep of 5 x 0.32 s, then 8 chopped I_ref segments
# of 1.05 s, so that a cancel lands in the middle of either part.
SCHEDULES = {'estimation.forward.points': 4, 'estimation.forward.average_s': 0.3,
             'estimation.forward.settle_s': 0.02, 'estimation.feedback.cycles': 2,
             'estimation.feedback.order': 'chopped', 'estimation.feedback.average_s': 1.0,
             'estimation.feedback.settle_s': 0.05}
# Every schedule service of the table, by kind: each is cancelled and undone below.
SERVICES = {spec.kind: spec.call for spec in SCHEDULE_SERVICES}


def defaults(**changes):
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update(changes)
    return values


def statuses(diagnostics):
    return {s.name.rsplit(': ', 1)[1]: s for s in diagnostics[-1].status}


def key_values(status):
    return {kv.key: kv.value for kv in status.values}


@pytest.fixture
def setup(tmp_path_factory):
    # One test uses it: a module-scoped node streamed on through the five tests after it.
    directory = tmp_path_factory.mktemp('security')
    output = directory / 'output'
    domain = domain_id('security')
    node = NodeProcess(domain, directory, {
        'qos_overrides./imu/data_raw.publisher.depth': 1000, 'diagnostics_rate_hz': 10.0,
        'output_dir': str(output),
        'state_file': str(directory / 'state.json'), 'estimation.realtime': False,
        **SCHEDULES})
    client = Client(domain)
    imu = ImuCollector(client)
    diagnostics = []
    client.subscribe(DiagnosticArray, '/diagnostics', diagnostics.append, depth=10)
    client.spin_until(lambda: imu.samples and diagnostics, 60, 'the node')
    yield SimpleNamespace(node=node, client=client, imu=imu, diagnostics=diagnostics,
                          directory=directory, output=output)
    client.close()
    node.stop(signal.SIGKILL)


def trigger(client, service):
    return client.call(Trigger, f'{NODE}/{service}', Trigger.Request())


def sensor_values(calibration):
    """Return the ``calibration`` key values without the last schedule's progress report."""
    return {k: v for k, v in calibration.items()
            if k != 'schedule running' and not k.startswith(('schedule ', 'sensor time '))}


def test_cancel_restores_the_sensor_for_every_schedule_kind(setup):
    client, imu, diagnostics = setup.client, setup.imu, setup.diagnostics
    response = trigger(client, 'cancel')
    assert not response.success and response.message == 'no schedule running'
    # A calibrated sensor with a state file, then a forward-gain drift the schedules see.
    response = trigger(client, 'capture_reference')
    assert response.success, response.message
    state_file = setup.directory / 'state.json'
    saved = state_file.read_bytes()
    saved_mtime = state_file.stat().st_mtime_ns
    results = client.set_parameters({'drift.forward_ppm': FORWARD_DRIFT_PPM,
                                     'estimation.realtime': True,
                                     'temperature_calibration.period_s': 4500.0,
                                     'temperature_calibration.cycles': 1})
    assert all(r.successful for r in results), [r.reason for r in results]
    count = len(diagnostics)
    client.spin_until(lambda: len(diagnostics) > count + 1, 10, 'diagnostics')
    before = key_values(statuses(diagnostics)['calibration'])
    compensating = key_values(statuses(diagnostics)['temperature'])['temperature compensation']
    assert before['has reference'] == 'True' and before['compensation'] == 'on'

    for kind, service in SERVICES.items():
        pending = client.call_async(Trigger, f'{NODE}/{service}', Trigger.Request())
        if kind in ('reference', 'self_calibrate'):
            # Into the feedback part: the forward part has captured or applied by now.
            def in_feedback():
                if not diagnostics:
                    return False
                status = statuses(diagnostics)
                running = key_values(status['calibration'])['schedule running'] == kind
                return running and key_values(status['stream'])['I_ref x'] == 'on'
            client.spin_until(in_feedback, 30, f'{kind} in its feedback part')
        while True:
            assert not pending.done(), pending.result().message
            response = trigger(client, 'cancel')
            if response.success:
                break
            assert response.message == 'no schedule running', response.message
            client.spin_for(0.05)
        cancelled_ns = time.time_ns()
        assert kind in response.message
        client.spin_until(pending.done, 1.0, f'the cancelled {kind} call to answer')
        answer = pending.result()
        assert not answer.success and 'cancelled' in answer.message, answer.message
        imu.clear(cancelled_ns)
        client.spin_until(lambda: len(imu.samples) >= 100, 10, f'imu/data_raw after {kind}')
        count = len(diagnostics)
        client.spin_until(lambda: len(diagnostics) > count + 1, 10, 'fresh diagnostics')
        status = statuses(diagnostics)
        after = key_values(status['calibration'])
        assert after['schedule running'] == 'none'
        assert after['schedule outcome'].startswith('cancelled'), after['schedule outcome']
        # The words, switches and state as before the call; what the last schedule did
        # (its outcome, phase and progress) is the progress report's, not the sensor's.
        assert sensor_values(after) == sensor_values(before), kind
        stream = key_values(status['stream'])
        assert [stream[f'loop {a}'] for a in 'xyz'] == ['closed'] * 3
        assert [stream[f'I_ref {a}'] for a in 'xyz'] == ['off'] * 3
        temperature = key_values(status['temperature'])
        assert temperature['ambient profile'] == 'room'   # the node's default, back
        assert temperature['temperature compensation'] == compensating
        assert state_file.read_bytes() == saved
        assert state_file.stat().st_mtime_ns == saved_mtime

    # The references are those of the first capture, not the drifted ones the cancelled
    # capture had measured: a forward estimate still sees the whole drift.
    assert client.set_parameters({'estimation.realtime': False})[0].successful
    response = trigger(client, 'estimate_forward_gain')
    assert response.success, response.message
    estimate = response.message.split('forward gain drift [ppm] ', 1)[1].split(';')[0]
    values = [float(part.split()[1].split('±')[0]) for part in estimate.split(', ')]
    # The drifted references would give ~0. The margin: the schedules above advanced the
    # sensor time by as much as the cancels let them (more on a busy machine), over which
    # the default room wanders; 0.5 degC moves I_ref by 15 ppm on every axis (30 ppm/degC,
    # not compensated without a temperature calibration): -14 ppm was seen once.
    assert values == pytest.approx(FORWARD_DRIFT_PPM, abs=30.0)
    errors = [value - drift for value, drift in zip(values, FORWARD_DRIFT_PPM)]
    assert max(errors) - min(errors) < 10.0  # a common-mode shift, not per-axis errors


def test_security_enabled_without_security_exits_with_one_line(tmp_path):
    keystore = tmp_path / 'keystore'
    enclave = keystore / 'enclaves' / 'qfa'
    enclave.mkdir(parents=True)
    for name in ('identity_ca.cert.pem', 'cert.pem', 'key.pem', 'permissions_ca.cert.pem',
                 'governance.p7s', 'permissions.p7s'):
        (enclave / name).write_text('not a certificate\n')
    env = node_environment(domain_id('security_env'))
    cases = {
        'permissive, no enclave': ({'ROS_SECURITY_ENABLE': 'true',
                                    'ROS_SECURITY_STRATEGY': 'Permissive',
                                    'ROS_SECURITY_KEYSTORE': str(tmp_path / 'missing')}, []),
        'enforce, enclave': ({'ROS_SECURITY_ENABLE': 'true', 'ROS_SECURITY_STRATEGY': 'Enforce',
                              'ROS_SECURITY_KEYSTORE': str(keystore)}, ['--enclave', '/qfa']),
        'security spelled True': ({'ROS_SECURITY_ENABLE': 'True'}, []),
        'missing parameters file': ({}, ['--params-file', str(tmp_path / 'missing.yaml')]),
    }
    processes = {
        case: subprocess.Popen(
            [sys.executable, '-m', 'qfa_ros.cli.node', '--ros-args', *args],
            env={**env, **extra}, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            cwd=ROOT)
        for case, (extra, args) in cases.items()}
    for case, process in processes.items():
        out, err = process.communicate(timeout=120)
        assert process.returncode == 1, (case, out, err)
        assert 'Traceback' not in out + err, (case, err)
        lines = [line for line in err.splitlines() if '[qfa_node]' in line]
        assert len(lines) == 1, (case, err)
        line = lines[0]
        if case == 'missing parameters file':
            assert 'cannot start' in line and 'params file' in line, line
        else:
            assert 'ROS_SECURITY_ENABLE' in line and 'Fast DDS' in line, line
            assert 'publishing' not in out + err and 'Hz on imu/data_raw' not in out + err


def test_paths_are_confined_to_the_output_directory(tmp_path):
    base = tmp_path / 'base'
    (base / 'inside').mkdir(parents=True)
    (base / 'escape').symlink_to(tmp_path, target_is_directory=True)
    values = defaults(output_dir=str(base))
    for value, expected in (('traces', base / 'traces'), (str(base / 'inside' / 'x'),
                                                          base / 'inside' / 'x'),
                            ('inside/../traces', base / 'traces'), ('.', base)):
        values['trace_dir'] = value
        assert confined_directory(values, 'trace_dir') == expected.resolve()
        assert check_all(values) is None
    for value in ('escape/traces', '..', str(tmp_path), '~/traces', ''):
        values['trace_dir'] = value
        with pytest.raises(ValueError, match='trace_dir'):
            confined_directory(values, 'trace_dir')
        assert 'trace_dir' in check_all(values)


def test_schedule_bounds_hold_at_any_loop_rate():
    # The worst case the ranges allow, stated in the descriptions and docs/security.md.
    assert SCHEDULE_WORST_S == pytest.approx(911.6)
    # The chamber program with its soaks (at the extremes, back to the start) fits the
    # loop-step budget at the default 10 kHz loop.
    assert 14000.0 < CHAMBER_WORST_S <= 18000.0
    assert MAX_SCHEDULE_LOOP_STEPS == 18000.0 * 10000.0
    # The largest schedules, from the one place that bounds them (they run in
    # test_trust_boundary.py).
    worst = largest_schedule_values()
    assert check_all(worst) is None
    # A faster loop costs more CPU per sensor second: the loop-step budget then refuses.
    reason = check_all({**worst, 'loop_rate_hz': 100000.0})
    assert 'temperature_calibration.period_s' in reason and 'loop steps' in reason
    reason = check_all({**worst, 'loop_rate_hz': 1.0e6,
                        'temperature_calibration.period_s': 600.0,
                        'temperature_calibration.cycles': 1})
    assert 'estimation.forward' in reason


class FakeUsage:
    """``shutil.disk_usage`` of a file system whose free space the test sets."""

    def __init__(self, free):
        self.free = free

    def __call__(self, path):
        return SimpleNamespace(total=1 << 40, used=0, free=self.free)


def test_recorder_stops_before_the_free_space_floor(tmp_path, monkeypatch):
    # Check at every message instead of every second.
    monkeypatch.setattr(recording_module, 'FREE_SPACE_CHECK_S', 0.0)
    floor = 1 << 30
    usage = FakeUsage(floor + GUARD_BAND_BYTES + (1 << 20))
    values = defaults(**{'output_dir': str(tmp_path), 'recorder.enabled': True,
                         'min_free_bytes': floor})
    recording = StreamRecording(RecordingNode(), values, {}, FreeSpaceGuard(floor, usage))
    recording.restart()
    assert recording.active
    stamp = time.time_ns()
    recording.record('/chatter', 'std_msgs/msg/String', STRING + b'a\x00',
                     stamp)
    assert recording.active
    recording.record('/chatter', 'std_msgs/msg/String', STRING + b'b\x00',
                     stamp + 1)
    assert recording.active
    path = recording.current_path
    usage.free = floor + GUARD_BAND_BYTES - 1
    recording.record('/chatter', 'std_msgs/msg/String', STRING + b'c\x00',
                     stamp + 2)
    assert not recording.active
    assert recording.problem_level == DiagnosticStatus.ERROR
    assert 'recording stopped' in recording.problem and 'min_free_bytes' in recording.problem
    # One bag directory (rosbag2 layout): its metadata and the finished file, no .part.
    bag, = (tmp_path / 'recordings').iterdir()
    assert sorted(p.name for p in bag.iterdir()) == sorted([path.name, 'metadata.yaml']), \
        'a partial file or a file under another name'
    with AnyReader([path]) as reader:
        assert sum(c.msgcount for c in reader.connections) == 3
    # Below the floor a recording does not even start.
    recording.restart()
    assert not recording.active and recording.problem_level == DiagnosticStatus.ERROR
    assert 'recorder not started' in recording.problem


def test_floor_refuses_traces_and_recording_on_a_running_node(tmp_path):
    domain = domain_id('floor')
    node = NodeProcess(domain, tmp_path, {
        'output_dir': str(tmp_path / 'output'), 'state_file': '', 'recorder.enabled': True,
        'min_free_bytes': 2 ** 50, 'estimation.realtime': False, 'diagnostics_rate_hz': 10.0,
        **SCHEDULES})
    client = Client(domain)
    try:
        imu = ImuCollector(client)
        diagnostics = []
        client.subscribe(DiagnosticArray, '/diagnostics', diagnostics.append, depth=10)
        client.spin_until(lambda: imu.samples and diagnostics, 60, 'the node')
        stream = statuses(diagnostics)['stream']
        assert stream.level == DiagnosticStatus.ERROR
        assert 'recorder not started' in stream.message
        assert 'min_free_bytes' in stream.message
        response = trigger(client, 'capture_reference')
        assert not response.success
        assert 'trace not written' in response.message and 'min_free_bytes' in response.message
        count = len(imu.samples)
        client.spin_until(lambda: len(imu.samples) > count + 100, 10, 'the stream')
        assert not (tmp_path / 'output' / 'traces').exists() or \
            not any((tmp_path / 'output' / 'traces').iterdir())
    finally:
        client.close()
        assert node.stop() == 0
