"""Temperature calibration through the loop model (issue: temperature)."""

import io
import json
import re

from bag_helpers import assert_same_bag, BAGS, make_bags_commands
import numpy as np
from numpy.testing import assert_allclose
import pytest

from qfa_ros.calibration.schedule import EstimationError, run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_schedule, TemperatureSettings
from qfa_ros.cli.sim import main as sim_main
from qfa_ros.model.noise import NoiseConfig
from qfa_ros.model.profiles import SineProfile
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import QfaTriad, TriadConfig

SHORT = TemperatureSettings(period_s=600.0)
CHAMBER = ThermalConfig(ambient_profile='constant', sensor_tau_s=30.0)


def thermal_triad(seed=0, noise=None, profile=None):
    config = TriadConfig(thermal=CHAMBER, noise=noise or NoiseConfig())
    return QfaTriad(config, rng=seed, profile=profile)


def test_default_sensor_zero_drift_is_reduced_tenfold(capsys, tmp_path):
    # The `make bags` command of the temperature example bag: one run checks the
    # out-of-sample reduction and that the committed bag is what the command writes.
    bag = tmp_path / 'temperature_cycle.mcap'
    arguments = make_bags_commands()['temperature_cycle.mcap']
    assert arguments[:3] == ['temperature-cycle', '--duration', '3600']
    assert sim_main([*arguments, '--out', str(bag)]) == 0
    rows = [line.strip(' |').split('|') for line in capsys.readouterr().out.splitlines()
            if re.match(r'^\| [xyz] \|', line)]
    assert [row[0].strip() for row in rows] == ['x', 'y', 'z']
    before = np.array([float(row[4]) for row in rows])
    after = np.array([float(row[5]) for row in rows])
    reductions = np.array([float(row[6].strip().rstrip('x')) for row in rows])
    assert_allclose(reductions, before / after, rtol=0.01)
    assert np.all(reductions >= 10.0)       # seed 2: about tenfold
    assert np.all(before > 300.0)           # a real drift to remove [ug]
    assert_same_bag(bag, BAGS / 'temperature_cycle.mcap')


def test_calibration_stores_rom_that_restores_the_same_compensation():
    triad = thermal_triad(noise=NoiseConfig(bias_instability=0.3e-6 * 9.80665))
    state = CalibrationState()
    settings = TemperatureSettings(period_s=1200.0)
    result = run_schedule(triad, temperature_schedule(triad, state, settings))
    assert result.applied and triad.temperature_compensation
    for calibration in result.calibrations:
        assert calibration.reduction >= 30.0  # a lower noise floor allows 30x
    restored = CalibrationState.from_dict(json.loads(json.dumps(state.to_dict())))
    other = thermal_triad(seed=5)
    restored.apply_to(other)
    v = np.linspace(0.2, 1.2, 50)
    for mine, theirs in zip(triad.temperature_compensators, other.temperature_compensators):
        assert np.array_equal(mine.evaluate_fixed(v), theirs.evaluate_fixed(v))
    assert 'temperature calibration' in result.summary()


def test_compensated_output_follows_the_fixed_point_model():
    triad = thermal_triad(noise=NoiseConfig.off())
    run_schedule(triad, temperature_schedule(triad, CalibrationState(), SHORT))
    triad.thermal.set_ambient(ambient_profile='cycle', cycle_period_s=600.0)
    compensated = triad.run_for(60.0)
    v = compensated.v_temp
    expected = np.column_stack([c.evaluate_fixed(v, clip=True)
                                for c in triad.temperature_compensators])
    triad.temperature_compensation = False
    # Same instants on a fresh identical sensor without compensation differ by the model.
    twin = thermal_triad(noise=NoiseConfig.off())
    run_schedule(twin, temperature_schedule(twin, CalibrationState(),
                                            TemperatureSettings(period_s=600.0, apply=False)))
    twin.thermal.set_ambient(ambient_profile='cycle', cycle_period_s=600.0)
    raw = twin.run_for(60.0)
    assert_allclose(raw.accel - compensated.accel, expected, atol=1e-12)


def test_without_thermal_model_the_schedule_is_refused():
    triad = QfaTriad(TriadConfig(), rng=0)
    with pytest.raises(EstimationError, match='thermal model'):
        run_schedule(triad, temperature_schedule(triad, CalibrationState(), SHORT))


def test_moving_input_is_refused_and_ambient_restored():
    profile = SineProfile(1.0, amplitude=(0.0, 0.0, 0.1), offset=(0.0, 0.0, 9.8))
    triad = thermal_triad(profile=profile)
    with pytest.raises(EstimationError, match='static'):
        run_schedule(triad, temperature_schedule(triad, CalibrationState(), SHORT))
    assert triad.thermal.config.ambient_profile == 'constant'
    assert not triad.temperature_compensation


@pytest.mark.parametrize('kwargs, name', [({'low_c': 80.0}, 'low_c'),
                                          ({'period_s': 10.0}, 'period_s'),
                                          ({'bins': 3}, 'bins'),
                                          ({'m_bits': 40}, 'm_bits')])
def test_invalid_temperature_settings_raise_value_error(kwargs, name):
    with pytest.raises(ValueError, match=name):
        TemperatureSettings(**kwargs)


def test_sim_paper_scenario_prints_the_papers_tables(tmp_path):
    out = io.StringIO()
    from qfa_ros.cli.sim import build_parser, run_paper_2019
    args = build_parser().parse_args(['paper-2019', '--trials', '2',
                                      '--out', str(tmp_path / 'paper.mcap')])
    assert run_paper_2019(args, out=out) == 0
    text = out.getvalue()
    assert 'Table 3' in text and 'Table 4' in text and 'Eq. 31' in text
    assert (tmp_path / 'paper.mcap').exists()


def test_sim_rejects_bad_arguments(capsys):
    assert sim_main(['static', '--duration', '-1']) == 2
    assert sim_main(['static', '--out', 'x.bag']) == 2
    assert 'must' in capsys.readouterr().err
