"""The topic and service tables: complete, consistent, every schedule bounded by its row."""

from dataclasses import replace
import inspect

import pytest

from qfa_ros.ros.bounds import MAX_SCHEDULE_LOOP_STEPS
from qfa_ros.ros.parameter_table import PARAMETERS, SPECS
from qfa_ros.ros.service_table import (
    budget_problem,
    SCHEDULE_SERVICES,
    SERVICE,
    SERVICES,
)
from qfa_ros.ros.services import CalibrationServices
from qfa_ros.ros.topic_table import TOPICS

DEFAULTS = {spec.name: spec.default for spec in PARAMETERS}


def test_every_row_is_whole_and_named_once():
    assert len({spec.name for spec in SERVICES}) == len(SERVICES)
    kinds = [spec.kind for spec in SERVICES if spec.kind]
    assert len(set(kinds)) == len(kinds)
    for spec in SERVICES:
        if spec.handler is not None:
            assert list(inspect.signature(getattr(CalibrationServices, spec.handler)).parameters) \
                == ['self', 'spec', 'request', 'response'], spec.name
    with pytest.raises(ValueError, match='pause'):
        replace(SERVICE['~/calibrate_gyros'], pause='')
    with pytest.raises(ValueError, match='either schedule or handler'):
        replace(SERVICE['~/cancel'], schedule=lambda triad, state, values: None)
    assert len({spec.name for spec in TOPICS}) == len(TOPICS)
    for spec in TOPICS:
        for named in (spec.rate, spec.frame, spec.only_if and spec.only_if[0]):
            if named and ('.' in named or named.endswith('_id')) and ' ' not in named:
                assert named in SPECS, (spec.name, named)


def test_each_schedule_is_bounded_by_its_row():
    assert budget_problem(DEFAULTS) is None
    for spec in SCHEDULE_SERVICES:
        default_s = spec.sensor_time_s(DEFAULTS)
        assert 0 < default_s <= spec.worst_s, spec.name
        assert budget_problem(DEFAULTS, [spec]) is None
        # A loop rate that makes the default call cost one loop step too many: refused,
        # naming the call and the parameters that set its sensor time.
        rate = MAX_SCHEDULE_LOOP_STEPS / default_s * 1.001
        reason = budget_problem({**DEFAULTS, 'loop_rate_hz': rate}, [spec])
        assert reason.startswith(f'{spec.parameters}: one {spec.call} would take'), reason
        assert 'loop steps' in reason
    # The gyro bias call at its longest, 600 s, fits the budget up to 240 kHz.
    gyros = SERVICE['~/calibrate_gyros']
    longest = {**DEFAULTS, 'gyro_bias.duration_s': SPECS['gyro_bias.duration_s'].high}
    assert gyros.sensor_time_s(longest) == gyros.worst_s == 600.0
    assert budget_problem({**longest, 'loop_rate_hz': 240_000.0}, [gyros]) is None
    assert 'gyro_bias.duration_s' in budget_problem({**longest, 'loop_rate_hz': 250_000.0},
                                                    [gyros])
    # A setting beyond a row's worst case is refused with the row's note.
    chamber = SERVICE['~/calibrate_temperature']
    reason = budget_problem(DEFAULTS, [replace(chamber, worst_s=1000.0)])
    assert f'({chamber.worst_note}); at most 1000 s are allowed' in reason

