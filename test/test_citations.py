"""Comments, docstrings, the shipped config and the docs cite only what exists.

A module renamed or a constant moved leaves its old name in prose that no import checks:
the node module's old path lived on in the generated ``config/qfa.yaml`` that way.
History (``CHANGELOG.rst``, ``bench/results/``) may name what is gone; a ``git show
COMMIT:path`` names a file of that commit.
"""

import ast
import functools
import io
from pathlib import Path
import re
import tokenize

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'qfa_ros'
LAYERS = ('model', 'calibration', 'bag', 'report', 'fleet', 'ros', 'cli')
TOP_DIRECTORIES = ('qfa_ros', 'bench', 'test', 'docs', 'config', 'launch', 'bags')

# A path from the top of the project (not a commit's: ``2d21a57:bench/x.py``).
PROJECT_PATH = re.compile(r'(?<![\w/.:-])((?:' + '|'.join(TOP_DIRECTORIES) + r')/[\w./-]*\w)')
# A module named from its layer, as the docs do: ``ros/node.py``.
LAYER_PATH = re.compile(r'(?<![\w/.:-])((?:' + '|'.join(LAYERS) + r')/\w+\.py)\b')
# A module named alone: ``writer.py``.
BARE_MODULE = re.compile(r'(?<![\w/.:-])(\w+\.py)\b')
DOTTED = re.compile(r'(?<![\w.])(qfa_ros(?:\.\w+)+)')


def prose_of_python(path):
    """Return ``(line, text)`` of every comment and docstring of a Python file."""
    source = path.read_text()
    found = [(token.start[0], token.string)
             for token in tokenize.generate_tokens(io.StringIO(source).readline)
             if token.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) \
                and node.body and isinstance(node.body[0], ast.Expr) \
                and isinstance(node.body[0].value, ast.Constant) \
                and isinstance(node.body[0].value.value, str):
            first = node.body[0].lineno
            found += [(first + k, line)
                      for k, line in enumerate(node.body[0].value.value.splitlines())]
        elif isinstance(node, (ast.Module, ast.ClassDef)):
            # An attribute docstring: a string right after an assignment.
            for before, after in zip(node.body, node.body[1:]):
                if isinstance(before, (ast.Assign, ast.AnnAssign)) \
                        and isinstance(after, ast.Expr) \
                        and isinstance(after.value, ast.Constant) \
                        and isinstance(after.value.value, str):
                    found += [(after.lineno + k, line)
                              for k, line in enumerate(after.value.value.splitlines())]
    return found


def prose():
    """Yield ``(file, line, text, bare_names_judged)`` of everything that cites code."""
    for pattern in ('qfa_ros/**/*.py', 'test/*.py', 'bench/*.py', 'launch/*.py',
                    'docs/conf.py'):
        for path in sorted(ROOT.glob(pattern)):
            # Tests and benchmarks write files of their own (``phase_probe.py``).
            bare = path.is_relative_to(PACKAGE)
            for number, text in prose_of_python(path):
                yield path, number, text, bare
    for path in sorted([*ROOT.glob('config/*.yaml'), *ROOT.glob('docs/*.md'),
                        ROOT / 'README.md']):
        for number, text in enumerate(path.read_text().splitlines(), 1):
            yield path, number, text, True


@functools.cache
def _module_names(path):
    tree = ast.parse(path.read_text())
    return tree, _names(tree.body)


def _names(body):
    """Return the names a module or class body binds (definitions, assignments, imports)."""
    names = set()
    for node in body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {name.id for target in targets for name in ast.walk(target)
                      if isinstance(name, ast.Name)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(alias.asname or alias.name).split('.')[0] for alias in node.names}
        elif isinstance(node, (ast.If, ast.Try, ast.With)):
            names |= _names([*node.body, *getattr(node, 'orelse', ()),
                             *getattr(node, 'finalbody', ()),
                             *(line for handler in getattr(node, 'handlers', ())
                               for line in handler.body)])
    return names


def dotted_exists(dotted):
    """Return whether ``qfa_ros.<module>[.<name>[.<member>]]`` names a module or a name in one."""
    parts = dotted.split('.')
    for k in range(len(parts), 0, -1):
        base = ROOT.joinpath(*parts[:k])
        module = base.with_suffix('.py') if base.with_suffix('.py').is_file() \
            else base / '__init__.py'
        if module.is_file():
            break
    else:
        return False
    rest = parts[k:]
    if not rest:
        return True
    tree, names = _module_names(module)
    if rest[0] not in names:
        return False
    cls = next((node for node in tree.body
                if isinstance(node, ast.ClassDef) and node.name == rest[0]), None)
    if len(rest) == 1 or cls is None or cls.bases:
        return True  # a member of a function, a value or an inherited class: not judged
    members = _names(cls.body) | {
        node.attr for node in ast.walk(cls) if isinstance(node, ast.Attribute)
        and isinstance(node.ctx, ast.Store) and isinstance(node.value, ast.Name)
        and node.value.id == 'self'}
    return rest[1] in members


def path_exists(cited):
    """Return whether a project path exists (``test/<helper>.<name>``: a name in a module)."""
    if (ROOT / cited).exists():
        return True
    module, _, _ = cited.partition('.')
    return (ROOT / f'{module}.py').is_file()


def stale_citations(cited_prose):
    """Return ``file:line: what`` for each citation of a path or module that does not exist."""
    modules = {path.name for path in ROOT.rglob('*.py')
               if not any(part.startswith('.') for part in path.relative_to(ROOT).parts)}
    stale = []
    for path, number, text, bare in cited_prose:
        where = f'{path.relative_to(ROOT)}:{number}'
        stale += [f'{where}: {cited}' for cited in PROJECT_PATH.findall(text)
                  if '_build' not in cited and not path_exists(cited.rstrip('.'))]
        stale += [f'{where}: {cited}' for cited in LAYER_PATH.findall(text)
                  if not (PACKAGE / cited).is_file()]
        stale += [f'{where}: {cited}' for cited in DOTTED.findall(text)
                  if not dotted_exists(cited)]
        if bare:
            stale += [f'{where}: {cited}' for cited in BARE_MODULE.findall(text)
                      if cited not in modules]
    return stale


def test_prose_cites_only_modules_paths_and_names_that_exist():
    stale = stale_citations(prose())
    assert not stale, 'cited but gone:\n' + '\n'.join(stale)


def test_the_check_finds_a_gone_module_path_and_name(tmp_path):
    cited = [(ROOT / 'config' / 'qfa.yaml', 1, text, True) for text in (
        '# Every parameter of qfa_ros/node.py with its default',
        'see `ros/params.py` and :data:`qfa_ros.ros.parameter_table.RUNTIME_EFFECTS`',
        ':data:`~qfa_ros.ros.params.RUNTIME_EFFECTS`, `trace.py`, qfa_ros.model.checks.gone',
        'qfa_ros.model.drift.DriftModel.no_such_member, `git show 2d21a57:bench/gone.py`')]
    assert [line.split(': ', 1)[1] for line in stale_citations(cited)] == [
        'qfa_ros/node.py', 'ros/params.py', 'qfa_ros.ros.params.RUNTIME_EFFECTS',
        'qfa_ros.model.checks.gone', 'trace.py', 'qfa_ros.model.drift.DriftModel.no_such_member']
