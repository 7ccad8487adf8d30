"""What a stranger sends or leaves: files, state files, temporaries, stamps, arrays, schedules."""

from dataclasses import replace
import json
import math
import os
from pathlib import Path
import re
import secrets
import threading

from node_helpers import domain_id, largest_schedule_values, NodeProcess
import numpy as np
import pytest

from qfa_ros.calibration.estimation import capture_reference
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.model import motion_scripts, safe_files
from qfa_ros.model.hardware import AxisHardware, nominal_gains
from qfa_ros.model.safe_files import read_regular_file, UntrustedFileError, write_atomically
from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.bounds import (
    CHAMBER_MAX_PERIOD_S,
    CHAMBER_WORST_S,
    feedback_sensor_time_s,
    FEEDBACK_WORST_S,
    FORWARD_MAX_SPAN,
    forward_sensor_time_s,
    FORWARD_WORST_S,
    LARGEST_FEEDBACK,
    LARGEST_FORWARD,
    MAX_SCHEDULE_LOOP_STEPS,
    SETTLE_TIME_S,
)
from qfa_ros.ros.calibration_keeper import CalibrationKeeper
from qfa_ros.ros.input_queue import GroundTruthInput
from qfa_ros.ros.model_settings import (
    input_profile,
    load_trajectory_file,
    make_triad,
    temperature_settings,
)
from qfa_ros.ros.parameter_checks import check_all, check_value
from qfa_ros.ros.parameter_table import PARAMETERS, SPECS
from qfa_ros.ros.state_store import StateFileError, StateStore

SECRET = 'SECRET_TOKEN=hunter2-do-not-echo'


def defaults(**changes):
    values = {spec.name: spec.default for spec in PARAMETERS}
    values.update(changes)
    return values


def refusal(call, *args, **kwargs):
    """Return the message ``call(*args)`` raises (a ValueError), checked to quote no secret."""
    with pytest.raises(ValueError) as caught:
        call(*args, **kwargs)
    message = str(caught.value)
    assert SECRET not in message and 'hunter2' not in message, message
    return message


def test_only_bounded_regular_files_are_read(tmp_path):
    good = tmp_path / 'good.txt'
    good.write_bytes(b'x' * 100)
    assert read_regular_file(good, 100) == b'x' * 100
    assert 'more than the 99' in refusal(read_regular_file, good, 99)
    fifo = tmp_path / 'fifo'
    os.mkfifo(fifo)
    # A FIFO with no writer would block a plain open() for good; this returns at once.
    done = []
    worker = threading.Thread(target=lambda: done.append(
        pytest.raises(UntrustedFileError, read_regular_file, fifo, 100)), daemon=True)
    worker.start()
    worker.join(timeout=30.0)
    assert done and 'not a regular file' in str(done[0].value)
    assert 'not a regular file' in refusal(read_regular_file, tmp_path, 100)
    assert 'not a regular file' in refusal(read_regular_file, '/dev/zero', 1 << 20)
    # The file system of what was opened decides, whatever path led there.
    for pseudo, kind in (('/proc/self/environ', 'proc'), ('/proc/self/status', 'proc'),
                         ('/sys/kernel/mm/transparent_hugepage/enabled', 'sysfs')):
        if os.path.exists(pseudo):
            assert f'kernel file system {kind}' in refusal(read_regular_file, pseudo, 1 << 20)
    # A symlink is followed to what it names, and judged there.
    (tmp_path / 'environ').symlink_to('/proc/self/environ')
    assert 'kernel file system proc' in refusal(read_regular_file, tmp_path / 'environ', 100)
    assert 'cannot open' in refusal(read_regular_file, tmp_path / 'missing', 100)
    sparse = tmp_path / 'sparse'
    with open(sparse, 'wb') as stream:
        stream.truncate(4 << 30)
    assert 'more than the' in refusal(read_regular_file, sparse, 16 << 20)


def test_the_file_system_type_is_the_opened_descriptors():
    descriptor = os.open('/proc/self/status', os.O_RDONLY)
    try:
        assert safe_files.PSEUDO_FILE_SYSTEMS[safe_files.file_system_type(descriptor)] == 'proc'
    finally:
        os.close(descriptor)
    descriptor = os.open(__file__, os.O_RDONLY)
    try:
        assert safe_files.file_system_type(descriptor) not in safe_files.PSEUDO_FILE_SYSTEMS
    finally:
        os.close(descriptor)


def test_a_directory_swapped_for_a_symlink_after_resolving_is_not_followed(tmp_path,
                                                                        monkeypatch):
    # What was checked is what is read: between resolving the path and opening it,
    # someone with a shell swaps a directory on it for a symlink into /proc.
    real = (tmp_path / 'real').resolve()
    real.mkdir()
    (real / 'environ').write_text('a harmless file\n')
    resolve = Path.resolve

    def resolve_then_swap(self, strict=False):
        resolved = resolve(self, strict)
        if resolved == real / 'environ' and not real.is_symlink():
            real.rename(tmp_path / 'moved')
            real.symlink_to('/proc/self', target_is_directory=True)
        return resolved

    monkeypatch.setattr(Path, 'resolve', resolve_then_swap)
    message = refusal(read_regular_file, real / 'environ', 1 << 20)
    assert 'cannot open' in message and 'Not a directory' in message, message
    assert '/proc' not in message


@pytest.mark.parametrize('content, expected', [
    (f'{SECRET}\n0,45,0,0,0,0,0\n', 'first line must be the header'),
    (','.join(motion_scripts.CSV_COLUMNS) + f'\n0,45,0,0,0,0,0\n1,{SECRET},0,0,0,0\n',
     '7 comma-separated numbers'),
    (','.join(motion_scripts.CSV_COLUMNS) + '\n0,45,0,0,0,0,0\n1,95.123456,0,0,0,0,0\n',
     'row 2: latitude, longitude or height out of range'),
    (','.join(motion_scripts.CSV_COLUMNS) + '\n0,45,0,0,0,0,0\n', 'at least two rows'),
    (b'\xff\xfe' + SECRET.encode(), 'not UTF-8'),
])
def test_a_bad_trajectory_file_is_refused_without_quoting_it(tmp_path, content, expected):
    path = tmp_path / 'motion.csv'
    (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
    message = refusal(load_trajectory_file, defaults(**{'input.trajectory_file': str(path)}))
    assert message.startswith('input.trajectory_file: ') and expected in message, message
    assert '95.12' not in message


def test_the_trajectory_file_is_read_once_at_start_and_never_by_a_check(tmp_path):
    path = tmp_path / 'turn.csv'
    motion_scripts.save_csv(path, motion_scripts.rate_table_turn(turns=1, dwell_s=2.0, ramp_s=2.0),
                          rate_hz=20.0)
    values = defaults(**{'input.trajectory_file': str(path), 'input.mode': 'trajectory',
                         'input.trajectory': 'file'})
    loaded = load_trajectory_file(values)
    path.unlink()  # what the checks and the input use is what was read at start
    assert check_all(values, loaded) is None
    profile = input_profile(values, 5.0, loaded)
    assert profile.start == pytest.approx(5.0)
    reason = check_all({**values, 'input.trajectory_file': ''})
    assert 'read-only, set it when the node starts' in reason
    spec = {spec.name: spec for spec in PARAMETERS}['input.trajectory_file']
    assert spec.read_only


def test_stamps_far_from_the_node_clock_are_refused_without_changing_the_order():
    values = defaults(**{'input.mode': 'topic'})
    truth = GroundTruthInput(values)
    now = 1_000 * NS_PER_S
    truth.accept(now, (0.0, 0.0, 9.8), now_ns=now)
    for offset_s in (1.0e6, -1.0e6, 1.5, -1.5):
        truth.accept(now + int(offset_s * NS_PER_S), (1.0, 2.0, 3.0), now_ns=now)
    assert truth.refused_stamps == 4 and truth.rejected == 0
    assert 'input.stamp_window_s' in truth.problem
    # The next valid message is in order: the refused ones left no trace.
    truth.accept(now + 10_000_000, (0.0, 0.0, 9.7), now_ns=now + 10_000_000)
    assert [t for t, _ in truth.pending] == [now, now + 10_000_000]
    force, _, stale = truth.inputs(np.array([now + 20_000_000], dtype=np.int64))
    np.testing.assert_allclose(force[0], (0.0, 0.0, 9.7))
    assert not stale.any()
    # Odometry: a refused stamp does not become the previous message of the difference.
    truth = GroundTruthInput(values)
    q = (0.0, 0.0, 0.0, 1.0)
    truth.accept_odometry(now, (0, 0, 0), q, (1.0, 0, 0), (0, 0, 0), now)
    truth.accept_odometry(now + 10 ** 15, (0, 0, 0), q, (50.0, 0, 0), (0, 0, 0), now)
    truth.accept_odometry(now + 100_000_000, (0, 0, 0), q, (1.1, 0, 0), (0, 0, 0), now)
    force, _, _ = truth.inputs(np.array([now + 100_000_000], dtype=np.int64))
    assert force[0, 0] == pytest.approx(1.0, abs=1e-9)  # (1.1 - 1.0) / 0.1 s
    assert truth.refused_stamps == 1


def test_one_ordering_rule_against_everything_accepted():
    values = defaults(**{'input.mode': 'topic'})
    truth = GroundTruthInput(values)
    now = 1_000 * NS_PER_S
    truth.accept(now, (0.0, 0.0, 9.8), now_ns=now)
    truth.accept(now + 20_000_000, (0.0, 0.0, 9.7), now_ns=now + 20_000_000)
    # The stream takes both: the queue drains, the newer message is held.
    truth.inputs(np.array([now + 30_000_000], dtype=np.int64))
    assert not truth.pending and truth.held[0] == now + 20_000_000
    # Older than the held message: out of order, though nothing is queued.
    truth.accept(now + 10_000_000, (5.0, 5.0, 5.0), now_ns=now + 30_000_000)
    assert truth.rejected == 1 and not truth.pending
    force, _, _ = truth.inputs(np.array([now + 40_000_000], dtype=np.int64))
    np.testing.assert_allclose(force[0], (0.0, 0.0, 9.7))


def test_the_stamp_window_is_read_only():
    # A participant that could widen it would stall the honest input for that long with one
    # message stamped ahead (3600 s, +3000 s: 73 of 600 samples taken in the probes).
    assert SPECS['input.stamp_window_s'].read_only


def test_arrays_and_strings_are_bounded_before_anything_is_quoted():
    # Every array parameter has a size (a new one without length or max_length fails
    # here), checked before its elements.
    for spec in PARAMETERS:
        if isinstance(spec.default, list):
            huge = [0.0] * 200_000
            reason = check_value(spec.name, huge)
            assert reason and spec.name in reason and len(reason) < 200, (
                spec.name, reason and reason[:300])
            reason = check_value(spec.name, [math.nan] + [1.0] * (len(spec.default) - 1))
            assert 'finite' in reason and len(reason) < 200, reason
        elif isinstance(spec.default, str):
            reason = check_value(spec.name, 'x' * 100_000)
            assert reason and spec.name in reason and len(reason) < 200, (
                spec.name, reason and reason[:300])
    reason = check_value('input.mode', f'{SECRET} ' * 10)
    assert 'one of' in reason and len(reason) < 200
    reason = check_value('input.steps.levels', [1.0] * 5 + [1.0e6])
    assert reason == 'input.steps.levels[5] must be in [-1000, 1000], got 1000000.0'


def nominal_state(triad):
    """Return a valid state file's dict: the words ``triad`` holds now."""
    state = CalibrationState(controller_gain=[loop.controller.gain for loop in triad.axes],
                             n_vref=[loop.n_vref for loop in triad.axes])
    return state.to_dict()


def hostile_state(case, state):
    """Return the text of a state file that breaks ``state`` (a dict) as ``case`` says."""
    if case == 'nested':
        return '[' * 100_000 + ']' * 100_000
    if case == 'nested in a field':
        return json.dumps(state)[:-1] + ', "last_estimates": ' + '[' * 5000 + ']' * 5000 + '}'
    if case == 'Infinity in n_vref':
        return json.dumps({**state, 'n_vref': [math.inf, 1, 1]})
    if case == 'huge captured_at_ns':
        return json.dumps(state)[:-1] + ', "captured_at_ns": 1e400}'
    if case == 'huge integer':
        return json.dumps(state)[:-1] + ', "updated_at_ns": ' + '9' * 5000 + '}'
    if case == 'word in controller_gain':
        return json.dumps({**state, 'controller_gain': [SECRET, 1.0, 1.0]})
    if case == 'word as a reference key':
        return json.dumps({**state, 'references': [{SECRET: 1.0}] * 3})
    if case == 'word in last_estimates':
        return json.dumps({**state, 'last_estimates': {SECRET: [1.0, 2.0, 3.0]}})
    if case == 'word in the temperature record':
        return json.dumps({**state, 'temperature': {'format': 'multiposition/1',
                                                    'bias': {'x': {'fit': {},
                                                                   'alpha': [SECRET, 1.0]}}}})
    if case == 'word as the compensation switch':
        return json.dumps({**state, 'compensation_enabled': SECRET})
    if case == 'not JSON':
        return f'{SECRET}\n'
    if case == 'gyro bias beyond the range':  # applied before: rates of 1e300 rad/s published
        return json.dumps({**state, 'gyro_bias': [1e300, 0.0, 0.0]})
    raise ValueError(case)


class LogLines:
    """A logger keeping every line."""

    def __init__(self):
        self.lines = []

    def error(self, line):
        self.lines.append(line)

    warning = info = error


@pytest.mark.parametrize('case', [
    'nested', 'nested in a field', 'Infinity in n_vref', 'huge captured_at_ns', 'huge integer',
    'word in controller_gain', 'word as a reference key', 'word in last_estimates',
    'word in the temperature record', 'word as the compensation switch', 'not JSON',
    'gyro bias beyond the range'])
def test_a_malformed_state_file_is_set_aside_without_quoting_it(tmp_path, case):
    triad = make_triad(defaults())
    nominal = [(loop.controller.gain, loop.n_vref) for loop in triad.axes]
    path = tmp_path / 'state.json'
    path.write_text(hostile_state(case, nominal_state(triad)))
    log = LogLines()
    keeper = CalibrationKeeper(triad, str(path), log)
    keeper.load()
    assert keeper.problem and 'starting uncalibrated' in keeper.problem, keeper.problem
    assert 'corrupt' in keeper.problem or 'cannot take' in keeper.problem, keeper.problem
    assert log.lines and all(SECRET not in line and 'hunter2' not in line
                             for line in log.lines), log.lines
    assert all(len(line) < 1000 for line in log.lines)
    assert not path.exists() and len(list(tmp_path.glob('state.json.corrupt-*'))) == 1
    assert [(loop.controller.gain, loop.n_vref) for loop in triad.axes] == nominal
    assert not keeper.state.has_reference and not keeper.state.last_estimates


def test_stored_words_the_sensor_refuses_are_not_quoted(tmp_path):
    # Loaded with the compensation off, a word out of the DA0 range is applied only when
    # a participant switches the compensation on.
    triad = make_triad(defaults())
    nominal = [(loop.controller.gain, loop.n_vref) for loop in triad.axes]
    word = 2 ** 40 + 12345
    path = tmp_path / 'state.json'
    path.write_text(json.dumps({**nominal_state(triad), 'compensation_enabled': False,
                                'n_vref': [nominal[0][1], word, nominal[2][1]]}))
    keeper = CalibrationKeeper(triad, str(path), LogLines())
    keeper.load()
    assert keeper.problem is None and not keeper.compensation
    success, message = keeper.set_compensation(True)
    assert not success and 'out of the sensor' in message, message
    assert str(word) not in message
    assert [(loop.controller.gain, loop.n_vref) for loop in triad.axes] == nominal
    assert not keeper.compensation


def test_leftover_temporary_state_files_are_removed(tmp_path):
    path = tmp_path / 'state.json'
    leftovers = [tmp_path / f'.state.json.{tag}.tmp' for tag in ('abc', 'x1')]
    for leftover in leftovers:
        leftover.write_text('{')
    other = tmp_path / '.other.json.abc.tmp'
    other.write_text('{')
    store = StateStore(str(path))
    assert store.remove_leftovers() == leftovers
    assert not any(p.exists() for p in leftovers) and other.exists()
    store.save(CalibrationState(), True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['.other.json.abc.tmp', 'state.json']


def test_a_state_file_that_is_not_one_is_left_alone(tmp_path):
    fifo = tmp_path / 'state.json'
    os.mkfifo(fifo)
    with pytest.raises(StateFileError, match='not a regular file') as caught:
        StateStore(str(fifo)).load()
    assert caught.value.kept_as is None and fifo.exists()
    big = tmp_path / 'big.json'
    big.write_text(' ' * (2 << 20))
    with pytest.raises(StateFileError, match='more than the'):
        StateStore(str(big)).load()
    assert big.exists()


def test_the_forward_span_bound_is_the_adc_and_da1_range():
    hardware = AxisHardware()
    top = hardware.n_fpga + FORWARD_MAX_SPAN
    counts = top * nominal_gains(hardware).open_loop_counts_per_fpga
    assert counts * 1.05 <= 2 ** (hardware.n_ad_bits - 1) < (counts + 300) * 1.05
    assert top < 2 ** (hardware.n_da1_bits - 1)
    step = FORWARD_MAX_SPAN // 50 + 1
    reason = check_all(defaults(**{'estimation.forward.points': 50,
                                   'estimation.forward.step': step}))
    assert 'estimation.forward.points x estimation.forward.step' in reason
    # A known forward drift narrows the span: the open-loop output grows with it.
    values = defaults(**{'estimation.forward.points': 50,
                         'estimation.forward.step': FORWARD_MAX_SPAN // 50})
    assert check_all(values) is None
    assert 'ADC' in check_all({**values, 'drift.forward_ppm': [5.0e4, 0.0, 0.0]})


def test_the_documented_chamber_bound_is_the_largest_an_accepted_setting_takes():
    # The bound docs/security.md states, against the chamber settings the node accepts:
    # limits 10 to 120 degC apart all over their range (the fewer plateaus, the longer
    # each holds), the I_ref steps on, the period at the top of its range and on either
    # side of where the bound cuts it. Not compared with bounds.py's constant: that would
    # be the bound with itself.
    text = (Path(__file__).resolve().parents[1] / 'docs' / 'security.md').read_text()
    stated = re.search(r'(\d{1,3}(?:[ \u202f]\d{3})*) s of sensor time for\s+'
                       r'`calibrate_temperature`', text)
    documented = float(re.sub(r'\D', '', stated.group(1)))
    largest = 0.0
    cut = 0
    for low in range(-60, 125, 15):
        for high in [low + span for span in (10, 15, 20, 40, 80, 120) if low + span <= 125]:
            # The nominal unit: drawing one per check would take most of the test's time.
            values = defaults(**{'unit.draw': False,
                                 'temperature_calibration.low_c': float(low),
                                 'temperature_calibration.high_c': float(high),
                                 'temperature_calibration.period_s': CHAMBER_MAX_PERIOD_S})

            def sensor_s(period):
                values['temperature_calibration.period_s'] = period
                return temperature_settings(values).max_sensor_time_s()

            longest_s = sensor_s(CHAMBER_MAX_PERIOD_S)
            if longest_s <= documented:
                assert check_all(values) is None, (low, high)
                largest = max(largest, longest_s)
                continue
            # The sensor time is affine in the period: where does it reach the bound?
            slope = (longest_s - sensor_s(1000.0)) / (CHAMBER_MAX_PERIOD_S - 1000.0)
            period = math.floor(CHAMBER_MAX_PERIOD_S - (longest_s - documented) / slope)
            assert documented < sensor_s(period + 1.0)
            within_s = sensor_s(period)
            assert within_s <= documented and check_all(values) is None, (low, high, period)
            largest = max(largest, within_s)
            # One second more is refused as a whole, naming the chamber's parameters.
            over_s = sensor_s(period + 1.0)
            reason = check_all(values)
            assert reason and 'temperature_calibration' in reason, (low, high, over_s)
            cut += 1
    assert cut > 10
    assert documented - 10.0 <= largest <= documented
    assert documented == round(CHAMBER_WORST_S)


def test_the_largest_schedules_the_ranges_allow_run():
    values = largest_schedule_values()
    assert check_all(values) is None
    # Each bound is at the top of its parameter range.
    specs = {spec.name: spec for spec in PARAMETERS}
    for name in ('estimation.forward.points', 'estimation.forward.settle_s',
                 'estimation.forward.average_s', 'estimation.feedback.cycles',
                 'estimation.feedback.settle_s', 'estimation.feedback.average_s',
                 'temperature_calibration.period_s', 'temperature_calibration.cycles'):
        assert values[name] == specs[name].high, name
    assert FORWARD_WORST_S == forward_sensor_time_s(LARGEST_FORWARD, SETTLE_TIME_S)
    assert FEEDBACK_WORST_S == feedback_sensor_time_s(LARGEST_FEEDBACK, SETTLE_TIME_S)
    # The widest sweep and the most I_ref segments the ranges allow, each point and segment
    # averaged for 0.05 s instead of up to 20 s: the same words drive DA1 and the ADC as at
    # the largest, and the call takes the sensor time the bound's functions give it. The
    # largest calls themselves (912 s of sensor time, 9.1e6 loop steps, ~10 CPU-s; the
    # chamber program 6.2e7 steps, ~30 CPU-s) run within their bounds in
    # `python bench/schedule_cost.py --largest` (bench/results/schedule_cost.md).
    forward_settings = replace(LARGEST_FORWARD, average_s=0.05)
    feedback_settings = replace(LARGEST_FEEDBACK, average_s=0.05)
    triad = make_triad(values, input_profile(values))
    state = CalibrationState()
    started = triad.time
    forward, feedback = run_schedule(
        triad, capture_reference(triad, state, forward_settings, feedback_settings),
        chunk_samples=100_000)
    assert forward.captured and feedback.captured
    assert triad.time - started == pytest.approx(
        forward_sensor_time_s(forward_settings, SETTLE_TIME_S)
        + feedback_sensor_time_s(feedback_settings, SETTLE_TIME_S), abs=0.01)
    np.testing.assert_allclose(feedback.measured, -71739.0, rtol=1e-3)
    assert CHAMBER_WORST_S * values['loop_rate_hz'] <= MAX_SCHEDULE_LOOP_STEPS


def test_documented_bounds_are_the_computed_ones():
    # A stated sensor time near a computed worst case but not equal to it is a stale copy.
    root = Path(__file__).resolve().parents[1]
    for path in [root / 'README.md', *sorted((root / 'docs').rglob('*.md'))]:
        text = path.read_text()
        for match in re.finditer(r'(?<![\d.])(\d{1,3}(?:[ \u202f]\d{3})+|\d+) s'
                                 r'(?= of sensor time| for `calibrate_temperature`)', text):
            stated = int(re.sub(r'\D', '', match.group(1)))
            for bound in (CHAMBER_WORST_S, FORWARD_WORST_S + FEEDBACK_WORST_S):
                if 0.9 * bound <= stated <= 1.1 * bound:
                    assert stated == round(bound), \
                        f'{path.name}: {match.group(0)!r} where the bound is {bound:.0f} s'


def test_every_test_the_security_page_names_exists():
    # docs/security.md's table: each line with the tests that hold it, as
    # `test_file.py::test_name` or `::test_name` (the file named before it on the line).
    root = Path(__file__).resolve().parents[1]
    named = 0
    for line in (root / 'docs' / 'security.md').read_text().splitlines():
        file = None
        for match in re.finditer(r'`(test_\w+\.py)?::(test_\w+)`', line):
            file = match.group(1) or file
            assert file, f'{match.group(0)} names no file: {line[:80]}'
            assert re.search(rf'^def {match.group(2)}\(', (root / 'test' / file).read_text(),
                             re.MULTILINE), f'docs/security.md names {file}::{match.group(2)}'
            named += 1
    assert named >= 20


def test_a_node_named_a_hostile_trajectory_file_refuses_to_start_without_quoting_it(tmp_path):
    secret = tmp_path / 'secret.csv'
    secret.write_text(f'{SECRET}\n')
    os.mkfifo(tmp_path / 'fifo')
    # One real start: the process ends by itself, with one line naming the parameter.
    node = NodeProcess(domain_id('hostile file'), tmp_path / 'run', {
        'input.trajectory_file': str(secret), 'output_dir': str(tmp_path / 'out'),
        'state_file': ''}, name='qfa_hostile')
    status = node.wait(120)
    log = node.log()
    assert status == 2, log
    fatal = [line for line in log.splitlines() if '[FATAL]' in line]
    assert len(fatal) == 1 and 'input.trajectory_file' in fatal[0], log
    assert SECRET not in log and 'hunter2' not in log, log
    # Each file, that one too, refused by the node's constructor (the ValueError qfa_node
    # reports as that line): a FIFO and a device neither block nor are read.
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from qfa_ros.ros.node import QfaNode

    context = Context()
    rclpy.init(context=context, domain_id=domain_id('hostile file in process'))
    try:
        for path in (secret, tmp_path / 'fifo', '/dev/zero'):
            message = refusal(QfaNode, 'qfa_hostile', context=context, parameter_overrides=[
                Parameter('input.trajectory_file', value=str(path)),
                Parameter('output_dir', value=str(tmp_path / 'out')),
                Parameter('state_file', value='')])
            assert 'input.trajectory_file' in message and '\n' not in message, message
    finally:
        rclpy.try_shutdown(context=context)


def test_a_failed_atomic_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / 'state.json'
    write_atomically(path, lambda stream: stream.write(b'old'))

    def half_then_fail(stream):
        stream.write(b'new, half written')
        raise OSError(28, 'No space left on device')

    with pytest.raises(OSError, match='No space'):
        write_atomically(path, half_then_fail)
    assert path.read_bytes() == b'old'
    assert [p.name for p in tmp_path.iterdir()] == ['state.json']
    write_atomically(path, lambda stream: stream.write(b'new'))
    assert path.read_bytes() == b'new'


def test_temporary_files_are_created_exclusively_under_unpredictable_names(tmp_path,
                                                                          monkeypatch):
    victim = tmp_path / 'victim.txt'
    victim.write_text('not yours\n')
    out = tmp_path / 'out'
    out.mkdir()
    path = out / 'state.json'
    # A link planted where a temporary named after the process would go.
    (out / f'.state.json.{os.getpid()}.tmp').symlink_to(victim)
    renamed = []
    replace = os.replace
    monkeypatch.setattr(os, 'replace', lambda source, target: (
        renamed.append(Path(source).name), replace(source, target))[1])
    write_atomically(path, lambda stream: stream.write(b'one'))
    write_atomically(path, lambda stream: stream.write(b'two'))
    assert victim.read_text() == 'not yours\n'
    assert not path.is_symlink() and path.read_bytes() == b'two'
    assert len(set(renamed)) == 2, renamed
    assert all(re.fullmatch(r'\.state\.json\.[0-9a-f]{16}\.tmp', name) for name in renamed)
    # A name that exists (here a planted link) is never opened: the next one is drawn.
    (out / f'.state.json.{"0" * 16}.tmp').symlink_to(victim)
    names = iter(['0' * 16, '1' * 16])
    monkeypatch.setattr(secrets, 'token_hex', lambda size: next(names))
    write_atomically(path, lambda stream: stream.write(b'three'))
    assert victim.read_text() == 'not yours\n' and path.read_bytes() == b'three'
    assert renamed[-1] == f'.state.json.{"1" * 16}.tmp'
