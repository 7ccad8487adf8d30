"""The package layout the foundation issue asks for (ament_python, one-command setup)."""

import ast
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ET

ROOT = Path(__file__).resolve().parents[1]


def test_package_xml_is_format_3_ament_python_with_the_runtime_dependencies():
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == 'qfa_ros'
    assert root.findtext('export/build_type') == 'ament_python'
    exec_depends = {e.text for e in root.findall('exec_depend')}
    assert {'rclpy', 'sensor_msgs', 'std_srvs', 'std_msgs', 'diagnostic_msgs',
            'python3-numpy', 'python3-scipy'} <= exec_depends
    # Packages without a system rosdep key use pip keys.
    assert {'python3-numba-pip', 'python3-mcap-pip'} <= exec_depends


def test_card_top_level_exists():
    for name in ('package.xml', 'setup.py', 'setup.cfg', 'resource/qfa_ros', 'qfa_ros',
                 'config', 'test', 'bags', 'README.md', 'Makefile', 'bench', '.ci/run'):
        assert (ROOT / name).exists(), name
    assert (ROOT / 'resource' / 'qfa_ros').is_file()


def test_console_scripts_install_where_ros2_run_finds_them():
    cfg = (ROOT / 'setup.cfg').read_text()
    assert 'script_dir=$base/lib/qfa_ros' in cfg
    assert 'install_scripts=$base/lib/qfa_ros' in cfg
    tree = ast.parse((ROOT / 'setup.py').read_text())
    entry_points = [ast.literal_eval(keyword.value) for node in ast.walk(tree)
                    if isinstance(node, ast.Call) for keyword in node.keywords
                    if keyword.arg == 'entry_points']
    assert len(entry_points) == 1
    scripts = entry_points[0]['console_scripts']
    names = {entry.split('=')[0].strip() for entry in scripts}
    assert {'qfa-sim', 'qfa-node', 'qfa_node', 'qfa-replay', 'qfa-report'} <= names
    assert 'qfa-sim = qfa_ros.cli.sim:main' in scripts


def test_make_targets_and_ci_entry_point():
    makefile = (ROOT / 'Makefile').read_text()
    for target in ('run:', 'test:'):
        assert f'\n{target}' in makefile
    # Both set up .venv from the pinned requirements; ROS wheels only without rclpy.
    assert 'requirements/ros.txt' in makefile and 'import rclpy' in makefile
    assert 'make test' in (ROOT / '.ci' / 'run').read_text()
    for requirement in (ROOT / 'requirements').glob('*.txt'):
        for line in requirement.read_text().splitlines():
            line = line.split('#')[0].strip()
            assert not line or '==' in line, f'{requirement.name}: unpinned {line!r}'


ROS_FREE_LAYERS = ('model', 'calibration', 'bag', 'report', 'fleet')
"""Layers that must run without ROS 2; only qfa_ros.ros and qfa_ros.cli map onto it."""

ROS_PACKAGES = ('rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'std_srvs',
                'geometry_msgs', 'diagnostic_msgs', 'rosgraph_msgs', 'builtin_interfaces',
                'rosidl_runtime_py')


def test_model_and_recording_modules_never_import_ros():
    modules = sorted(f'{layer}.{p.stem}' for layer in ROS_FREE_LAYERS
                     for p in (ROOT / 'qfa_ros' / layer).glob('*.py'))
    assert {'model.triad', 'model.kernel', 'calibration.estimation', 'bag.writer',
            'bag.imu_cdr', 'model.thermal'} <= set(modules)
    code = ('import sys\n'
            f'for name in {modules!r}:\n'
            '    __import__("qfa_ros." + name)\n'
            f'print(sorted(m for m in sys.modules if m.split(".")[0] in {ROS_PACKAGES!r}))\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=ROOT, check=True, timeout=120)
    assert result.stdout.strip() == '[]'
