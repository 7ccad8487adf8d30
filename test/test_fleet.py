"""Fleet studies: validation before work, identical results whatever the workers, resume."""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

import numpy as np
import pyarrow.parquet as pq
import pytest

from qfa_ros.cli.fleet import main as fleet_main
from qfa_ros.fleet.runner import code_digest, parts_directory, run_study
from qfa_ros.fleet.study import Study, StudyError
from qfa_ros.fleet.unit import simulate_unit

ROOT = Path(__file__).resolve().parents[1]
# A short schedule keeps a unit at about a second of CPU.
CHEAP = {'units': 3, 'batch_units': 1, 'horizon_years': 0.05,
         'calibration_interval_days': 18.0,
         'schedule': {'name': 'improved',
                      'forward': {'points': 3, 'average_s': 0.05},
                      'feedback': {'cycles': 2, 'average_s': 0.1}}}


def write_study(path, data):
    import yaml
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize('change, key', [
    ({'unitz': 3}, 'unitz'),
    ({'horizon_years': -1.0}, 'horizon_years'),
    ({'schedule': {'name': 'weekly-magic'}}, 'schedule.name'),
    ({'schedule': {'name': 'paper', 'feedback': {'cycle': 3}}}, 'schedule.feedback.cycle'),
    ({'aging': {'feedback_ppm_per_year': 'lots'}}, 'aging.feedback_ppm_per_year'),
    ({'environment': {'error_profile': 'mars'}}, 'environment.error_profile'),
    ({'aging': {'distribution': 'cauchy'}}, 'aging.distribution'),
    ({'environment': {'magnet_tc_ppm': 'warm'}}, 'environment.magnet_tc_ppm'),
    ({'environment': {'component_tcs': 'guessed'}}, 'environment.component_tcs'),
    ({'kind': 'vibration'}, 'kind'),
    ({'kind': 'temperature', 'temperature': {'period': 60}}, 'temperature.period'),
    ({'kind': 'temperature', 'sensor': {'sensor_tau_s': -1.0}}, 'sensor.sensor_tau_s'),
    ({'kind': 'temperature', 'verification': {'temperatures_c': [20.0]}},
     'verification.temperatures_c'),
])
def test_bad_study_fails_before_starting_and_names_the_key(tmp_path, capsys, change, key):
    study = write_study(tmp_path / 'bad.yaml', {**CHEAP, **change})
    with pytest.raises(StudyError, match=key.replace('.', r'\.')):
        Study.load(study)
    assert fleet_main([str(study), '--workers', '1', '--no-progress']) == 2
    assert key in capsys.readouterr().err
    assert not list(tmp_path.glob('*.parquet*')), 'nothing may start for a bad study'


def test_study_validation_keeps_good_values():
    study = Study.from_dict(CHEAP)
    assert study.calibrations == 1
    assert study.batches == [(0, 1), (1, 2), (2, 3)]
    assert study.schedule_settings().feedback.cycles == 2
    assert study.digest() == Study.from_dict({**CHEAP, 'name': 'other'}).digest()
    assert study.digest() != Study.from_dict({**CHEAP, 'seed': 1}).digest()


def test_one_and_two_workers_give_identical_tables(tmp_path):
    study = Study.from_dict(CHEAP)
    one = run_study(study, tmp_path / 'one.parquet', workers=1, progress=False,
                    log=lambda line: None)
    two = run_study(study, tmp_path / 'two.parquet', workers=2, progress=False,
                    log=lambda line: None)
    assert one.num_rows == study.units * study.calibrations
    assert one.equals(two)
    assert pq.read_table(tmp_path / 'one.parquet').equals(pq.read_table(tmp_path / 'two.parquet'))
    # A unit's rows depend on its own seed only, not on the batch it ran in.
    alone = simulate_unit(study, 2)
    assert one.slice(2, 1).to_pylist() == alone


def test_killed_study_restarts_with_only_the_missing_units(tmp_path):
    study_file = write_study(tmp_path / 'study.yaml', {**CHEAP, 'units': 4})
    out = tmp_path / 'study.parquet'
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    process = subprocess.Popen(
        [sys.executable, '-m', 'qfa_ros.cli.fleet', str(study_file), '--workers', '1',
         '--no-progress'], cwd=tmp_path, env=env, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    parts = parts_directory(out)
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline and len(list(parts.glob('batch-*.parquet'))) < 2:
            assert process.poll() is None, 'the study ended before it could be killed'
            time.sleep(0.05)
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
    kept = {path.name: path.stat().st_mtime_ns for path in parts.glob('batch-*.parquet')}
    assert 2 <= len(kept) < 4, kept
    lines = []
    table = run_study(Study.load(study_file), out, workers=1, progress=False,
                      log=lines.append)
    assert lines[0].startswith(f'{len(kept)} of 4 batches already done'), lines
    assert {p.name: p.stat().st_mtime_ns for p in parts.glob('batch-*.parquet')
            if p.name in kept} == kept, 'finished batches must not be recomputed'
    assert sorted(set(table.column('unit').to_pylist())) == [0, 1, 2, 3]


def test_uniform_aging_stays_within_its_span():
    study = Study.one_calibration('improved', 200.0, torquer_drift=True, units=1)
    rng = np.random.default_rng(3)
    rates = [study.aging.draw(rng, 200.0) for _ in range(2000)]
    assert max(map(abs, rates)) <= 200.0
    assert np.std(rates) == pytest.approx(200.0 / np.sqrt(3), rel=0.05)
    assert study.calibrations == 1 and study.environment.magnet_tc_ppm is None
    stable = Study.one_calibration('paper', 100.0, torquer_drift=False, units=1)
    assert stable.environment.magnet_tc_ppm == 0.0 and stable.aging.torquer_ppm_per_year == 0


def test_results_of_another_study_are_not_mixed_in(tmp_path):
    out = tmp_path / 'mixed.parquet'
    parts_directory(out).mkdir()
    (parts_directory(out) / 'study.json').write_text('{"digest": "0000"}')
    with pytest.raises(StudyError, match='another study'):
        run_study(Study.from_dict(CHEAP), out, workers=1, progress=False)


def test_results_of_other_model_code_are_not_mixed_in(tmp_path):
    study = Study.from_dict(CHEAP)
    out = tmp_path / 'upgraded.parquet'
    parts_directory(out).mkdir()
    (parts_directory(out) / 'study.json').write_text(json.dumps(
        {'digest': study.digest(), 'code': 'an-older-model'}))
    with pytest.raises(StudyError, match='other model code'):
        run_study(study, out, workers=1, progress=False)
    assert code_digest() == code_digest() and len(code_digest()) == 16


def test_drawn_component_coefficients_differ_per_unit_and_move_no_other_draw():
    # Issue 28: component_tcs drawn gives each unit its own I_ref and forward-chain
    # temperature coefficients; the aging draws (another stream) stay the same.
    from qfa_ros.model.unit import COMPONENT_TC_KEY, draw_component_tcs
    draws = [draw_component_tcs(np.random.SeedSequence([0, i], spawn_key=(COMPONENT_TC_KEY,)))
             for i in range(3)]
    assert len({round(float(i_ref[0]), 6) for i_ref, _ in draws}) == 3
    drawn = Study.from_dict({**CHEAP, 'units': 1,
                             'environment': {'component_tcs': 'drawn'}})
    typed = Study.from_dict({**CHEAP, 'units': 1})
    assert drawn.digest() != typed.digest()
    row_drawn, = simulate_unit(drawn, 0)
    row_typed, = simulate_unit(typed, 0)
    for axis in 'xyz':
        # Same aging, so the same drift truths; other coefficients, other estimates.
        assert row_drawn[f'feedback_truth_ppm_{axis}'] == pytest.approx(
            row_typed[f'feedback_truth_ppm_{axis}'], abs=1e-6)


TEMPERATURE = {'kind': 'temperature', 'units': 2, 'batch_units': 1, 'seed': 3,
               'temperature': {'period_s': 720.0, 'block_s': 2.0, 'bins': 40},
               'sensor': {'sensor_tau_s': 60.0, 'loop_rate_hz': 2000.0,
                          'sample_rate_hz': 100.0, 'crossover_hz': 100.0},
               'verification': {'temperatures_c': [-27.0, 8.0, 41.0, 64.0],
                                'average_s': 1.0}}


def test_temperature_study_calibrates_and_verifies_every_unit(tmp_path):
    from qfa_ros.fleet.summary import format_summary, temperature_rows
    from qfa_ros.fleet.temperature_unit import unit_seed
    study = Study.from_dict(TEMPERATURE)
    assert study.calibrations == 1
    table = run_study(study, tmp_path / 'temperature.parquet', workers=1, progress=False,
                      log=lambda line: None)
    assert table.num_rows == 2
    rows = table.to_pylist()
    assert [r['unit_seed'] for r in rows] == [unit_seed(study, 0), unit_seed(study, 1)]
    for row in rows:
        assert row['probe_lag_s'] == pytest.approx(row['probe_tau_s'], abs=0.3)
        assert {f'zd_roll_p90_ug_{a}' for a in 'xyz'} <= set(row)
        for axis in 'xyz':
            assert 0 < row[f'zd_max_ug_{axis}'] < 30.0
            assert row[f'sf_max_ppm_{axis}'] < 20.0
    assert len(temperature_rows(table)) == 9
    summary = format_summary(table)
    assert 'units within every limit' in summary and '2 of 2' in summary
