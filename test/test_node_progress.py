"""
A long schedule's progress where a ROS user looks: ``/diagnostics`` and the node's log.

One node for every schedule, in real time and as fast as the CPU allows
(``estimation.realtime``), its diagnostics at 10 Hz so that a short schedule shows several.
"""

import re
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray
from node_helpers import Client, domain_id, NodeProcess
import pytest
from std_srvs.srv import Trigger

from qfa_ros.ros.service_table import SCHEDULE_SERVICES, SERVICE

NODE = '/qfa_node'
REALTIME = {'estimation.realtime': True, 'estimation.forward.points': 2,
            'estimation.forward.average_s': 0.5, 'estimation.feedback.cycles': 1,
            'estimation.feedback.order': 'single', 'estimation.feedback.average_s': 0.6,
            'gyro_bias.duration_s': 2.0}
"""Short schedules (1.3-2.9 s) that still last several diagnostics periods after the half
second before a real-time pace is told (``progress.REALTIME_PACE_AFTER_S``)."""
FAST = {'estimation.realtime': False, 'estimation.forward.points': 20,
        'estimation.forward.average_s': 2.0, 'estimation.feedback.cycles': 2,
        'estimation.feedback.order': 'chopped', 'estimation.feedback.average_s': 5.0,
        'gyro_bias.duration_s': 60.0}
"""Schedules of 40-80 s of sensor time: a few tenths of a CPU second each."""
MODES = {'realtime': REALTIME, 'fast': FAST}
KINDS = {spec.call: spec.kind for spec in SCHEDULE_SERVICES}
"""Every schedule service, from the service table, with its kind."""
BOTH = ['forward: loops open', 'forward: loops re-closed', 'feedback: I_ref steps']
TEMPERATURE = ['tumble at the starting temperature']
for _index, _at in enumerate(('20', '30', r'2\d(\.\d+)?')):
    TEMPERATURE += [f'plateau {_index + 1} of 3 at {_at} degC',
                    f'plateau {_index + 1} of 3 at {_at} degC: I_ref steps']
PHASES = {'capture_reference': BOTH, 'estimate_forward_gain': ['loops open', 'loops re-closed'],
          'estimate_feedback_gain': ['I_ref steps'], 'self_calibrate': BOTH,
          'calibrate_gyros': ['averaging'], 'calibrate_temperature': [*TEMPERATURE, 'fitting']}
"""Every phase each schedule logs, in order (regular expressions of the phase's name)."""
LOG_LINE = re.compile(r'\]: (\w+): (.+) \((\d+) % done, at most ([\d.]+) s of sensor time '
                      r'left\)$')


@pytest.fixture(scope='module')
def setup(tmp_path_factory):
    directory = tmp_path_factory.mktemp('progress')
    domain = domain_id('progress')
    # A short chamber program: 20, 30 and back to the room's 25 degC, 100 s of plateaus; a
    # 10 s body time constant lets the extremes settle within a few tumbles.
    parameters = {'diagnostics_rate_hz': 10.0, 'output_dir': str(directory),
                  'state_file': str(directory / 'state.json'),
                  'trace_dir': str(directory / 'traces'), 'thermal.sensor_tau_s': 10.0,
                  'temperature_calibration.low_c': 20.0, 'temperature_calibration.high_c': 30.0,
                  'temperature_calibration.period_s': 100.0, 'estimation.forward.step': 500,
                  'estimation.forward.settle_s': 0.0, 'estimation.feedback.settle_s': 0.02}
    node = NodeProcess(domain, directory, parameters)
    client = Client(domain)
    seen = []
    client.subscribe(DiagnosticArray, '/diagnostics', lambda array: seen.append(snapshot(array)),
                     depth=50)
    client.spin_until(lambda: seen, 60, 'the node')
    yield {'node': node, 'client': client, 'seen': seen}
    client.close()
    node.stop(signal.SIGKILL)


def snapshot(array):
    """Return the calibration and stream statuses of a diagnostics message, as text."""
    statuses = {status.name.rsplit(': ', 1)[1]: status for status in array.status}
    calibration, stream = statuses['calibration'], statuses['stream']
    return {'values': {kv.key: kv.value for kv in calibration.values},
            'message': calibration.message, 'stream': stream.message,
            'stream_values': {kv.key: kv.value for kv in stream.values}}


def call_and_watch(setup, service, cancel=False):
    """Call ``service`` with the diagnostics watched; return the answer, snapshots, log, time."""
    client, seen, node = setup['client'], setup['seen'], setup['node']
    logged = len(node.log())
    seen.clear()
    started = time.monotonic()
    future = client.call_async(Trigger, f'{NODE}/{service}', Trigger.Request())
    if cancel:
        client.spin_until(lambda: future.done() or any(
            float(s['values']['schedule progress [%]']) > 0 for s in running(seen)), 60,
            f'{service} under way')
        stopped = client.call(Trigger, f'{NODE}/cancel', Trigger.Request())
        assert stopped.success, stopped.message
    client.spin_until(future.done, 120, f'the answer of {service}')
    elapsed = time.monotonic() - started
    answered = len(seen)
    # What the diagnostics say once the call has answered (its busy state cleared).
    client.spin_until(lambda: any(s['values']['schedule running'] == 'none'
                                  for s in seen[answered:]), 30, 'diagnostics after the answer')
    return future.result(), list(seen), node.log()[logged:], elapsed


def running(seen):
    return [s for s in seen if s['values'].get('schedule outcome') == 'running']


def phase_lines(log, kind):
    """Return (phase, percent done, sensor time left) of every phase line ``kind`` logged."""
    found = [LOG_LINE.search(line) for line in log.splitlines()]
    return [(m[2], int(m[3]), float(m[4])) for m in found if m and m[1] == kind]


def assert_in_order(names, patterns):
    """Assert that every name matches a pattern, the patterns in their order."""
    position = 0
    for name in names:
        while position < len(patterns) and not re.fullmatch(patterns[position], name):
            position += 1
        assert position < len(patterns), f'{name!r} out of order in {names}'


CASES = [(mode, service) for mode in MODES for service in KINDS]


@pytest.mark.parametrize('mode, service', CASES, ids=[f'{m}-{s}' for m, s in CASES])
def test_a_schedule_says_its_phase_progress_and_time_left(setup, mode, service):
    client = setup['client']
    results = client.set_parameters(MODES[mode])
    assert all(r.successful for r in results), [r.reason for r in results]
    kind = KINDS[service]
    response, seen, log, elapsed = call_and_watch(setup, service)
    assert response.success, response.message

    # One INFO line a phase: every phase in order, how far it is, what is left at most.
    lines = phase_lines(log, kind)
    names = [name for name, _, _ in lines]
    assert len(names) == len(PHASES[service]), names
    assert all(re.fullmatch(p, n) for p, n in zip(PHASES[service], names)), names
    assert [percent for _, percent, _ in lines] == sorted(p for _, p, _ in lines)
    left = [seconds for _, _, seconds in lines]
    assert left == sorted(left, reverse=True) and (len(left) == 1 or left[-1] < left[0]), left

    # While it runs: the phase in words, the fraction only going up, the time left going
    # down, imu/data_raw withheld (the calibration and the stream status alike).
    first = next(i for i, s in enumerate(seen) if s['values'].get('schedule outcome') == 'running')
    seen = seen[first:]
    during = running(seen)
    assert len(during) >= (2 if mode == 'realtime' else 1), (mode, service, len(during))
    phases = [s['values']['schedule phase'] for s in during]
    assert all(phase.startswith(f'{kind}: ') for phase in phases), phases
    assert_in_order([phase[len(kind) + 2:].split(', ')[0] for phase in phases], PHASES[service])
    for s in during:
        assert s['message'].startswith(f'{kind}: ') and 'imu/data_raw withheld' in s['message']
        assert s['values']['imu/data_raw'].startswith('withheld since ')
        assert s['stream_values']['imu/data_raw'].startswith('withheld since ')
        assert s['stream'].startswith('paused: ') and 'imu/data_raw withheld since' in s['stream']
    percents = [float(s['values']['schedule progress [%]']) for s in seen]
    assert percents == sorted(percents) and percents[-1] == 100.0, percents
    sensor_left = [float(s['values']['sensor time left at most [s]']) for s in during]
    assert sensor_left == sorted(sensor_left, reverse=True), sensor_left
    wall_left = [float(s['values']['wall time left [s]']) for s in during
                 if s['values']['wall time left [s]'] != 'unknown']
    assert wall_left and min(wall_left) >= 0.0, wall_left
    if mode == 'realtime':
        # At the node clock the pace is steady; as fast as the CPU allows, the wall time
        # left follows the machine's load and may rise between two reports.
        assert wall_left[-1] <= wall_left[0], wall_left
    if len(during) >= 2:
        assert sensor_left[-1] < sensor_left[0], sensor_left

    # The answer: 100 %, the schedule done; imu/data_raw no longer withheld.
    final = seen[-1]['values']
    assert final['schedule outcome'] == 'done' and final['schedule progress [%]'] == '100.0'
    assert 'imu/data_raw' not in final and 'withheld' not in seen[-1]['stream']
    done_s = float(final['sensor time done [s]'])
    pace = [float(s['values']['pace [sensor s per wall s]']) for s in during
            if s['values']['pace [sensor s per wall s]'] != 'unknown'][-1]
    if mode == 'realtime' and not SERVICE[f'~/{service}'].always_fast:
        # At the node clock (computed up to stream.lead_s ahead): a sensor second a second.
        assert elapsed > done_s - 0.3 and 0.5 < pace < 1.5, (elapsed, done_s, pace)
    else:
        # As fast as the CPU allows; the temperature calibration whatever the flag.
        assert elapsed < done_s and pace > 2.0, (elapsed, done_s, pace)


ENDINGS = [('realtime', 'calibrate_gyros', 'cancelled through ~/cancel'),
           ('fast', 'calibrate_temperature', 'cancelled through ~/cancel'),
           ('fast', 'capture_reference', 'failed')]


@pytest.mark.parametrize('mode, service, outcome', ENDINGS,
                         ids=[f'{m}-{s}-{o.split()[0]}' for m, s, o in ENDINGS])
def test_a_cancelled_or_failed_schedule_says_so_until_the_next(setup, mode, service, outcome):
    client = setup['client']
    kind = KINDS[service]
    # No motion allowed at all: the first I_ref segment reads its noise as a move.
    limit = 1.0e-3 if outcome == 'failed' else 200.0
    results = client.set_parameters({**MODES[mode], 'estimation.feedback.motion_limit_ug': limit})
    assert all(r.successful for r in results), [r.reason for r in results]
    response, seen, _, _ = call_and_watch(setup, service, cancel=outcome != 'failed')
    assert not response.success and outcome.split()[0] in response.message, response.message
    # How it ended, its last phase and fraction, in the calibration status; the stream
    # publishes again.
    last = seen[-1]
    values = last['values']
    assert values['schedule outcome'] == outcome
    percent = float(values['schedule progress [%]'])
    assert 0.0 < percent < 100.0, percent
    assert values['schedule phase'].startswith(f'{kind}: ')
    if outcome == 'failed':
        assert values['schedule phase'] == \
            'reference: feedback: I_ref steps, segment 1 of 8, I_ref off'
    assert f'last schedule {outcome} at {percent:.0f} % ({values["schedule phase"]})' in \
        last['message'], last['message']
    assert 'imu/data_raw' not in values and 'withheld' not in last['stream']
    # It stays said until the next schedule starts; that one says its own.
    count = len(setup['seen'])
    client.spin_until(lambda: len(setup['seen']) > count + 2, 30, 'more diagnostics')
    assert all(s['values']['schedule outcome'] == outcome for s in setup['seen'][count:])
    results = client.set_parameters({**FAST, 'gyro_bias.duration_s': 2.0,
                                     'estimation.feedback.motion_limit_ug': 200.0})
    assert all(r.successful for r in results), [r.reason for r in results]
    response, seen, _, _ = call_and_watch(setup, 'calibrate_gyros')
    assert response.success, response.message
    assert seen[-1]['values']['schedule outcome'] == 'done'
    assert 'last schedule' not in seen[-1]['message']
