"""The architecture as a contract: layers, ROS only where it belongs, no circles."""

import ast
import functools
import importlib
import inspect
from pathlib import Path
import subprocess
import sys
import textwrap

import grimp

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'qfa_ros'
LAYERS = ('model', 'calibration', 'bag', 'report', 'fleet', 'ros', 'cli')
LONG_MODULE_LINES = 600


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


@functools.cache
def _walked(path):
    """Return every node of the syntax tree of ``path`` (``ast.walk``), parsed and walked once.

    The parse and the walk are most of the time of the checks below, which share them.
    """
    return tuple(ast.walk(ast.parse(path.read_text())))


def test_no_private_name_imported_across_modules():
    offences = []
    for path, _ in _modules():
        for node in _walked(path):
            if isinstance(node, ast.ImportFrom) and (node.module or '').startswith('qfa_ros'):
                offences += [f'{path.relative_to(ROOT)}: {alias.name} from {node.module}'
                             for alias in node.names if alias.name.startswith('_')]
    assert not offences


# Documented public API that happens to start with an underscore.
PUBLIC_UNDERSCORE_NAMES = {
    '_fields_',  # ctypes.Structure field list (ctypes documentation)
    '_replace', '_asdict', '_fields', '_make',  # collections.namedtuple methods
    '_exit',  # os._exit (documented: exit without cleanup, as after fork)
}
"""Names allowed as attributes of other packages' objects: their documentation makes them public.

Everything else a name in qfa_ros/ reaches with a leading underscore must be defined in
qfa_ros/ itself (the allow-list of private dependency attributes is empty)."""


def _private(name):
    return name.startswith('_') and not (name.startswith('__') and name.endswith('__'))


def _project_private_names(modules_nodes):
    """Return every private name qfa_ros/ defines: functions, classes, attributes, variables.

    ``modules_nodes``: per module, the list of its syntax tree's nodes (``ast.walk``).
    """
    names = set()
    for nodes in modules_nodes:
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.arg):
                names.add(node.arg)
            elif isinstance(node, ast.keyword) and node.arg:
                names.add(node.arg)  # dataclass fields built with keywords
            elif isinstance(node, ast.alias):
                names.add(node.asname or node.name.split('.')[0])
    return {name for name in names if _private(name)}


def _dependency_private_names(nodes):
    """Return, per class of a module, the private names its other-package base classes use.

    ``nodes``: the module's syntax tree's nodes (``ast.walk``).

    A class of qfa_ros/ that derives from another package's class (``rclpy.node.Node``,
    ``threading.Thread``) must neither read nor overwrite that class's private state
    (``self._parameter_overrides``) or methods (``Thread._stop``).
    """
    imported = {}
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.level == 0 and \
                not node.module.startswith('qfa_ros'):
            imported.update({alias.asname or alias.name: (node.module, alias.name)
                             for alias in node.names})
        elif isinstance(node, ast.Import):
            imported.update({alias.asname or alias.name.split('.')[0]:
                             (alias.name if alias.asname else alias.name.split('.')[0], None)
                             for alias in node.names if not alias.name.startswith('qfa_ros')})
    found = {}
    for node in nodes:
        if not isinstance(node, ast.ClassDef):
            continue
        names = set()
        for base in node.bases:
            chain = []
            while isinstance(base, ast.Attribute):
                chain.insert(0, base.attr)
                base = base.value
            if not isinstance(base, ast.Name) or base.id not in imported:
                continue
            module, name = imported[base.id]
            cls = importlib.import_module(module)
            for part in ([name] if name else []) + chain:
                cls = getattr(cls, part)
            for ancestor in inspect.getmro(cls) if inspect.isclass(cls) else ():
                names |= _private_names_of_class(ancestor)
        found[node.name] = names
    return found


@functools.cache
def _private_names_of_class(cls):
    """Return the private attributes and methods the source of ``cls`` itself uses.

    Cached: many classes of qfa_ros/ share an ancestor (``rclpy.node.Node``, ``object``),
    whose source is parsed once.
    """
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):  # built in (ctypes.Structure, object)
        return frozenset()
    names = set()
    for item in ast.walk(ast.parse(source)):
        if isinstance(item, ast.Attribute) and _private(item.attr):
            names.add(item.attr)
        elif isinstance(item, ast.FunctionDef) and _private(item.name):
            names.add(item.name)
    return frozenset(names)


def private_dependency_uses(sources):
    """Return ``file:line: what`` for each private name of another package qfa_ros/ touches."""
    walked = {path: _walked(path) for path in sources}
    allowed = _project_private_names(walked.values()) | PUBLIC_UNDERSCORE_NAMES
    offences = []
    for path, nodes in walked.items():
        where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
        for node in nodes:
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                modules = [node.module] + [f'{node.module}.{a.name}' for a in node.names]
            else:
                modules = []
            offences += [f'{where}:{node.lineno}: imports {module}' for module in modules
                         if not module.startswith('qfa_ros')
                         and any(_private(part) for part in module.split('.'))]
            if isinstance(node, ast.Attribute) and _private(node.attr) and \
                    node.attr not in allowed:
                offences.append(f'{where}:{node.lineno}: .{node.attr}')
        inherited_by_class = _dependency_private_names(nodes)
        for cls in (n for n in nodes if isinstance(n, ast.ClassDef)):
            inherited = inherited_by_class.get(cls.name)
            if not inherited:
                continue
            offences += [f'{where}:{node.lineno}: {cls.name} touches inherited .{node.attr}'
                         for node in ast.walk(cls)
                         if isinstance(node, ast.Attribute) and node.attr in inherited
                         and isinstance(node.value, ast.Name) and node.value.id == 'self']
    return sorted(set(offences))


def test_no_private_attribute_of_a_dependency_is_used():
    offences = private_dependency_uses(sorted(PACKAGE.rglob('*.py')))
    assert not offences, 'private names of other packages:\n' + '\n'.join(offences)


LONG_MODULES = {
}
"""Modules allowed over LONG_MODULE_LINES: path -> (line budget, why it stays one module).

Growing past the budget, or a new module past LONG_MODULE_LINES, fails until a reviewer
either splits the module or raises its budget here (a visible decision in the diff)."""


def long_module_offences(package=PACKAGE, limit=LONG_MODULE_LINES, allowed=LONG_MODULES):
    """Return why each module of ``package`` breaks its line budget (empty when none does)."""
    offences = []
    for path in sorted(package.rglob('*.py')):
        name = path.relative_to(package).as_posix()
        lines = len(path.read_text().splitlines())
        budget = allowed.get(name, (limit, None))[0]
        if lines > budget:
            offences.append(f'{name}: {lines} lines > {budget}: split it, or raise its budget '
                            'in LONG_MODULES with the reason')
    offences += [f'{name}: in LONG_MODULES but missing or no longer long: drop the entry'
                 for name in allowed if not (package / name).is_file()
                 or len((package / name).read_text().splitlines()) <= limit]
    return offences


def test_long_modules_are_the_reviewed_few():
    offences = long_module_offences()
    assert not offences, '\n'.join(offences)


NODE_MODULE_LINES = 300
"""Line budget of ``ros/node.py``: the node class wires its collaborators; parameter,
service, input and diagnostics plumbing lives in a collaborator of ``ros/``."""


def test_the_node_module_stays_within_its_budget():
    lines = len((PACKAGE / 'ros' / 'node.py').read_text().splitlines())
    assert lines <= NODE_MODULE_LINES, \
        f'ros/node.py: {lines} lines > {NODE_MODULE_LINES}: move plumbing to a collaborator'


LONG_FUNCTION_LINES = 80

LONG_FUNCTIONS = {
    'calibration/estimation.py:feedback_schedule': (
        84, 'a schedule generator whose progress reporting is being reworked apart; '
        'split along its seams (the estimate after the segments) once that is merged'),
}
"""Functions allowed over LONG_FUNCTION_LINES: ``module:name`` -> (line budget, why).

A compiled hot loop (``@njit``) is exempt: splitting it costs a call per step. Any other
function past LONG_FUNCTION_LINES (``def`` line to its last, docstring included) fails
until it is split along its seams or given a budget here with the reason."""


def _compiled(function):
    return any('njit' in ast.unparse(decorator) for decorator in function.decorator_list)


def long_function_offences(package=PACKAGE, limit=LONG_FUNCTION_LINES,
                           allowed=LONG_FUNCTIONS):
    """Return why each function of ``package`` breaks its line budget (empty when none does)."""
    offences, seen = [], set()
    for path in sorted(package.rglob('*.py')):
        module = path.relative_to(package).as_posix()
        for node in _walked(path):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) \
                    or _compiled(node):
                continue
            name = f'{module}:{node.name}'
            lines = node.end_lineno - node.lineno + 1
            budget = allowed.get(name, (limit, None))[0]
            if name in allowed and lines > limit:
                seen.add(name)
            if lines > budget:
                offences.append(f'{name} (line {node.lineno}): {lines} lines > {budget}: '
                                'split it along its seams, or give it a budget in '
                                'LONG_FUNCTIONS with the reason')
    offences += [f'{name}: in LONG_FUNCTIONS but missing or no longer long: drop the entry'
                 for name in allowed if name not in seen]
    return offences


def test_long_functions_are_compiled_loops_or_the_reviewed_few():
    offences = long_function_offences()
    assert not offences, '\n'.join(offences)


def test_the_function_check_finds_a_long_function_and_spares_a_kernel(tmp_path):
    body = ''.join(f'    x{k} = {k}\n' for k in range(80))
    (tmp_path / 'long.py').write_text(
        'from numba import njit\n\n\ndef long():\n' + body
        + '\n\n@njit\ndef kernel():\n' + body
        + '\n\ndef allowed():\n' + body)
    assert [offence.split(' ')[0] for offence in long_function_offences(
        tmp_path, allowed={'long.py:allowed': (81, 'why'), 'long.py:gone': (90, 'why')})] \
        == ['long.py:long', 'long.py:gone:']
