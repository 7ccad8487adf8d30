"""Fleet studies: validation before work, identical results whatever the workers, resume."""

from contextlib import contextmanager
import importlib.util
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from statistics_helpers import normal_bound

# On the library floor (.venv-jazzy) the fleet studies' tools are not installed: pyarrow 26
# needs numpy 2 (requirements/tools-floor.txt).
pq = pytest.importorskip('pyarrow.parquet', reason='the fleet studies need pyarrow, which '
                         'needs numpy 2: not on the library floor (tools-floor.txt)')

from qfa_ros.cli.fleet import main as fleet_main  # noqa: E402
from qfa_ros.fleet.runner import (  # noqa: E402
    batch_table,
    code_digest,
    parts_directory,
    run_study,
)
from qfa_ros.fleet.self_calibration_unit import simulate_unit  # noqa: E402
from qfa_ros.fleet.study import Study, StudyError  # noqa: E402
from qfa_ros.fleet.summary import format_summary  # noqa: E402

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



def test_a_scheduler_address_that_is_none_is_one_line(tmp_path, capsys):
    """Before: Dask's ValueError as a traceback."""
    study = write_study(tmp_path / 'study.yaml', CHEAP)
    assert fleet_main([str(study), '--scheduler', 'nonsense!!', '--no-progress']) == 2
    err = capsys.readouterr().err
    assert err.startswith('qfa-fleet: --scheduler: ') and err.count('\n') == 1, err
    assert list(tmp_path.iterdir()) == [study], 'nothing made before the refusal'


@pytest.mark.parametrize('case, expected', [
    # Before: a traceback (RecursionError), a message quoting the line, MemoryError reading
    # /dev/zero, a FIFO that blocked forever.
    ('[' * 1000, 'not YAML (nested too deeply)'),
    ('units: 2\nname: SECRET\n: : :\n', 'not YAML (line 3, column 1)'),
    ('fifo', 'cannot read the study file: not a regular file'),
    ('device', 'cannot read the study file: not a regular file'),
    ('big', 'more than the 1048576 read'),
])
def test_a_study_file_that_is_none_is_refused_without_reading_or_quoting_it(tmp_path, capsys,
                                                                            case, expected):
    study = tmp_path / 'study.yaml'
    if case == 'fifo':
        os.mkfifo(study)
    elif case == 'device':
        study.symlink_to('/dev/zero')
    else:
        study.write_text(f'# SECRET\n{" " * (1 << 20)}' if case == 'big' else case)
    assert fleet_main([str(study), '--workers', '1', '--no-progress']) == 2
    err = capsys.readouterr().err
    assert expected in err and err.count('\n') == 1 and 'SECRET' not in err, err
    assert not list(tmp_path.glob('*.parquet*'))


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


def test_uniform_aging_stays_within_its_span():
    # Uniform in +-a: variance a^2 / 3, the sample variance's standard error
    # a^2 sqrt((1/5 - 1/9) / n); per seed (5 x 2000 draws) and pooled, within z = 5.45 of
    # it, a false failure of 1e-6 per test over the 6 checks (test/statistics_helpers.py).
    study = Study.one_calibration('improved', 200.0, torquer_drift=True, units=1)
    seeds, n, span = range(3, 8), 2000, 200.0
    z = normal_bound(len(seeds) + 1)
    samples = [[study.aging.draw(rng, span) for _ in range(n)]
               for rng in map(np.random.default_rng, seeds)]
    for rates in samples + [np.ravel(samples)]:
        assert max(map(abs, rates)) <= span
        se = span ** 2 * np.sqrt((1 / 5 - 1 / 9) / len(rates))
        assert abs(np.mean(np.square(rates)) - span ** 2 / 3) < z * se
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


@contextmanager
def sigint_as_at_a_terminal():
    """
    Start commands with SIGINT at its default, as a terminal's foreground command has it.

    A suite started in the background of a script (``pytest &``) inherits SIGINT ignored,
    and so would a command it starts, which then rightly keeps ignoring it (as Python and
    the shells do). A handler of this process becomes the default in a child at ``exec``.
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize('when', ['starting', 'running'])
def test_ctrl_c_stops_a_study_with_one_line_and_keeps_its_batches(tmp_path, when):
    study_file = write_study(tmp_path / 'study.yaml', {**CHEAP, 'units': 4})
    parts = parts_directory(tmp_path / 'study.parquet')
    # 'starting': the parts directory is prepared and the cluster starts (its workers
    # ignore SIGINT meanwhile, the command must not); 'running': a batch is done.
    ready = ((lambda: (parts / 'study.json').exists()) if when == 'starting'
             else (lambda: bool(list(parts.glob('batch-*.parquet')))))
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    # Ctrl-C signals the terminal's whole process group: the command and its workers.
    with sigint_as_at_a_terminal():
        process = subprocess.Popen(
            [sys.executable, '-m', 'qfa_ros.cli.fleet', str(study_file), '--workers', '1',
             '--no-progress'], cwd=tmp_path, env=env, start_new_session=True,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline and not ready():
            assert process.poll() is None, process.communicate()
            time.sleep(0.05)
        os.killpg(process.pid, signal.SIGINT)
        out, err = process.communicate(timeout=60)
    except BaseException:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
        raise
    assert process.returncode == 130, err
    assert 'Traceback' not in err and 'KeyboardInterrupt' not in err, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    kept = len(list(parts.glob('batch-*.parquet')))
    assert (when == 'starting' or kept >= 1) and kept < 4
    assert lines[0] == (f'qfa-fleet: interrupted; {kept} of 4 batches kept in '
                        f'{parts}: the same command resumes')
    # No worker outlives the command.
    deadline = time.monotonic() + 30
    while True:
        try:
            os.killpg(process.pid, 0)
        except ProcessLookupError:
            break
        assert time.monotonic() < deadline, 'a worker process outlived qfa-fleet'
        time.sleep(0.1)


def _digest_of_copy(tmp_path, edit=None):
    """Return ``code_digest()`` of a copy of qfa_ros/ after ``edit(copy)``."""
    copy = tmp_path / f'copy{len(list(tmp_path.glob("copy*")))}' / 'qfa_ros'
    shutil.copytree(ROOT / 'qfa_ros', copy, ignore=shutil.ignore_patterns('__pycache__'))
    if edit:
        edit(copy)
    spec = importlib.util.spec_from_file_location(f'runner_{copy.parent.name}',
                                                  copy / 'fleet' / 'runner.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.code_digest()


def _append(relative, text):
    def edit(copy):
        path = copy / relative
        path.write_text((path.read_text() if path.exists() else '') + text)
    return edit


def test_code_digest_follows_the_simulating_code_only(tmp_path):
    digest = code_digest()
    assert len(digest) == 16
    assert _digest_of_copy(tmp_path) == digest, 'the same sources give the same digest'
    # One changed constant in the model changes the digest; so does a new module there.
    assert _digest_of_copy(tmp_path, _append('model/design.py', '\nEXTRA = 1\n')) != digest
    assert _digest_of_copy(tmp_path, _append('calibration/new_stage.py', 'X = 1\n')) != digest
    # The node and the recorder do not compute a unit's rows.
    assert _digest_of_copy(tmp_path, _append('ros/node.py', '\n# note\n')) == digest


def test_drawn_component_coefficients_differ_per_unit_and_move_no_other_draw():
    # Issue 28: component_tcs drawn gives each unit its own I_ref and forward-chain
    # temperature coefficients; the aging draws (another stream) stay the same.
    from qfa_ros.model import random_streams
    from qfa_ros.model.drawn_unit import draw_component_tcs
    draws = [draw_component_tcs(random_streams.seed_sequence([0, i], 'unit.component_tcs'))
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


# --- studies on one shared two-worker cluster (last: it is torn down after them) ---

@pytest.fixture(scope='module')
def cluster_client():
    """Yield a client of a two-worker local cluster, shared by this module's studies.

    Each cluster start costs seconds of CPU (a nanny and a worker process each, importing
    Dask, the model and its kernels); the studies here share one (``run_study(client=)``,
    ``qfa-fleet --scheduler``). ``run_study`` starting its own cluster is exercised by
    every ``qfa-fleet --workers 1`` command this module starts (the Ctrl-C tests).
    """
    import logging

    from dask.distributed import Client, LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=':0',
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client


def test_one_and_two_workers_give_identical_tables(tmp_path, cluster_client):
    # One worker runs the batches one after another in one process: so does this process,
    # the three units in one batch, after the other units this module simulated here. Two
    # worker processes, one unit a batch, finishing in any order, give the same table: a
    # unit's rows depend on its own seed only, not on the process, batch or order it ran in.
    study = Study.from_dict(CHEAP)
    one = batch_table(study, 0, study.units)
    two = run_study(study, tmp_path / 'two.parquet', client=cluster_client, progress=False,
                    log=lambda line: None)
    assert two.num_rows == study.units * study.calibrations
    assert two.replace_schema_metadata(None).equals(one)
    assert pq.read_table(tmp_path / 'two.parquet').equals(two)
    # The summary's rows say what they compare: the estimate rows are not the accuracy.
    summary = format_summary(two)
    assert '| scale-factor error after (known input): the accuracy [ppm] |' in summary
    feedback = next(line for line in summary.splitlines() if 'feedback estimate -' in line)
    assert 'k_VI k_DA drift alone' in feedback and 'not an error' in feedback
    assert 'temperature change since the reference' in feedback


FIRST_TWO_BATCHES_ONLY = """
import sys
import threading

from dask import distributed

from qfa_ros.cli import fleet


def first_two_batches_only(futures, **options):
    futures = list(futures)
    for future in futures[:2]:
        distributed.wait(future)
        yield future
    threading.Event().wait()  # never returns: the command is killed meanwhile


distributed.as_completed = first_two_batches_only
sys.exit(fleet.main(sys.argv[1:]))
"""
"""``qfa-fleet`` that writes the batches of units 0 and 1, then hangs (a run killed half way).

The hang is in the command, not in a task: the command runs on the shared cluster
(``--scheduler``), whose workers must stay free for the tests after it.
"""


def test_killed_study_restarts_with_only_the_missing_units(tmp_path, cluster_client):
    study_file = write_study(tmp_path / 'study.yaml', CHEAP)
    out = tmp_path / 'study.parquet'
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    # The command hangs after its second batch: the kill always finds two batches written
    # and one not, however fast or slow the machine.
    log = open(tmp_path / 'fleet.log', 'w')
    process = subprocess.Popen(
        [sys.executable, '-c', FIRST_TWO_BATCHES_ONLY, str(study_file),
         '--scheduler', cluster_client.scheduler.address, '--no-progress'],
        cwd=tmp_path, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=log)
    parts = parts_directory(out)
    deadline = time.monotonic() + 240
    try:
        # Each batch appears by an atomic rename: a file seen is a finished batch.
        while len(list(parts.glob('batch-*.parquet'))) < 2:
            assert time.monotonic() < deadline, 'two batches not written in 240 s'
            try:
                process.wait(timeout=0.05)
            except subprocess.TimeoutExpired:
                continue
            pytest.fail('the study ended before it was killed: '
                        + (tmp_path / 'fleet.log').read_text())
    finally:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(timeout=30)
        log.close()
    kept = {path.name: path.stat().st_mtime_ns for path in parts.glob('batch-*.parquet')}
    assert sorted(kept) == ['batch-0000000-0000001.parquet', 'batch-0000001-0000002.parquet']
    lines = []
    table = run_study(Study.load(study_file), out, client=cluster_client, progress=False,
                      log=lines.append)
    assert lines[0].startswith(f'{len(kept)} of 3 batches already done'), lines
    assert {p.name: p.stat().st_mtime_ns for p in parts.glob('batch-*.parquet')
            if p.name in kept} == kept, 'finished batches must not be recomputed'
    assert sorted(set(table.column('unit').to_pylist())) == [0, 1, 2]


# A 360 s program and a 30 s body time constant (its soaks 10 of them): ~1 CPU-s a unit,
# half the 720 s / 60 s one's. Zero drift up to 19 ug against the 30 ug limit (12-16 at
# 720 s / 60 s); without the compensation ('apply': False) 2150 ug.
TEMPERATURE = {'kind': 'temperature', 'units': 2, 'batch_units': 1, 'seed': 3,
               'temperature': {'period_s': 360.0, 'block_s': 2.0, 'bins': 40},
               'sensor': {'sensor_tau_s': 30.0, 'loop_rate_hz': 2000.0,
                          'sample_rate_hz': 100.0, 'crossover_hz': 100.0},
               'verification': {'temperatures_c': [-27.0, 8.0, 41.0, 64.0],
                                'average_s': 1.0}}


def test_temperature_study_calibrates_and_verifies_every_unit(tmp_path, cluster_client):
    from qfa_ros.fleet.summary import format_summary, temperature_rows
    from qfa_ros.fleet.temperature_unit import unit_seed
    study = Study.from_dict(TEMPERATURE)
    assert study.calibrations == 1
    table = run_study(study, tmp_path / 'temperature.parquet', client=cluster_client,
                      progress=False, log=lambda line: None)
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
