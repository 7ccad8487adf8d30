"""
Jazzy and Kilted on one domain, and the node started from another ROS environment.

The suite runs in either distribution's venv (``make test``, ``make test
ROS_DISTRO=jazzy``); the tests here also use the *other* venv (:func:`other_distribution`:
skipped without it, failed without it in CI). Which distribution a process runs is read
from the libraries it has mapped (Fast DDS 2.14 is Jazzy's, 3.2 Kilted's), and that it
runs on its own environment's libraries alone from where they were mapped.
"""

import json
import os
from pathlib import Path
import subprocess
import sys

from node_helpers import (
    Client,
    domain_id,
    node_environment,
    NodeProcess,
    other_distribution,
    ROOT,
    VENVS,
)
import pytest
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu

from qfa_ros.cli.own_libraries import (
    BOOTSTRAP_GUARD,
    own_environment,
    own_library_directories,
    REEXEC_MARK,
    use_own_numba_cache,
    use_own_ros_libraries,
)
from qfa_ros.ros.distro import ros_distribution

PARAMETERS = {'state_file': '', 'sample_rate_hz': 1000.0}
FAST_DDS = {'libfastrtps.so.2.14': 'jazzy', 'libfastdds.so.3.2': 'kilted'}
"""The Fast DDS library each distribution's wheels map, by name."""


def mapped_files(pid):
    """Return the files process ``pid`` has mapped (/proc/PID/maps), resolved."""
    paths = set()
    for line in Path(f'/proc/{pid}/maps').read_text().splitlines():
        fields = line.split(maxsplit=5)
        if len(fields) == 6 and fields[5].startswith('/'):
            paths.add(os.path.realpath(fields[5].removesuffix(' (deleted)')))
    return paths


def distribution_of(pid):
    """Return the distribution of the Fast DDS that process ``pid`` runs on."""
    found = {distro for path in mapped_files(pid) for name, distro in FAST_DDS.items()
             if os.path.basename(path).startswith(name)}
    assert len(found) == 1, found
    return found.pop()


def foreign_files(pid, venv):
    """Return the files of ``venv`` mapped by process ``pid`` (which is not ``venv``'s)."""
    root = os.path.realpath(venv) + os.sep
    return sorted(path for path in mapped_files(pid) if path.startswith(root))


def test_a_client_of_one_distribution_talks_to_a_node_of_the_other(tmp_path):
    other, python = other_distribution()
    mine = ros_distribution()
    # Both directions at once, each on a domain of its own: this venv's node with the
    # other venv's client, the other venv's node with this venv's client.
    runs = {mine: (sys.executable, python), other: (python, sys.executable)}
    nodes, clients = {}, {}
    try:
        for distro, (node_python, client_python) in runs.items():
            domain = domain_id(f'cross-distribution node {distro}')
            # This venv's node forked (the same main, 0.4 CPU-s against 2.2 as a command):
            # what is about the start is the other venv's node, started as its command.
            nodes[distro] = NodeProcess(domain, tmp_path / distro,
                                        dict(PARAMETERS, output_dir=str(tmp_path / distro)),
                                        python=None if distro == mine else node_python)
            clients[distro] = subprocess.Popen(
                [str(client_python), str(ROOT / 'test' / 'cross_distro_client.py'),
                 str(domain)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                env=node_environment(domain, client_python), cwd=ROOT)
        for distro, client in clients.items():
            out, err = client.communicate(timeout=240)
            assert client.returncode == 0, err[-3000:] + nodes[distro].log()[-2000:]
            answers = json.loads(out)
            node_distro = distribution_of(nodes[distro].pid)
            assert node_distro == distro and answers['client'] != distro, answers['client']
            stamps = answers['stamps']
            # A best-effort subscriber of depth 5: samples in order on the 1 ms grid.
            steps = [b - a for a, b in zip(stamps, stamps[1:])]
            assert len(stamps) == 300 and all(s > 0 and s % 1_000_000 == 0 for s in steps)
            assert answers['latched'] is False  # a late subscriber gets the latched value
            success, message = answers['service']
            assert not success and message.startswith('no stored corrections'), message
            assert answers['accepted'] == [True, '']
            refused, reason = answers['refused']
            assert not refused and 'drift.feedback_ppm' in reason and 'nan' in reason, reason
            assert answers['read'] == [[200.0, -150.0, 300.0], 1000.0]
    finally:
        for client in clients.values():
            client.kill()
            client.wait()
        for node in nodes.values():
            node.stop()


def cache_files(directory):
    """Return ``{path: modification time [ns]}`` of the files under ``directory``."""
    return {path: path.stat().st_mtime_ns for path in Path(directory).rglob('*')
            if path.is_file()}


def fake_environment(root, venv, leave_out=()):
    """
    Lay out ``root/lib`` as another environment's library directory; return it.

    Symbolic links to ``venv``'s libraries, those whose names start with one of
    ``leave_out`` left out (an environment without those message packages).
    """
    lib = root / 'lib'
    lib.mkdir(parents=True)
    for library in (Path(venv) / 'lib').glob('lib*.so*'):
        if not library.name.startswith(tuple(leave_out)):
            (lib / library.name).symlink_to(library)
    return lib


def sourced_ros_environment(root, venv, distro, domain):
    """
    Return what a sourced ROS 2 ``setup.bash`` of ``distro`` exports, simulated.

    No ROS 2 installation is here: ``root/opt/ros/DISTRO`` is laid out like one from
    ``venv``'s libraries and ROS Python packages (links), under another Python's
    ``lib/python3.12/site-packages`` as on Ubuntu 24.04; the variables are those of
    ``/opt/ros/jazzy/setup.bash`` (``LD_LIBRARY_PATH``, ``PYTHONPATH``,
    ``AMENT_PREFIX_PATH``, ``ROS_DISTRO``, ``ROS_VERSION``, ``ROS_PYTHON_VERSION``,
    ``PATH``). The wheels' bootstrap guard is not set, as a sourced ROS 2 does not set it.
    """
    prefix = root / 'opt' / 'ros' / distro
    lib = fake_environment(prefix, venv)
    python_path = lib / 'python3.12' / 'site-packages'
    python_path.mkdir(parents=True)
    site = next((Path(venv) / 'lib').glob('python3*/site-packages'))
    for package in ('rclpy', 'rpyutils', 'rcl_interfaces', 'builtin_interfaces', 'std_msgs',
                    'sensor_msgs', 'nav_msgs', 'ament_index_python'):
        (python_path / package).symlink_to(site / package)
    (prefix / 'bin').mkdir()
    env = node_environment(domain, Path(venv) / 'bin' / 'python')
    env.pop(BOOTSTRAP_GUARD, None)
    env.update(LD_LIBRARY_PATH=str(lib), PYTHONPATH=str(python_path),
               AMENT_PREFIX_PATH=str(prefix), ROS_DISTRO=distro, ROS_VERSION='2',
               ROS_PYTHON_VERSION='3', PATH=f'{prefix / "bin"}:{env["PATH"]}')
    return env


def test_the_node_started_from_another_ros_environment_runs_on_its_own_libraries(tmp_path):
    """
    The node streams on its own distribution, none of another environment's files mapped.

    Started from the other distribution's venv (with every message package the node uses),
    from an environment without nav_msgs, and from a sourced ROS 2 (simulated).
    """
    other, python = other_distribution()
    program = str(Path(sys.prefix) / 'bin' / 'qfa_node')
    domains = {case: domain_id(f'foreign: {case}')
               for case in ('another venv', 'without nav_msgs', 'sourced ROS 2')}
    # A process of the other venv (its bootstrap made LD_LIBRARY_PATH and the guard) that
    # replaces itself with this venv's qfa_node: what such a launcher hands down.
    execute = 'import os, sys; os.execv(sys.argv[1], sys.argv[1:])'
    commands = {'another venv': [str(python), '-c', execute, program],
                'without nav_msgs': [program], 'sourced ROS 2': [program]}
    lib = fake_environment(tmp_path / 'no_nav_msgs', VENVS[other], leave_out=('libnav_msgs',))
    environments = {
        'another venv': node_environment(domains['another venv'], python),
        'without nav_msgs': dict(node_environment(domains['without nav_msgs'], python),
                                 LD_LIBRARY_PATH=str(lib), **{BOOTSTRAP_GUARD: '1'}),
        'sourced ROS 2': sourced_ros_environment(tmp_path / 'sourced', VENVS[other], other,
                                                 domains['sourced ROS 2'])}
    # The other venv's numba cache (Jazzy's has one), which its processes hand down.
    other_cache = cache_files(VENVS[other] / 'numba_cache')
    nodes = {}
    try:
        for case, domain in domains.items():
            nodes[case] = NodeProcess(domain, tmp_path / case.replace(' ', '_'),
                                      dict(PARAMETERS, output_dir=str(tmp_path)),
                                      command=commands[case], env=environments[case])
        for case, node in nodes.items():
            client = Client(domains[case])
            try:
                stamps = []
                client.node.create_subscription(
                    Imu, 'imu/data_raw', lambda m: stamps.append(m.header.stamp),
                    qos_profile_sensor_data)
                client.spin_until(lambda: len(stamps) >= 50 or node.process.poll() is not None,
                                  120, f'samples of the node started from {case}')
            finally:
                client.close()
            assert len(stamps) >= 50, f'{case}: {node.log()[-3000:]}'
            assert distribution_of(node.pid) == ros_distribution(), case
            assert foreign_files(node.pid, VENVS[other]) == [], case
        # Left alone: this venv's numba compiled nothing into it (nor found it stale).
        assert cache_files(VENVS[other] / 'numba_cache') == other_cache
    finally:
        for node in nodes.values():
            node.stop()


def test_the_environment_a_node_of_this_venv_needs(tmp_path):
    own = own_library_directories()
    assert own[0] == str(Path(sys.prefix) / 'lib')
    assert own_environment(os.environ, own) is None  # this process's: nothing to change
    other = fake_environment(tmp_path / 'other', Path(sys.prefix))
    python_path = tmp_path / 'site-packages'
    (python_path / 'rclpy').mkdir(parents=True)
    kept = tmp_path / 'mine'
    kept.mkdir()
    environ = {'LD_LIBRARY_PATH': f'{other}:{kept}', 'PYTHONPATH': f'{python_path}:{kept}',
               'ROS_DISTRO': 'jazzy'}
    env = own_environment(environ, own)
    # This venv's directories first, the other's ROS libraries and rclpy gone, the rest kept.
    assert env['LD_LIBRARY_PATH'].split(':') == own + [str(kept)]
    assert env['PYTHONPATH'] == str(kept) and env[BOOTSTRAP_GUARD] == '1'
    assert env['ROS_DISTRO'] == 'jazzy' and environ['LD_LIBRARY_PATH'] == f'{other}:{kept}'


def test_a_program_started_from_another_venv_keeps_to_its_own_numba_cache(tmp_path):
    # Another venv's cache (the Jazzy venv's .pth sets it) holds another numba's index.
    mine, other = tmp_path / 'mine', tmp_path / 'other'
    for venv in (mine, other):
        (venv / 'numba_cache').mkdir(parents=True)
        (venv / 'pyvenv.cfg').write_text('home = /usr/bin\n')
    environ = {'NUMBA_CACHE_DIR': str(other / 'numba_cache')}
    assert use_own_numba_cache(environ, prefix=mine) == str(mine / 'numba_cache')
    assert environ == {'NUMBA_CACHE_DIR': str(mine / 'numba_cache')}
    assert use_own_numba_cache(environ, prefix=mine) is False  # its own: kept
    # A venv without a cache of its own (Kilted's) caches in __pycache__.
    (mine / 'numba_cache').rmdir()
    environ = {'NUMBA_CACHE_DIR': str(other / 'numba_cache' / 'sub')}
    assert use_own_numba_cache(environ, prefix=mine) is None and environ == {}
    # A directory outside any venv is the user's choice.
    environ = {'NUMBA_CACHE_DIR': str(tmp_path)}
    assert use_own_numba_cache(environ, prefix=mine) is False
    assert environ == {'NUMBA_CACHE_DIR': str(tmp_path)}


def test_a_node_still_in_another_environment_after_its_restart_refuses_in_one_line(
        tmp_path, capsys):
    lib = fake_environment(tmp_path / 'other', Path(sys.prefix))
    environ = {'LD_LIBRARY_PATH': str(lib), BOOTSTRAP_GUARD: '1', REEXEC_MARK: '1'}
    with pytest.raises(SystemExit) as stopped:
        use_own_ros_libraries(environ, program='qfa_node')
    assert stopped.value.code == 1
    line = capsys.readouterr().err
    assert line.count('\n') == 1 and line.startswith('qfa_node: cannot start on this ')
    assert 'env -u LD_LIBRARY_PATH -u _ROS_WHEELS_BOOTSTRAP_COMPLETE -u PYTHONPATH' in line
    # Other programs load no ROS library: nothing to check.
    assert use_own_ros_libraries(environ, program='qfa-sim') is None


@pytest.mark.parametrize('variable', ['FASTDDS_DEFAULT_PROFILES_FILE',
                                      'FASTRTPS_DEFAULT_PROFILES_FILE'])
def test_a_fast_dds_profile_given_by_either_name_reaches_fast_dds(tmp_path, variable):
    # A profile Fast DDS cannot parse: its error says the file was read.
    broken = tmp_path / 'broken.xml'
    broken.write_text('<dds><profiles')
    domain = domain_id('profile variable')
    env = node_environment(domain)
    env.pop('FASTDDS_DEFAULT_PROFILES_FILE', None)
    env.pop('FASTRTPS_DEFAULT_PROFILES_FILE', None)
    env[variable] = str(broken)
    script = ('from qfa_ros.ros.fastdds import use_shipped_fastdds_profile\n'
              'use_shipped_fastdds_profile()\n'
              'import rclpy\n'
              'rclpy.init()\n'
              'rclpy.create_node("qfa_profile_probe").destroy_node()\n'
              'rclpy.shutdown()\n')
    result = subprocess.run([sys.executable, '-c', script], env=env, capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    # Fast DDS 2.14 logs to stdout, 3.2 to stderr.
    assert f"Error parsing '{broken}'" in result.stdout + result.stderr, result.stderr
