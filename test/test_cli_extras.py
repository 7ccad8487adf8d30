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
