"""The package layout the foundation issue asks for (ament_python, one-command setup)."""

import ast
import configparser
from glob import glob
import importlib
import importlib.util
import itertools
import os
from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

from packaging.requirements import Requirement

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
    'lifecycle_msgs': 'lifecycle_msgs',
    # No key of their own: mcap requires both (its chunk compressions), and
    # mcap-ros2-support's pip install brings mcap.
    'lz4': 'mcap-ros2-support', 'zstandard': 'mcap-ros2-support',
}
# No rosdep key exists for these (checked in rosdep/python.yaml): only the fleet studies
# (qfa-fleet) use them, and they come from requirements/tools.txt with pip.
PIP_ONLY = {'dask', 'distributed', 'pyarrow'}
TEST_KEYS = {'pytest': 'python3-pytest', 'pytest-timeout': 'python3-pytest-timeout',
             'pytest-xdist': 'python3-pytest-xdist', 'ruff': 'python3-ruff-pip',
             'hypothesis': 'python3-hypothesis'}


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
    pinned = (ROOT / 'requirements' / 'tools.txt').read_text()
    assert all(f'{name}==' in pinned for name in PIP_ONLY)
    # The keys that turned out not to exist in rosdep are gone.
    assert not {'python3-numba-pip', 'python3-mcap-pip'} & exec_depends


def modules_run_with_dash_m(paths):
    """Return the modules the files in ``paths`` run as ``[..., '-m', 'module', ...]``."""
    names = set()
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.List):
                items = [e.value if isinstance(e, ast.Constant) else None for e in node.elts]
                names.update(item for previous, item in zip(items, items[1:])
                             if previous == '-m' and isinstance(item, str))
    return names


def test_test_dependencies_are_declared_as_the_tests_use_them():
    root = ET.parse(ROOT / 'package.xml').getroot()
    test_depends = {e.text for e in root.findall('test_depend')}
    assert set(TEST_KEYS.values()) <= test_depends
    assert not {'ament_flake8', 'ament_pep257'} & test_depends, 'declared but not used'
    tests = sorted((ROOT / 'test').glob('*.py'))
    used = imported_modules(tests) | modules_run_with_dash_m(tests)
    ini = configparser.ConfigParser()
    ini.read(ROOT / 'pytest.ini')
    if int(ini['pytest'].get('timeout', '0')) > 0:
        used.add('pytest-timeout')  # the plugin enforces pytest.ini's timeout
    if '-n' in ini['pytest'].get('addopts', '').split():
        used.add('pytest-xdist')  # the plugin runs pytest.ini's workers
    assert set(TEST_KEYS) <= used, f'declared, not used: {set(TEST_KEYS) - used}'


def test_card_top_level_exists():
    for name in ('package.xml', 'setup.py', 'setup.cfg', 'resource/qfa_ros', 'qfa_ros',
                 'config', 'test', 'bags', 'README.md', 'Makefile', 'bench', '.ci/run'):
        assert (ROOT / name).exists(), name
    assert (ROOT / 'resource' / 'qfa_ros').is_file()


def setup_keywords():
    """Return the keyword arguments of ``setup()`` in setup.py as AST nodes."""
    call = next(node for node in ast.walk(ast.parse((ROOT / 'setup.py').read_text()))
                if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'setup')
    return {keyword.arg: keyword.value for keyword in call.keywords}


def test_console_scripts_install_where_ros2_run_finds_them():
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / 'setup.cfg')
    assert cfg['develop']['script_dir'] == '$base/lib/qfa_ros'
    assert cfg['install']['install_scripts'] == '$base/lib/qfa_ros'
    keywords = setup_keywords()
    scripts = ast.literal_eval(keywords['entry_points'])['console_scripts']
    targets = dict((part.strip() for part in entry.split('=')) for entry in scripts)
    assert set(targets) == {'qfa-sim', 'qfa_node', 'qfa_lifecycle_node', 'qfa-replay',
                            'qfa-report', 'qfa-fleet'}
    assert len(set(targets.values())) == len(targets), 'one executable name per program'
    assert targets['qfa-sim'] == 'qfa_ros.cli.sim:main'
    assert targets['qfa_node'] == 'qfa_ros.cli.node:main'
    assert targets['qfa_lifecycle_node'] == 'qfa_ros.cli.node:lifecycle_main'
    for target in targets.values():
        module, function = target.split(':')
        assert callable(getattr(importlib.import_module(module), function)), target
    # data_files as setup() gets them: the launch files go to share/qfa_ros/launch.
    data_files = dict(eval(compile(ast.Expression(keywords['data_files']), 'setup.py', 'eval'),
                           {'glob': lambda pattern: sorted(glob(str(ROOT / pattern))),
                            'package_name': 'qfa_ros'}))
    launch_files = sorted(str(p) for p in (ROOT / 'launch').glob('*.launch.py'))
    assert launch_files and data_files['share/qfa_ros/launch'] == launch_files


FAKE_PYTHON = """#!/bin/sh
echo "$*" >> "$FAKE_LOG"
if [ "$1" = -c ]; then exit "$FAKE_RCLPY"; fi
if [ "$1 $2" = "-m venv" ]; then
  shift 2; [ "$1" = --system-site-packages ] && shift
  mkdir -p "$1/bin" "$1/lib/qfa_ros"; cp "$0" "$1/bin/python"
  printf '#!/bin/sh\necho "uv $*" >> "$FAKE_LOG"\nexit "$FAKE_UV"\n' > "$1/bin/uv"
  chmod +x "$1/bin/uv"
fi
exit 0
"""
"""A python that logs its arguments, answers ``import rclpy`` with $FAKE_RCLPY, makes venvs
with a ``uv`` that logs its arguments and exits with $FAKE_UV."""


def make_target(tmp_path, target, rclpy_status, distro=None, uv_status=0):
    """Run ``make TARGET`` on a copy of the project with a fake python; return its calls."""
    project = tmp_path / f'project{rclpy_status}{distro or ""}{uv_status}'
    if not project.exists():
        project.mkdir()
        for name in ('Makefile', 'setup.py', 'requirements'):
            (shutil.copytree if (ROOT / name).is_dir() else shutil.copy)(
                ROOT / name, project / name)
    python = tmp_path / 'python'
    python.write_text(FAKE_PYTHON)
    python.chmod(0o755)
    log = project / 'calls.log'
    log.unlink(missing_ok=True)
    # ROS_DISTRO as a sourced ROS 2 exports it, or as `make ... ROS_DISTRO=jazzy` gives it.
    env = make_environment()
    if distro:
        env['ROS_DISTRO'] = distro
    subprocess.run(['make', '-s', target, f'PYTHON={python}'], cwd=project, check=True,
                   capture_output=True, timeout=60,
                   env={**env, 'FAKE_LOG': str(log), 'FAKE_RCLPY': str(rclpy_status),
                        'FAKE_UV': str(uv_status)})
    return log.read_text().splitlines() if log.exists() else []


def make_environment():
    """
    Return this environment without a parent make's variables (CI runs us under make).

    Nor ``ROS_DISTRO``, which a sourced ROS 2 exports and the Makefile reads, nor the
    ``TESTS`` of a ``make test TESTS=...`` that runs this file.
    """
    return {k: v for k, v in os.environ.items()
            if k not in ('MAKEFLAGS', 'MAKELEVEL', 'MFLAGS', 'ROS_DISTRO', 'TESTS')}


def requirement_files(calls, installer='-m pip install'):
    """Return the ``-r`` files of every call of ``installer`` among ``calls``."""
    files = set()
    for call in calls:
        words = call.split()
        if call.startswith(installer):
            files |= {words[i + 1] for i, word in enumerate(words) if word == '-r'}
    return files


def installed_files(calls, venv, uv_status):
    """Return the requirement files installed by uv (into ``venv``) or, where uv failed, pip."""
    if uv_status:
        return requirement_files(calls)
    assert not requirement_files(calls), calls
    assert all(f'--python {venv}/bin/python ' in call
               for call in calls if call.startswith('uv pip install')), calls
    return requirement_files(calls, 'uv pip install')


WHEEL_SETS = {None: ('.venv', 'requirements/base.txt', 'requirements/ros.txt',
                     'requirements/tools.txt'),
              'kilted': ('.venv', 'requirements/base.txt', 'requirements/ros.txt',
                         'requirements/tools.txt'),
              'jazzy': ('.venv-jazzy', 'requirements/floor.txt', 'requirements/ros-jazzy.txt',
                        'requirements/tools-floor.txt')}
"""Per ROS_DISTRO: the venv, its libraries, its ROS 2 wheels and its tools (the Makefile)."""


def test_make_run_installs_the_node_only_and_make_setup_the_rest(tmp_path):
    for distro, (venv, libraries, wheels, tools) in WHEEL_SETS.items():
        # uv installs the requirements; where it fails, pip installs the same ones.
        for (rclpy_status, system, ros), uv_status in itertools.product(
                ((1, False, True), (0, True, False)), (0, 1)):
            # What `make run` needs: the libraries, and the distribution's ROS 2 wheels only
            # without a system rclpy.
            calls = make_target(tmp_path, f'{venv}/.qfa-node', rclpy_status, distro, uv_status)
            venv_call = next(call for call in calls if call.startswith('-m venv'))
            assert ('--system-site-packages' in venv_call.split()) == system, calls
            assert venv_call.split()[-1] == venv, calls
            assert installed_files(calls, venv, uv_status) == \
                {libraries} | ({wheels} if ros else set()), calls
            assert any(call.startswith('-m pip install') and call.endswith('-e .')
                       for call in calls), calls
            # `make setup` afterwards adds the tools and the test packages, and redoes nothing.
            calls = make_target(tmp_path, 'setup', rclpy_status, distro, uv_status)
            assert installed_files(calls, venv, uv_status) == {tools, 'requirements/test.txt'}, \
                calls
            assert not any(call.startswith('-m venv') for call in calls), calls
    # `make run` and `make sim` wait for the node's set-up only, `make test` for all of it.
    for distro, (venv, *_) in WHEEL_SETS.items():
        for target, prerequisite in (('run', f'{venv}/.qfa-node'), ('sim', f'{venv}/.qfa-node'),
                                     ('test', f'{venv}/.qfa-installed')):
            database = subprocess.run(['make', '-pnq', target] + ([f'ROS_DISTRO={distro}']
                                                                  if distro else []),
                                      cwd=ROOT, env=make_environment(), timeout=60,
                                      capture_output=True, text=True).stdout
            rule = next(line for line in database.splitlines()
                        if line.startswith(f'{target}:'))
            assert rule.split(':', 1)[1].split() == [prerequisite], rule


def test_the_floor_differs_from_the_pins_in_the_floor_libraries_alone():
    def pins(name):
        lines = (line.split('#')[0].strip()
                 for line in (ROOT / 'requirements' / name).read_text().splitlines())
        return dict(line.split('==') for line in lines if line)

    base, floor = pins('base.txt'), pins('floor.txt')
    assert set(base) == set(floor)
    differing = {name for name in base if base[name] != floor[name]}
    assert differing == {'numpy', 'scipy', 'numba', 'llvmlite'}
    # The floor is what package.xml promises (version_gte of its rosdep keys).
    root = ET.parse(ROOT / 'package.xml').getroot()
    stated = {e.text: e.get('version_gte') for e in root.findall('exec_depend')
              if e.get('version_gte')}
    assert stated == {f'python3-{name}': floor[name] for name in ('numpy', 'scipy', 'numba')}
    assert pins('tools-floor.txt') == {'matplotlib': pins('tools.txt')['matplotlib']}


def test_one_version_in_package_xml_setup_py_the_node_and_the_changelog():
    from catkin_pkg.changelog import get_changelog_from_path

    version = ET.parse(ROOT / 'package.xml').getroot().findtext('version')
    setup = subprocess.run([sys.executable, 'setup.py', '--version'], cwd=ROOT, timeout=120,
                           capture_output=True, text=True, check=True)
    assert setup.stdout.split()[-1] == version
    import qfa_ros
    assert qfa_ros.__version__ == version
    node = subprocess.run([sys.executable, '-m', 'qfa_ros.cli.node', '--version'], cwd=ROOT,
                          timeout=120, capture_output=True, text=True, check=True)
    assert node.stdout.startswith(f'qfa_node {version} (qfa_ros; ROS 2 '), node.stdout
    changelog = get_changelog_from_path(str(ROOT / 'CHANGELOG.rst'), 'qfa_ros')
    released = [str(entry[0]) for entry in changelog.foreach_version(reverse=True)]
    assert released[0] == version, 'CHANGELOG.rst: the newest entry is not the release'


def test_make_test_runs_pytest_and_ci_runs_make_test(tmp_path):
    # Under `make test` (CI) this make is a sub-make: without the parent's variables and
    # with --no-print-directory it prints only the recipe.
    dry = subprocess.run(['make', '-n', '--no-print-directory', '-o', '.venv/.qfa-installed',
                          'test'], cwd=ROOT, env=make_environment(), capture_output=True,
                         text=True, check=True, timeout=60)
    assert dry.stdout.split() == ['PYTHONDONTWRITEBYTECODE=', '.venv/bin/python', '-m', 'pytest']
    fake_make = tmp_path / 'make'
    fake_make.write_text('#!/bin/sh\necho "$QFA_TEST_BOTH_DISTRIBUTIONS $*" >> "$FAKE_LOG"\n')
    fake_make.chmod(0o755)
    subprocess.run(['bash', str(ROOT / '.ci' / 'run')], check=True, timeout=60,
                   capture_output=True,
                   env={**make_environment(), 'PATH': f'{tmp_path}:{os.environ["PATH"]}',
                        'FAKE_LOG': str(tmp_path / 'make.log'),
                        'QFA_TEST_BOTH_DISTRIBUTIONS': ''})
    # Both venvs first, side by side (the cross-distribution tests need both), then the
    # README's test command on Kilted and on Jazzy, each told that the other venv is there.
    calls = (tmp_path / 'make.log').read_text().splitlines()
    assert sorted(calls[:2]) == [' setup', ' setup ROS_DISTRO=jazzy']
    assert calls[2:] == ['1 test', '1 test ROS_DISTRO=jazzy']


def test_requirements_are_pinned():
    for requirement in (ROOT / 'requirements').glob('*.txt'):
        for line in requirement.read_text().splitlines():
            line = line.split('#')[0].strip()
            if line:
                specifiers = list(Requirement(line).specifier)
                assert [s.operator for s in specifiers] == ['=='], \
                    f'{requirement.name}: unpinned {line!r}'


ROS_FREE_LAYERS = ('model', 'calibration', 'bag', 'report', 'fleet')
"""Layers that must run without ROS 2; only qfa_ros.ros and qfa_ros.cli map onto it."""

ROS_PACKAGES = ('rclpy', 'rcl_interfaces', 'sensor_msgs', 'std_msgs', 'std_srvs',
                'geometry_msgs', 'diagnostic_msgs', 'rosgraph_msgs', 'builtin_interfaces',
                'rosidl_runtime_py')


def test_model_and_recording_modules_never_import_ros():
    # The fleet layer needs pyarrow, which the library floor (.venv-jazzy) has not.
    layers = [layer for layer in ROS_FREE_LAYERS
              if layer != 'fleet' or importlib.util.find_spec('pyarrow') is not None]
    modules = sorted(f'{layer}.{p.stem}' for layer in layers
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
