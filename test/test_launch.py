"""
The launch files: installed, one node with the shipped parameters and a namespace, two units.

``launch`` and ``launch_ros`` have no wheel beside the Kilted ones (PyPI's ``launch`` is an
unrelated project), so ``ros2 launch`` cannot run here. Each launch file's
``generate_launch_description()`` runs instead against recording stand-ins of the few
``launch``/``launch_ros`` classes it uses; every ``Node`` it describes is then started the
way ``launch_ros`` starts it (the installed executable, ``__node``/``__ns`` remappings, one
parameters file per entry), from a share directory laid out by ``setup.py``'s
``data_files``, and asked for its name and parameters; the managed launch's
``ChangeState`` events and ``OnStateTransition`` handlers are played as launch plays them
(each event one ``~/change_state`` call, a handler whose node reached its goal state runs
its actions once). What remains untested here is
``launch`` itself: ``test_launch_descriptions_load_with_ros2_launch`` runs where it is
installed.
"""

import ast
from glob import glob
import importlib.util
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import types

from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from node_helpers import Client, domain_id, ImuCollector, node_environment
import pytest

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'launch'


class Entity:
    """A ``launch``/``launch_ros`` object as the launch file built it: kind and arguments."""

    def __init__(self, kind, *args, **kwargs):
        self.kind, self.args, self.kwargs = kind, args, kwargs


def setup_keywords():
    """Return the literal-evaluable keyword arguments of ``setup()`` in setup.py as AST."""
    tree = ast.parse((ROOT / 'setup.py').read_text())
    call = next(node for node in ast.walk(tree) if isinstance(node, ast.Call)
                and getattr(node.func, 'id', None) == 'setup')
    return {keyword.arg: keyword.value for keyword in call.keywords}


def install_share(prefix):
    """Copy what setup.py's ``data_files`` installs under ``prefix``; return the share dir."""
    data_files = eval(compile(ast.Expression(setup_keywords()['data_files']), 'setup.py',
                              'eval'),
                      {'glob': lambda pattern: sorted(glob(str(ROOT / pattern))),
                       'package_name': 'qfa_ros'})
    for destination, sources in data_files:
        (prefix / destination).mkdir(parents=True, exist_ok=True)
        for source in sources:
            shutil.copy(ROOT / source, prefix / destination)
    return prefix / 'share' / 'qfa_ros'


def console_scripts():
    """Return ``{executable: 'module:function'}`` of setup.py's console scripts."""
    entries = ast.literal_eval(setup_keywords()['entry_points'])['console_scripts']
    return dict((part.strip() for part in entry.split('=')) for entry in entries)


def load_description(path, monkeypatch, share):
    """Run ``generate_launch_description()`` of ``path``; return its entities."""
    for module_name, names in (
            ('launch', ['LaunchDescription']),
            ('launch.actions', ['DeclareLaunchArgument', 'EmitEvent', 'RegisterEventHandler']),
            ('launch.events', ['matches_action']),
            ('launch.substitutions', ['LaunchConfiguration']),
            ('launch_ros', []), ('launch_ros.actions', ['Node', 'LifecycleNode']),
            ('launch_ros.event_handlers', ['OnStateTransition']), ('launch_ros.events', []),
            ('launch_ros.events.lifecycle', ['ChangeState'])):
        module = types.ModuleType(module_name)
        for name in names:
            setattr(module, name, (lambda kind: lambda *a, **k: Entity(kind, *a, **k))(name))
        monkeypatch.setitem(sys.modules, module_name, module)
    ament = types.ModuleType('ament_index_python.packages')
    ament.get_package_share_directory = lambda package: str({'qfa_ros': share}[package])
    monkeypatch.setitem(sys.modules, 'ament_index_python.packages', ament)
    spec = importlib.util.spec_from_file_location(path.name.split('.')[0] + '_launch', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert description.kind == 'LaunchDescription'
    entities, = description.args
    return list(entities)


def resolve(value, arguments):
    """Return ``value`` with a ``LaunchConfiguration`` replaced by its argument's value."""
    if isinstance(value, Entity) and value.kind == 'LaunchConfiguration':
        return arguments[value.args[0]]
    return value


def node_command(node, arguments, directory):
    """Return the command ``launch_ros`` runs for a ``Node`` entity."""
    options = {key: resolve(value, arguments) for key, value in node.kwargs.items()}
    assert options['package'] == 'qfa_ros'
    target = console_scripts()[options['executable']]  # installed in lib/qfa_ros
    module, function = target.split(':')
    command = [sys.executable, '-c', f'import sys; from {module} import {function}; '
               f'sys.exit({function}())', '--ros-args', '-r', f'__node:={options["name"]}']
    if options.get('namespace'):
        command += ['-r', f'__ns:=/{options["namespace"]}']
    for index, entry in enumerate(options.get('parameters', [])):
        entry = resolve(entry, arguments)
        if isinstance(entry, dict):  # launch_ros writes a dict to a parameters file
            path = directory / f'{options.get("namespace")}_{index}.yaml'
            path.write_text(json.dumps({'/**': {'ros__parameters': entry}}))
            entry = path
        command += ['--params-file', str(entry)]
    return command


def run_nodes(commands, domain, home):
    """Start the node commands with ``HOME`` at ``home``; return the processes."""
    env = {**node_environment(domain), 'HOME': str(home), 'PYTHONPATH': str(ROOT)}
    log = open(home / 'nodes.log', 'w')
    try:
        return [subprocess.Popen(command, env=env, cwd=home, stdout=log,
                                 stderr=subprocess.STDOUT) for command in commands]
    finally:
        log.close()


def stop(processes):
    for process in processes:
        process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def ask(domain, node, names):
    """Return the values of parameters ``names`` of ``node`` (``/ns/name``)."""
    client = Client(domain, target=node.lstrip('/'))
    try:
        return dict(zip(names, client.get_parameters(names, timeout=90.0)))
    finally:
        client.close()


def test_qfa_launch_starts_the_node_with_the_shipped_parameters_in_a_namespace(
        tmp_path, monkeypatch):
    share = install_share(tmp_path / 'install')
    entities = load_description(LAUNCH / 'qfa.launch.py', monkeypatch, share)
    declared = {e.args[0]: e.kwargs['default_value'] for e in entities
                if e.kind == 'DeclareLaunchArgument'}
    assert set(declared) == {'namespace', 'node_name', 'params_file'}
    assert Path(declared['params_file']) == share / 'config' / 'qfa.yaml'
    node, = (e for e in entities if e.kind == 'Node')
    # ros2 launch qfa_ros qfa.launch.py namespace:=imu1
    command = node_command(node, {**declared, 'namespace': 'imu1'}, tmp_path)
    domain = domain_id('launch_one')
    processes = run_nodes([command], domain, tmp_path)
    try:
        values = ask(domain, '/imu1/qfa_node', ['sample_rate_hz', 'frame_id'])
    finally:
        stop(processes)
    shipped = (ROOT / 'config' / 'qfa.yaml').read_text()
    assert f"sample_rate_hz: {values['sample_rate_hz']}" in shipped
    assert f"frame_id: '{values['frame_id']}'" in shipped


def test_two_units_launch_starts_two_namespaced_units_with_their_own_identity(
        tmp_path, monkeypatch):
    share = install_share(tmp_path / 'install')
    nodes = load_description(LAUNCH / 'two_units.launch.py', monkeypatch, share)
    assert [node.kind for node in nodes] == ['Node', 'Node']
    namespaces = [node.kwargs['namespace'] for node in nodes]
    domain = domain_id('launch_two')
    processes = run_nodes([node_command(node, {}, tmp_path) for node in nodes], domain,
                          tmp_path)
    names = ['seed', 'hardware_id', 'frame_id', 'state_file', 'sample_rate_hz']
    try:
        units = [ask(domain, f'/{namespace}/qfa_node', names) for namespace in namespaces]
    finally:
        stop(processes)
    assert len(set(namespaces)) == 2
    # Two units are two draws with their own identity; the shipped parameters otherwise.
    for name in ('seed', 'hardware_id', 'frame_id', 'state_file'):
        assert units[0][name] != units[1][name], name
    assert units[0]['sample_rate_hz'] == units[1]['sample_rate_hz']
    assert all(namespace in unit['frame_id'] and namespace in unit['hardware_id']
               for namespace, unit in zip(namespaces, units))


def test_managed_units_launch_configures_both_in_order_then_activates_both(
        tmp_path, monkeypatch):
    share = install_share(tmp_path / 'install')
    entities = load_description(LAUNCH / 'managed_units.launch.py', monkeypatch, share)
    nodes = [e for e in entities if e.kind == 'LifecycleNode']
    handlers = [e.args[0] for e in entities if e.kind == 'RegisterEventHandler']
    assert len(nodes) == 2 and all(h.kind == 'OnStateTransition' for h in handlers)
    assert all(h.kwargs['handle_once'] for h in handlers)  # a later deactivate stays
    domain = domain_id('launch_managed')
    processes = run_nodes([node_command(node, {}, tmp_path) for node in nodes], domain,
                          tmp_path)
    client = Client(domain)
    imu = {node.kwargs['namespace']: ImuCollector(client, f'/{node.kwargs["namespace"]}'
                                                  '/imu/data_raw') for node in nodes}
    steps = []
    try:
        # As launch runs it: each EmitEvent(ChangeState) asks its node for the transition;
        # an OnStateTransition whose node reached its goal state runs its entities once.
        pending = [e for e in entities if e.kind == 'EmitEvent']
        while pending:
            event = pending.pop(0).kwargs['event']
            assert event.kind == 'ChangeState'
            matcher = event.kwargs['lifecycle_node_matcher']
            assert matcher.kind == 'matches_action'
            node, = matcher.args
            name = f'/{node.kwargs["namespace"]}/{node.kwargs["name"]}'
            request = ChangeState.Request()
            request.transition.id = event.kwargs['transition_id']
            assert client.call(ChangeState, f'{name}/change_state', request, 90.0).success
            state = client.call(GetState, f'{name}/get_state',
                                GetState.Request()).current_state.label
            steps.append((node.kwargs['namespace'], request.transition.id, state,
                          client.node.get_clock().now().nanoseconds))
            for handler in list(handlers):
                if handler.kwargs['target_lifecycle_node'] is node and \
                        handler.kwargs['goal_state'] == state:
                    handlers.remove(handler)
                    pending.extend(handler.kwargs['entities'])
        client.spin_until(lambda: all(len(c.samples) >= 100 for c in imu.values()), 60,
                          '100 samples of each unit')
    finally:
        client.close()
        stop(processes)
    configure, activate = Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE
    assert [step[:3] for step in steps] == [
        ('imu_a', configure, 'inactive'), ('imu_b', configure, 'inactive'),
        ('imu_a', activate, 'active'), ('imu_b', activate, 'active')]
    # Neither unit published before both were configured.
    both_configured = steps[1][3]
    assert all(c.samples[0][0] > both_configured for c in imu.values())


def test_launch_descriptions_load_with_ros2_launch():
    pytest.importorskip('launch_ros', reason='launch_ros is not installed (no Kilted wheel); '
                        'the other tests here run the descriptions without it')
    from launch.launch_description_sources import PythonLaunchDescriptionSource
    for name, entities in (('qfa.launch.py', ['DeclareLaunchArgument'] * 3 + ['Node']),
                           ('two_units.launch.py', ['Node', 'Node']),
                           ('managed_units.launch.py', ['LifecycleNode'] * 2
                            + ['RegisterEventHandler'] * 2 + ['EmitEvent'])):
        description = PythonLaunchDescriptionSource(
            str(LAUNCH / name)).try_get_launch_description_without_context()
        assert [type(e).__name__ for e in description.entities] == entities


def test_setup_installs_the_launch_files_and_the_parameters(tmp_path):
    share = install_share(tmp_path / 'install')
    assert sorted(p.name for p in (share / 'launch').iterdir()) == sorted(
        p.name for p in LAUNCH.glob('*.launch.py'))
    assert (share / 'config' / 'qfa.yaml').read_bytes() == \
        (ROOT / 'config' / 'qfa.yaml').read_bytes()
    assert os.path.isfile(share / 'package.xml')
