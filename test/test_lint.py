"""Run the linter configured like ament_flake8 / ament_pep257 (ruff.toml)."""

import ast
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_ruff_reports_no_issue():
    result = subprocess.run([sys.executable, '-m', 'ruff', 'check', '--no-cache', str(ROOT)],
                            capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr


def test_no_merge_conflict_marker_is_left_in_the_sources_or_docs():
    # A marker in a Markdown file passes every other check (one was found in docs/node.md).
    markers = ('<<<<<<< ', '>>>>>>> ', '=======\n')
    suffixes = ('.py', '.md', '.rst', '.yaml', '.cfg', '.toml', '.txt')
    found = []
    # Hidden directories (the venvs, .git) and build/ pruned, not walked: walking the
    # venvs took seconds.
    for directory, subdirectories, names in os.walk(ROOT):
        subdirectories[:] = [name for name in subdirectories
                             if not name.startswith('.') and name != 'build']
        for name in names:
            if name.startswith('.') or not (name.endswith(suffixes) or name == 'Makefile'):
                continue
            path = Path(directory) / name
            for number, line in enumerate(path.read_text(errors='replace').splitlines(True)):
                if line.startswith(markers):
                    found.append(f'{path.relative_to(ROOT)}:{number + 1}')
    assert not found, found


FIRST_CHECKED_COMMIT = 'e659f9b'
"""The first commit held to :data:`MAX_SUBJECT` (those before it are history as it is)."""
MAX_SUBJECT = 72
"""Longest commit subject: what ``git log --oneline`` shows whole in 80 columns."""


def _git(*args):
    return subprocess.run(['git', *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)


def long_subjects(*revisions):
    """Return ``hash subject`` of each commit of ``revisions`` whose subject is too long."""
    log = _git('log', '--format=%h %s', *revisions)
    assert log.returncode == 0, log.stderr
    return [line for line in log.stdout.splitlines()
            if len(line.split(' ', 1)[1]) > MAX_SUBJECT]


def test_commit_subjects_fit_on_one_line():
    # The why and the measurements go to the body; the subject says what changed.
    top = _git('rev-parse', '--show-toplevel') if shutil.which('git') else None
    if top is None or top.returncode != 0 or Path(top.stdout.strip()).resolve() != ROOT:
        pytest.skip('no git history of this tree (an sdist, an export): no commits to check')
    if _git('rev-parse', '--verify', '--quiet', f'{FIRST_CHECKED_COMMIT}^{{commit}}').returncode:
        pytest.skip(f'{FIRST_CHECKED_COMMIT} is not in this history (a shallow clone)')
    offences = long_subjects(f'{FIRST_CHECKED_COMMIT}..HEAD')
    assert not offences, f'subjects over {MAX_SUBJECT} characters:\n' + '\n'.join(offences)
    # The check sees one where there is one: the commit before the first checked has a
    # subject of 198 characters.
    if _git('rev-parse', '--verify', '--quiet', f'{FIRST_CHECKED_COMMIT}~1').returncode == 0:
        assert len(long_subjects('-1', f'{FIRST_CHECKED_COMMIT}~1')) == 1


NUMPYDOC_LAYERS = ('model', 'calibration', 'bag', 'ros', 'report', 'fleet', 'cli')
"""The layers of ``qfa_ros`` whose docstrings are numpydoc only (``ros`` joins once converted)."""
REST_FIELD = re.compile(
    r'^[ \t]*:(param|type|returns?|rtype|raises?|yields?|var|ivar|cvar)\b[^:]*:', re.MULTILINE)


def rest_fields(paths):
    """Return ``file:line: :field`` for each reST field of the docstrings in ``paths``."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                     ast.AsyncFunctionDef)):
                continue
            docstring = ast.get_docstring(node, clean=False)
            if not docstring:
                continue
            first = node.body[0].lineno
            where = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name
            found += [f'{where}:{first + docstring.count(chr(10), 0, match.start())}: '
                      f':{match.group(1)}' for match in REST_FIELD.finditer(docstring)]
    return found


def test_docstrings_are_numpydoc_not_rest_field_lists(tmp_path):
    # The README and docs/conf.py (napoleon, numpy style) say numpydoc: Parameters,
    # Returns, Raises sections, not :param: fields.
    paths = sorted(path for layer in NUMPYDOC_LAYERS
                   for path in (ROOT / 'qfa_ros' / layer).rglob('*.py'))
    found = rest_fields(paths)
    assert not found, 'reST fields where numpydoc sections belong:\n' + '\n'.join(found)
    planted = tmp_path / 'planted.py'
    planted.write_text('def f(x):\n    """\n    Do.\n\n    :param x: A value.\n'
                       '    :raises ValueError: Never.\n    """\n')
    assert rest_fields([planted]) == ['planted.py:5: :param', 'planted.py:6: :raises']
