"""The package layout the foundation issue asks for (ament_python, one-command setup)."""

import ast
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ET

ROOT = Path(__file__).resolve().parents[1]


# The import name of every third-party module qfa_ros/ imports, and the rosdep key of
# package.xml that provides it. Keys checked in ros/rosdistro (rosdep/python.yaml,
# rosdep/base.yaml, kilted/distribution.yaml): `mcap` has no key of its own and comes
# with mcap-ros2-support; numba has a system key (python3-numba).
ROSDEP_KEYS = {
    'rclpy': 'rclpy', 'rcl_interfaces': 'rcl_interfaces',
    'ament_index_python': 'ament_index_python', 'sensor_msgs': 'sensor_msgs',
    'std_msgs': 'std_msgs', 'std_srvs': 'std_srvs', 'geometry_msgs': 'geometry_msgs',
    'diagnostic_msgs': 'diagnostic_msgs', 'rosgraph_msgs': 'rosgraph_msgs',
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib', 'numba': 'python3-numba',
    'mcap': 'mcap-ros2-support', 'mcap_ros2': 'mcap-ros2-support',
    'launch': 'launch', 'launch_ros': 'launch_ros', 'tqdm': 'python3-tqdm',
    'nav_msgs': 'nav_msgs', 'rosbags': 'python3-rosbags-pip',
}
# No rosdep key exists for these (checked in rosdep/python.yaml): only the fleet studies
# (qfa-fleet) use them, and they come from requirements/base.txt with pip.
PIP_ONLY = {'dask', 'distributed', 'pyarrow'}
TEST_KEYS = {'pytest': 'python3-pytest', 'pytest-timeout': 'python3-pytest-timeout',
             'ruff': 'python3-ruff-pip', 'hypothesis': 'python3-hypothesis'}


def imported_modules(paths):
    """Return the top-level names of every module imported by the files in ``paths``."""
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names.update(alias.name.split('.')[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names.add(node.module.split('.')[0])
    return names


def test_package_xml_declares_every_import_by_an_existing_rosdep_key():
    root = ET.parse(ROOT / 'package.xml').getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    assert root.findtext('name') == 'qfa_ros'
    assert root.findtext('export/build_type') == 'ament_python'
    exec_depends = {e.text for e in root.findall('exec_depend')}
    sources = [*(ROOT / 'qfa_ros').rglob('*.py'), *(ROOT / 'launch').glob('*.launch.py')]
    third_party = {name for name in imported_modules(sources)
                   if name not in sys.stdlib_module_names and name != 'qfa_ros'}
    unknown = third_party - set(ROSDEP_KEYS) - PIP_ONLY
    assert not unknown, f'no rosdep key known for {unknown}'
    missing = {ROSDEP_KEYS[name] for name in third_party - PIP_ONLY} - exec_depends
    assert not missing, f'package.xml does not declare {missing}'
    # What has no rosdep key stays in the fleet layer and is pinned for pip.
    outside_fleet = [p for p in sources if 'fleet' not in p.parts]
    assert not PIP_ONLY & imported_modules(outside_fleet)
    pinned = (ROOT / 'requirements' / 'base.txt').read_text()
    assert all(f'{name}==' in pinned for name in PIP_ONLY)
    # The keys that turned out not to exist in rosdep are gone.
    assert not {'python3-numba-pip', 'python3-mcap-pip'} & exec_depends


def test_test_dependencies_are_declared_as_the_tests_use_them():
    root = ET.parse(ROOT / 'package.xml').getroot()
    test_depends = {e.text for e in root.findall('test_depend')}
    assert set(TEST_KEYS.values()) <= test_depends
    assert not {'ament_flake8', 'ament_pep257'} & test_depends, 'declared but not used'
    assert 'timeout' in (ROOT / 'pytest.ini').read_text()  # pytest-timeout
    assert 'ruff' in (ROOT / 'test' / 'test_lint.py').read_text()
    assert 'rosbags' in imported_modules((ROOT / 'test').glob('test_*.py'))


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
    assert names == {'qfa-sim', 'qfa_node', 'qfa-replay', 'qfa-report', 'qfa-fleet'}
    targets = [entry.split('=')[1].strip() for entry in scripts]
    assert len(set(targets)) == len(targets), 'one executable name per program'
    assert 'qfa-sim = qfa_ros.cli.sim:main' in scripts
    assert 'qfa_node = qfa_ros.cli.node:main' in scripts
    assert "glob('launch/*.launch.py')" in (ROOT / 'setup.py').read_text()
    assert '/launch' in (ROOT / 'setup.py').read_text()


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
