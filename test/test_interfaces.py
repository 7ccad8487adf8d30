"""The topic and service tables: complete, consistent, and the docs generated from them."""

from dataclasses import replace
import inspect
from pathlib import Path

import pytest

from qfa_ros.ros import interface_docs
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

ROOT = Path(__file__).resolve().parents[1]
DEFAULTS = {spec.name: spec.default for spec in PARAMETERS}


@pytest.mark.parametrize('path, name, generate', interface_docs.BLOCKS,
                         ids=[f'{path}:{name}' for path, name, _ in interface_docs.BLOCKS])
def test_generated_interface_blocks_are_current(path, name, generate):
    text = (ROOT / path).read_text()
    begin, end = f'<!-- {name}:begin -->\n', f'<!-- {name}:end -->'
    assert text.count(begin) == 1 and text.count(end) == 1, f'{path}: the {name} markers'
    block = text.split(begin, 1)[1].split(end, 1)[0]
    assert block == generate(), \
        f'{path}: the {name} block is stale; regenerate: {interface_docs.COMMAND}'


def test_a_stale_block_is_found_and_rewritten(tmp_path):
    for path, _, _ in interface_docs.BLOCKS:
        (tmp_path / path).parent.mkdir(exist_ok=True)
        (tmp_path / path).write_text((ROOT / path).read_text())
    assert interface_docs.stale_blocks(tmp_path) == []
    readme = tmp_path / 'README.md'
    readme.write_text(readme.read_text().replace('reliable, depth 100', 'best effort, depth 5'))
    assert interface_docs.stale_blocks(tmp_path) == ['README.md: interfaces']
    assert interface_docs.write(tmp_path) == ['README.md: interfaces']
    assert readme.read_text() == (ROOT / 'README.md').read_text()


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
    # The gyro bias call at its longest, 600 s: within the budget up to the loop rate that
    # spends it, refused above.
    gyros = SERVICE['~/calibrate_gyros']
    longest = {**DEFAULTS, 'gyro_bias.duration_s': SPECS['gyro_bias.duration_s'].high}
    assert gyros.sensor_time_s(longest) == gyros.worst_s == 600.0
    rate = MAX_SCHEDULE_LOOP_STEPS / 600.0
    assert budget_problem({**longest, 'loop_rate_hz': rate}, [gyros]) is None
    assert 'gyro_bias.duration_s' in budget_problem({**longest, 'loop_rate_hz': rate * 1.01},
                                                    [gyros])
    # A setting beyond a row's worst case is refused with the row's note.
    chamber = SERVICE['~/calibrate_temperature']
    reason = budget_problem(DEFAULTS, [replace(chamber, worst_s=1000.0)])
    assert f'({chamber.worst_note}); at most 1000 s are allowed' in reason

