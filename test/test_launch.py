"""The launch files: installed, one node with the shipped parameters and a namespace, two units."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / 'launch'


def node_calls(path):
    """Return the keyword arguments (as source text) of every ``Node(...)`` call in ``path``."""
    calls = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'Node':
            calls.append({k.arg: ast.unparse(k.value) for k in node.keywords})
    return calls


def declared_arguments(path):
    return [ast.literal_eval(node.args[0]) for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.Call)
            and getattr(node.func, 'id', None) == 'DeclareLaunchArgument']


def test_qfa_launch_starts_the_node_with_the_shipped_parameters_in_a_namespace():
    path = LAUNCH / 'qfa.launch.py'
    assert {'namespace', 'params_file'} <= set(declared_arguments(path))
    call, = node_calls(path)
    assert call['package'] == "'qfa_ros'" and call['executable'] == "'qfa_node'"
    assert call['namespace'] == "LaunchConfiguration('namespace')"
    assert call['parameters'] == "[LaunchConfiguration('params_file')]"
    text = path.read_text()
    assert "get_package_share_directory('qfa_ros'), 'config', 'qfa.yaml'" in text
    # The shipped parameters apply under any name and namespace.
    assert (ROOT / 'config' / 'qfa.yaml').read_text().count("'/**':") == 1


def test_two_units_launch_starts_two_namespaced_units_with_their_own_identity():
    path = LAUNCH / 'two_units.launch.py'
    call, = node_calls(path)  # one call in a comprehension over UNITS
    assert call['namespace'] == 'unit'
    for key in ('seed', 'hardware_id', 'frame_id', 'state_file'):
        assert f"'{key}'" in call['parameters']
    units = next(ast.literal_eval(node.value) for node in ast.parse(path.read_text()).body
                 if isinstance(node, ast.Assign) and node.targets[0].id == 'UNITS')
    assert len({unit for unit, _ in units}) == 2 and len({seed for _, seed in units}) == 2


def test_launch_descriptions_load_with_ros2_launch():
    pytest.importorskip('launch_ros', reason='launch_ros is not installed (no Kilted wheel); '
                        'docs/getting_started.md lists how the launch files were run instead')
    from launch.launch_description_sources import PythonLaunchDescriptionSource
    for name, entities in (('qfa.launch.py', ['DeclareLaunchArgument'] * 3 + ['Node']),
                           ('two_units.launch.py', ['Node', 'Node'])):
        description = PythonLaunchDescriptionSource(
            str(LAUNCH / name)).try_get_launch_description_without_context()
        assert [type(e).__name__ for e in description.entities] == entities
