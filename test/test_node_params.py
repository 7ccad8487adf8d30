"""Parameter table, validation and the state store of the node (no DDS)."""

import json
import math
from pathlib import Path

from node_helpers import domain_id, OPERATOR_ONLY
import numpy as np
import pytest
from rclpy.parameter import Parameter
import yaml

from qfa_ros.calibration.state import AxisReference, CalibrationState
from qfa_ros.model.drawn_unit import draw_unit, FORWARD_TC_COMPONENTS
from qfa_ros.ros.model_settings import make_triad
from qfa_ros.ros.parameter_checks import as_declared_type, check_all, check_value, descriptor
from qfa_ros.ros.parameter_docs import access_table, config_yaml, markdown_table
from qfa_ros.ros.parameter_table import EFFECT_OF, OPERATOR, PARAMETERS, RUNTIME_EFFECTS, SPECS
from qfa_ros.ros.state_store import StateFileError, StateStore
from qfa_ros.ros.stream import offered_qos
from qfa_ros.ros.topic_table import PUBLISHER, SUBSCRIPTION, TOPICS

ROOT = Path(__file__).resolve().parents[1]


def defaults():
    return {spec.name: spec.default for spec in PARAMETERS}


def test_config_file_holds_every_parameter_with_its_default():
    text = (ROOT / 'config' / 'qfa.yaml').read_text()
    assert text == config_yaml(), 'regenerate: python -m qfa_ros.ros.parameter_docs yaml'
    values = yaml.safe_load(text)['/**']['ros__parameters']
    assert set(values) == set(SPECS)
    for name, value in values.items():
        assert value == pytest.approx(SPECS[name].default), name
        assert type(value) is type(SPECS[name].default), name


def test_docs_list_every_parameter():
    assert markdown_table() in (ROOT / 'docs' / 'node.md').read_text(), \
        'regenerate the table: python -m qfa_ros.ros.parameter_docs markdown'


def test_the_security_page_says_who_may_set_what():
    assert access_table() in (ROOT / 'docs' / 'security.md').read_text(), \
        'regenerate the table: python -m qfa_ros.ros.parameter_docs access'


def test_every_parameter_has_a_description_and_fixed_names_exist():
    for spec in PARAMETERS:
        assert descriptor(spec).description, spec.name
    for name in ('sample_rate_hz', 'loop_rate_hz', 'frame_id', 'seed', 'drift.forward_ppm',
                 'drift.feedback_ppm', 'estimation.realtime', 'trace_dir', 'state_file'):
        assert name in SPECS
    assert descriptor(SPECS['sample_rate_hz']).read_only
    assert descriptor(SPECS['drift.time_acceleration']).floating_point_range


def test_the_operator_alone_sets_files_directories_and_resources():
    # The table agrees with the tests' list: what no participant sets in any state.
    operator = {spec.name for spec in PARAMETERS if spec.access == OPERATOR}
    assert operator == OPERATOR_ONLY, operator ^ OPERATOR_ONLY


def test_defaults_are_consistent():
    assert check_all(defaults()) is None


@pytest.mark.parametrize('name, value, words', [
    ('drift.forward_ppm', [math.nan, 0.0, 0.0], 'finite'),
    ('drift.feedback_ppm', [1.0, 2.0], 'exactly 3'),
    ('sample_rate_hz', -1000.0, 'in [1'),
    ('input.mode', 'flying', 'one of static, profile, trajectory, topic'),
    ('estimation.forward.order', 'random', 'one of'),
    ('frame_id', '', 'must not be empty'),
    ('drift.time_acceleration', math.inf, 'finite'),
    ('sensor.error_profile', 'perfect', 'one of paper, ideal'),
])
def test_bad_values_are_rejected_with_a_reason(name, value, words):
    assert words in check_value(name, value)


def test_default_sensor_carries_the_paper_error_sources_in_the_paper_room():
    # One sensor: the node's default triad has Ran et al.'s component temperature
    # coefficients (qfa_ros.model.error_profiles) and sits in the paper's wandering room.
    # The drawn unit (Ran et al. 2019) brings its own I_ref and forward-chain coefficients.
    paper = make_triad(defaults())
    drift = paper.drift
    unit = draw_unit(1)
    forward = dict(zip(FORWARD_TC_COMPONENTS, unit.forward_tc_ppm_per_c))
    for component, ppm in (('i_ref', unit.i_ref_tc_ppm_per_c), ('b', [10.0] * 3),
                           *forward.items()):
        index = drift.components.index(component)
        assert drift.temperature_coefficient[:, index] == pytest.approx(np.multiply(ppm,
                                                                                    1e-6))
    assert len(set(unit.i_ref_tc_ppm_per_c)) == 3
    nominal = make_triad({**defaults(), 'unit.draw': False}).drift
    for component, ppm in (('i_ref', 30.0), ('b', 10.0), ('v_da1_ref', 20.0),
                           ('k_tz', 7.0), ('k_amp', 6.0)):
        index = nominal.components.index(component)
        assert nominal.temperature_coefficient[:, index] == pytest.approx([ppm * 1e-6] * 3)
    thermal = paper.thermal.config
    assert (thermal.ambient_profile, thermal.room_amplitude_c, thermal.room_correlation_s) \
        == ('room', 1.5, 43200.0)
    ideal = make_triad({**defaults(), 'sensor.error_profile': 'ideal'})
    assert not ideal.drift.temperature_coefficient.any()
    assert descriptor(SPECS['sensor.error_profile']).read_only


def test_loop_rate_must_be_a_multiple_of_the_sample_rate():
    values = defaults()
    values['loop_rate_hz'] = 2500.0
    assert 'integer multiple' in check_all(values)


def test_inconsistent_step_profile_is_rejected():
    values = defaults()
    values['input.mode'] = 'profile'
    values['input.profile'] = 'steps'
    values['input.steps.levels'] = [0.0, 0.0, 9.8]
    assert 'input.steps' in check_all(values)


def calibrated_state():
    state = CalibrationState(references=[AxisReference(73.4, -71739.0, 25.0)
                                         for _ in range(3)])
    state.controller_gain = [0.25, 0.25, 0.25]
    state.n_vref = [13981013, 13981013, 13981013]
    return state


def test_state_store_round_trip_and_atomic_write(tmp_path):
    store = StateStore(tmp_path / 'sub' / 'state.json')
    assert store.load() == (None, True)
    store.save(calibrated_state(), False)
    state, compensation = store.load()
    assert state.has_reference and compensation is False
    assert [p.name for p in store.path.parent.iterdir()] == ['state.json']


def test_corrupt_state_file_is_set_aside(tmp_path):
    path = tmp_path / 'state.json'
    path.write_text('{"format": "qfa_ros.calibration/1", "references": [')
    with pytest.raises(StateFileError) as error:
        StateStore(path).load()
    assert 'corrupt' in str(error.value)
    assert not path.exists()
    assert error.value.kept_as.name.startswith('state.json.corrupt-')
    assert error.value.kept_as.read_text().startswith('{"format"')


def test_state_file_with_wrong_format_is_set_aside(tmp_path):
    path = tmp_path / 'state.json'
    path.write_text(json.dumps({'format': 'something else'}))
    with pytest.raises(StateFileError, match='unknown or missing format'):
        StateStore(path).load()


def test_state_store_without_path_keeps_nothing():
    store = StateStore('')
    assert store.save(calibrated_state(), True) is None
    assert store.load() == (None, True)


def test_integers_typed_for_doubles_become_doubles():
    converted = as_declared_type(Parameter('drift.feedback_ppm', value=[1, 2, 3]))
    assert converted.type_ == Parameter.Type.DOUBLE_ARRAY
    assert converted.value == [1.0, 2.0, 3.0]
    converted = as_declared_type(Parameter('sample_rate_hz', value=2000))
    assert converted.type_ == Parameter.Type.DOUBLE and converted.value == 2000.0
    for unchanged in (Parameter('seed', value=3), Parameter('frame_id', value='x'),
                      Parameter('recorder.max_bytes', value=2 ** 20)):
        assert as_declared_type(unchanged) is unchanged


def test_array_descriptors_show_length_and_element_range():
    for spec in PARAMETERS:
        if not isinstance(spec.default, list):
            continue
        result = descriptor(spec)
        assert spec.low is not None, spec.name
        assert result.floating_point_range[0].from_value == spec.low
        assert f'[{spec.low:g}, {spec.high:g}]' in result.additional_constraints
        assert check_value(spec.name, [spec.high * 2] * len(spec.default)) is not None
        assert check_value(spec.name, spec.default) is None


def test_every_writable_parameter_has_one_runtime_effect():
    writable = {spec.name for spec in PARAMETERS if not spec.read_only}
    listed = [name for names in RUNTIME_EFFECTS.values() for name in names]
    assert sorted(listed) == sorted(writable), 'each writable parameter exactly once'
    # A live parameter is read where it is used: its name appears beyond its declaration.
    sources = '\n'.join(path.read_text() for path in (ROOT / 'qfa_ros').rglob('*.py'))
    for name in RUNTIME_EFFECTS['live']:
        assert sources.count(f"'{name}'") >= 3, f'{name}: declared and listed, never read'


def changed_value(spec):
    """Return a valid value of ``spec`` other than its default."""
    default = spec.default
    if isinstance(default, bool):
        return not default
    if spec.choices:
        return next(choice for choice in spec.choices if choice != default)
    if isinstance(default, str):
        return default + '_changed'
    if isinstance(default, list):
        low = -1.0 if spec.low is None else max(spec.low, -1.0)
        return [low if v != low else low / 2 for v in default]
    if isinstance(default, int):
        return default + 1 if spec.high is None or default + 1 <= spec.high else default - 1
    low, high = spec.low, spec.high
    return (low + high) / 2 if low is not None and (low + high) / 2 != default \
        else default * 0.9 + 0.01


def assert_qos_of_the_topic_table(node):
    values = {name: node.get_parameter(name).value
              for name in {spec.only_if[0] for spec in TOPICS if spec.only_if}}
    endpoints = {(PUBLISHER, p.topic_name): p for p in node.publishers}
    endpoints |= {(SUBSCRIPTION, s.topic_name): s for s in node.subscriptions}
    checked = 0
    for spec in TOPICS:
        endpoint = endpoints.get((spec.direction, node.resolve_topic_name(spec.name)))
        assert (endpoint is not None) == spec.offered(values), spec.name
        if endpoint is None:
            continue
        offered = offered_qos(endpoint.qos_profile)
        assert (offered.reliability, offered.durability, offered.history, offered.depth) == \
            (spec.qos.reliability, spec.qos.durability, spec.qos.history, spec.qos.depth), \
            spec.name
        checked += 1
    assert checked == sum(spec.offered(values) for spec in TOPICS) > 5


def test_every_writable_parameter_takes_effect_or_is_refused(tmp_path):
    import rclpy
    from rclpy.context import Context

    from qfa_ros.ros.node import QfaNode

    context = Context()
    rclpy.init(context=context, domain_id=domain_id('runtime effects'))
    node = QfaNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path)), Parameter('state_file', value=''),
        Parameter('estimation.realtime', value=False)])
    try:
        # First, the node's own publishers and subscription have their rows' QoS, the depth
        # included (discovery does not carry it: test_node_truth.py compares the rest over DDS).
        assert_qos_of_the_topic_table(node)
        assert set(node.runtime_effects) == set(RUNTIME_EFFECTS)
        outcomes = {}
        for spec in PARAMETERS:
            if spec.read_only:
                continue
            value = changed_value(spec)
            before = dict(node.applied_effects)
            result, = node.set_parameters([Parameter(spec.name, value=value)])
            if result.successful:
                assert node.get_parameter(spec.name).value == value, spec.name
                effect = EFFECT_OF[spec.name]
                assert node.applied_effects[effect] == before.get(effect, 0) + 1, spec.name
                assert sum(node.applied_effects.values()) == sum(before.values()) + 1
                outcomes[spec.name] = 'applied'
            else:
                assert result.reason, spec.name
                outcomes[spec.name] = result.reason
            # Back to the default, so that each change is judged on its own.
            assert node.set_parameters([Parameter(spec.name, value=spec.default)])[0].successful
        applied = [name for name, outcome in outcomes.items() if outcome == 'applied']
        assert len(applied) > 0.8 * len(outcomes), outcomes
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_change_whose_effect_fails_is_refused_and_undone(tmp_path):
    import rclpy
    from rclpy.context import Context

    from qfa_ros.ros.node import QfaNode

    context = Context()
    rclpy.init(context=context, domain_id=domain_id('failing effects'))
    node = QfaNode(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path)), Parameter('state_file', value='')])
    drift = node.runtime_effects['drift']
    seen = []

    def fails_once(error):
        def step():
            # The real step first (the model takes the values it is given), then a failure
            # the first time: the change must be refused and the step run again, undoing it.
            seen.append(list(node.get_parameter('drift.forward_ppm').value)
                        if seen else 'new')
            drift()
            if len(seen) == 1:
                raise error
        return step

    try:
        old = list(node.get_parameter('drift.forward_ppm').value)
        for error, words in ((ValueError('the model refused it'), 'the model refused it'),
                             (RuntimeError('unexpected'), 'RuntimeError: unexpected')):
            seen.clear()
            node.runtime_effects['drift'] = fails_once(error)
            applied = dict(node.applied_effects)
            result, = node.set_parameters([Parameter('drift.forward_ppm',
                                                     value=[500.0, 0.0, 0.0])])
            assert not result.successful, error
            assert 'drift.forward_ppm not changed' in result.reason and words in result.reason
            assert list(node.get_parameter('drift.forward_ppm').value) == old
            # Undone: the step ran again, while the parameter held its old value.
            assert seen == ['new', old]
            assert dict(node.applied_effects) == applied
        node.runtime_effects['drift'] = drift
        # The node goes on: the same change, its effect working, is accepted.
        result, = node.set_parameters([Parameter('drift.forward_ppm', value=[500.0, 0.0, 0.0])])
        assert result.successful, result.reason
        assert node.applied_effects['drift'] == applied.get('drift', 0) + 1
    finally:
        node.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
