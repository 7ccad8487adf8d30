"""The architecture as a contract: layers, ROS only where it belongs, no circles."""

import ast
from pathlib import Path
import subprocess
import sys

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'qfa_ros'
LAYERS = ('model', 'calibration', 'bag', 'report', 'fleet', 'ros', 'cli')
LONG_MODULE_LINES = 500


def test_import_linter_contracts_are_kept():
    """Run import-linter on the shipped ``.importlinter`` (layers, rclpy only in ros/cli)."""
    lint_imports = Path(sys.executable).with_name('lint-imports')
    result = subprocess.run([str(lint_imports), '--no-cache'], capture_output=True, text=True,
                            cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert '4 kept, 0 broken' in result.stdout, result.stdout


def test_every_layer_is_a_subpackage_that_says_what_it_may_import():
    for layer in LAYERS:
        init = PACKAGE / layer / '__init__.py'
        assert init.is_file(), layer
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and 'import' in doc, f'{layer}/__init__.py must say what it may import'
    assert sorted(p.name for p in PACKAGE.glob('*.py')) == ['__init__.py'], \
        'modules belong in a layer subpackage'


def _modules():
    for path in sorted(PACKAGE.rglob('*.py')):
        yield path, '.'.join(path.relative_to(ROOT).with_suffix('').parts)


def test_no_import_cycles_between_modules():
    graph = grimp.build_graph('qfa_ros', cache_dir=None)
    modules = {m for m in graph.modules if m.startswith('qfa_ros')}
    visiting, done = set(), set()

    def visit(module, path):
        visiting.add(module)
        for imported in sorted(graph.find_modules_directly_imported_by(module) & modules):
            if imported.endswith('__init__') or imported in done:
                continue
            assert imported not in visiting, ' -> '.join(path + [imported])
            visit(imported, path + [imported])
        visiting.discard(module)
        done.add(module)

    for module in sorted(modules):
        if module not in done:
            visit(module, [module])


def test_no_private_name_imported_across_modules():
    offences = []
    for path, _ in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or '').startswith('qfa_ros'):
                offences += [f'{path.relative_to(ROOT)}: {alias.name} from {node.module}'
                             for alias in node.names if alias.name.startswith('_')]
    assert not offences


@pytest.mark.parametrize('path', [p for p, _ in _modules()], ids=lambda p: p.stem)
def test_long_modules_say_why(path):
    lines = len(path.read_text().splitlines())
    if lines <= LONG_MODULE_LINES:
        return
    doc = ast.get_docstring(ast.parse(path.read_text())) or ''
    assert 'one cohesive' in doc.lower(), \
        f'{path.relative_to(ROOT)} has {lines} lines: split it or say why it is one cohesive thing'
