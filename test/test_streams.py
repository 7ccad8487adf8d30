"""Named random streams (qfa_ros.model.random_streams): stable keys, unique per owner."""

import numpy as np
import numpy.testing as npt
import pytest

from qfa_ros.model import random_streams
from qfa_ros.model.drawn_unit import draw_unit
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig


def _triad_draws(parent):
    # Every stream of a triad: the three noise axes, the thermal model, the gyro unit and
    # its noise (ThermalConfig 'room' so the thermal stream is drawn from).
    config = TriadConfig(thermal=ThermalConfig(ambient_profile='room',
                                               room_correlation_s=1.0))
    triad = QfaTriad(config, rng=parent)
    out = triad.run_for(0.05)
    return out.accel, out.gyro, out.v_temp, np.asarray(triad.gyro.unit.bias)


def test_the_table_has_unique_keys_per_owner():
    random_streams.check_unique(random_streams.STREAMS)
    for name in random_streams.STREAMS:
        owner, _, stream = name.partition('.')
        assert owner and stream
    with pytest.raises(ValueError, match="'triad.thermal' and 'triad.extra' share"):
        random_streams.check_unique({**random_streams.STREAMS, 'triad.extra': 3})
    with pytest.raises(ValueError, match="'triad.noise' and 'triad.extra' share"):
        random_streams.check_unique({**random_streams.STREAMS, 'triad.extra': 1})
    with pytest.raises(ValueError, match='share'):
        random_streams.check_unique({'paper.a': range(0, 4), 'paper.b': range(3, 5)})
    # Another owner may reuse a key: its parent is another stream.
    random_streams.check_unique({**random_streams.STREAMS, 'other.extra': 3})
    for bad in ({'nodot': 0}, {'a.b': -1}, {'a.b': True}, {'a.b': range(0)},
                {'a.b': range(0, 6, 2)}, {'a.b': 1.0}):
        with pytest.raises(ValueError, match='stream'):
            random_streams.check_unique(bad)


def test_the_keys_are_the_spawn_order_layout_the_streams_had():
    # The table reproduces what rng.spawn() gave before it: noise x, y, z then thermal
    # from the triad's generator, the thermal model's own child, the gyros' four.
    for seed in (0, 1, [3, 4]):
        old = np.random.default_rng(seed)
        noise, thermal = old.spawn(3), old.spawn(1)[0]
        environment = thermal.spawn(1)[0]
        new = np.random.default_rng(seed)
        for axis in range(3):
            npt.assert_array_equal(random_streams.generator(new, 'triad.noise', axis).random(4),
                                   noise[axis].random(4))
        new_thermal = random_streams.generator(new, 'triad.thermal')
        npt.assert_array_equal(
            random_streams.generator(new_thermal, 'thermal.environment').random(4),
            environment.random(4))
        npt.assert_array_equal(new_thermal.random(4), thermal.random(4))
        gyro_seq = random_streams.seed_sequence(new, 'triad.gyro')
        old_gyro = np.random.default_rng(gyro_seq).spawn(4)
        for i, name in enumerate(('gyro.unit', 'gyro.white', 'gyro.flicker', 'gyro.walk')):
            npt.assert_array_equal(
                random_streams.generator(np.random.default_rng(gyro_seq), name).random(4),
                old_gyro[i].random(4))
        root = np.random.SeedSequence(seed)
        model, draws = root.spawn(2)
        assert random_streams.seed_sequence(seed, 'unit.model').state == model.state
        assert random_streams.seed_sequence(seed, 'unit.draws').state == draws.state
        trials = np.random.SeedSequence(seed).spawn(5)
        assert random_streams.seed_sequence(seed, 'paper.trial', 4).state == trials[4].state


def test_adding_a_stream_changes_no_other(monkeypatch):
    before_triad = _triad_draws(np.random.default_rng(11))
    before_unit = draw_unit(11)
    # A new name, first in the table, drawn from before any other stream is derived:
    # with spawn order it would have taken key 0 and shifted every stream of the triad.
    table = {'triad.extra': 4, 'unit.extra': 2, **random_streams.STREAMS}
    random_streams.check_unique(table)
    monkeypatch.setattr(random_streams, 'STREAMS', table)
    parent = np.random.default_rng(11)
    extra = random_streams.generator(parent, 'triad.extra').standard_normal(1000)
    after_triad = _triad_draws(parent)
    for before, after in zip(before_triad, after_triad):
        npt.assert_array_equal(after, before)
    assert draw_unit(11) == before_unit
    # The new stream is one of its own.
    noise_x = random_streams.generator(np.random.default_rng(11), 'triad.noise', 0)
    assert not np.array_equal(noise_x.standard_normal(1000), extra)


def test_key_validates_the_name_and_the_index():
    assert random_streams.key('triad.gyro') == (0x6779726F,)
    assert random_streams.key('triad.noise', 2) == (2,)
    with pytest.raises(ValueError, match='name'):
        random_streams.key('triad.unknown')
    for index in (None, 3, -1, True, 1.0):
        with pytest.raises(ValueError, match='index'):
            random_streams.key('triad.noise', index)
    with pytest.raises(ValueError, match='index'):
        random_streams.key('triad.thermal', 0)
    child = random_streams.generator(np.random.Generator(np.random.SFC64(5)), 'triad.thermal')
    assert isinstance(child.bit_generator, np.random.SFC64)
    assert child.bit_generator.seed_seq.spawn_key == (3,)
