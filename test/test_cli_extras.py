"""Without the figure and fleet tools (`make run` installs none) their commands say so."""

import os
from pathlib import Path
import subprocess
import sys

import pytest

from qfa_ros.cli.extras import needs_tools

ROOT = Path(__file__).resolve().parents[1]

# A None entry in sys.modules makes its import raise ModuleNotFoundError, as a package
# that is not installed does.
WITHOUT = 'import sys\nfor name in {hidden!r}:\n    sys.modules[name] = None\n' \
          'from qfa_ros.cli.{module} import main\nsys.exit(main({argv!r}))\n'


@pytest.mark.parametrize('module, hidden, argv, package', [
    ('report', ['matplotlib'], ['bags/static_10s.mcap', '--out', 'OUT'], 'matplotlib'),
    ('fleet', ['pyarrow', 'dask', 'distributed'],
     ['bench/studies/self_calibration_200.yaml', '--out', 'OUT/fleet.parquet'], 'pyarrow'),
])
def test_a_missing_tool_is_one_line_naming_it_and_how_to_install(tmp_path, module, hidden,
                                                                 argv, package):
    argv = [str(tmp_path) if word == 'OUT' else word.replace('OUT', str(tmp_path))
            for word in argv]
    script = WITHOUT.format(hidden=hidden, module=module, argv=argv)
    result = subprocess.run([sys.executable, '-c', script], cwd=ROOT, capture_output=True,
                            text=True, timeout=120, env={**os.environ, 'PYTHONPATH': str(ROOT)})
    assert result.returncode == 2, result.stderr
    assert result.stderr.count('\n') == 1, result.stderr
    assert f'needs {package}' in result.stderr and 'requirements/tools.txt' in result.stderr
    assert list(tmp_path.iterdir()) == [], 'nothing written'


def test_report_imu_yaml_needs_no_tool(tmp_path):
    script = WITHOUT.format(hidden=['matplotlib'], module='report',
                            argv=['imu-yaml', 'config/qfa.yaml', '--out',
                                  str(tmp_path / 'imu.yaml')])
    result = subprocess.run([sys.executable, '-c', script], cwd=ROOT, capture_output=True,
                            text=True, timeout=120, env={**os.environ, 'PYTHONPATH': str(ROOT)})
    assert result.returncode == 0, result.stderr
    assert (tmp_path / 'imu.yaml').is_file()


def test_any_other_missing_module_is_a_real_error():
    @needs_tools('qfa-example')
    def main(argv=None):
        import qfa_ros_no_such_module  # noqa: F401

    with pytest.raises(ModuleNotFoundError, match='qfa_ros_no_such_module'):
        main([])


# --- bad options: one line, nothing written -------------------------------------------------

@pytest.mark.parametrize('argv, expected', [
    # Before: OverflowError, MemoryError (a 21 PiB array), ZeroDivisionError and ValueError
    # tracebacks, and a .mcap.part left behind by a --start-time past 2262.
    (['static', '--duration', 'inf'], '--duration must be a positive finite'),
    (['static', '--duration', 'nan'], '--duration must be a positive finite'),
    (['static', '--duration', '1e12'], 'ends after 2262'),
    (['static', '--duration', '1e8'], 'GiB for the Allan deviation'),
    (['trajectory', '--duration', 'inf'], '--duration must be a positive finite'),
    (['temperature-cycle', '--duration', '1'], '--duration: period_s must be at least'),
    (['trajectory', '--rate', '0'], '--rate: sample_rate_hz must be'),
    (['trajectory', '--rate', '7'], '--rate: loop_rate_hz must be an integer multiple'),
    (['trajectory', '--truth-rate', '0'], '--truth-rate must be a positive finite'),
    (['trajectory', '--truth-rate', 'nan'], '--truth-rate must be a positive finite'),
    (['trajectory', '--yaw', 'nan'], '--yaw must be a finite'),
    (['static', '--seed', '-1'], '--seed must be non-negative'),
    (['static', '--start-time', '9999-01-01', '--out', 'OUT/x.mcap'], 'between 1970 and 2262'),
    (['static', '--start-time', '1900-01-01', '--out', 'OUT/x.mcap'], 'between 1970 and 2262'),
    (['static', '--duration', '1', '--out', 'OUT/missing/x.mcap'], 'No such file'),
])
def test_qfa_sim_refuses_a_bad_option_in_one_line_writing_nothing(tmp_path, capsys, argv,
                                                                  expected):
    from qfa_ros.cli.sim import main
    argv = [word.replace('OUT', str(tmp_path)) for word in argv]
    try:
        status = main(argv)
    except SystemExit as exit_:  # argparse
        status = exit_.code
    err = capsys.readouterr().err
    assert status in (1, 2) and expected in err, err
    assert 'Traceback' not in err and err.splitlines()[-1].startswith(('qfa-sim: ', 'usage'))
    assert list(tmp_path.iterdir()) == [], 'nothing written'


def test_qfa_sim_refuses_to_replace_an_existing_bag_in_one_line(tmp_path, capsys):
    from qfa_ros.cli.sim import main
    existing = tmp_path / 'x.mcap'
    existing.write_bytes(b'mine')
    assert main(['static', '--duration', '1', '--out', str(existing)]) == 1
    err = capsys.readouterr().err
    assert err == f'qfa-sim: {existing}: MCAP file already exists (pass overwrite=True)\n'
    assert existing.read_bytes() == b'mine' and list(tmp_path.iterdir()) == [existing]
