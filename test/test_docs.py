"""The documentation site builds without a warning; the README stays short and its links hold."""

import importlib.util
from pathlib import Path
import pickle
import re
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[1]


SPHINX_HIGHLIGHTING_DUMMY = """
import sys

from docutils import nodes
from sphinx.builders.dummy import DummyBuilder
from sphinx.cmd.build import main
from sphinx.highlighting import PygmentsBridge


def write_doc(self, docname, doctree):
    # What the html writer does with each code block (HTML5Translator.visit_literal_block):
    # a fence's unknown language or a lexing error is a warning there, and so here.
    bridge = PygmentsBridge('html', self.config.pygments_style)
    for node in doctree.findall(nodes.literal_block):
        if node.rawsource != node.astext():
            continue  # a parsed literal, not highlighted
        language = node.get('language', 'default')
        bridge.highlight_block(
            node.rawsource, language, opts=self.config.highlight_options.get(language, {}),
            linenos=node.get('linenos', False), location=node,
            **{**node.get('highlight_args', {}), 'force': node.get('force', False)})


DummyBuilder.write_doc = write_doc
sys.exit(main(sys.argv[1:]))
"""
"""``python -m sphinx`` with the ``dummy`` builder highlighting every code block as html does."""


def test_docs_site_builds_with_warnings_as_errors(tmp_path):
    """
    What `make docs` runs, but its pages not written: any warning fails the build.

    A page missing from every toctree, a broken cross-reference (a page, a heading anchor,
    a label), an unknown MyST directive or role, a module autodoc cannot import, a code
    block in an unknown language: each fails it. Sphinx's ``dummy`` builder reads and
    resolves every page as ``html`` does (every warning of those phases) and writes
    nothing; writing the html pages (their search index, theme and writer) is ~4 of its
    ~21 CPU-s (~28 since the API page's 1101 objects are rendered). Its only warning the
    docs can meet, the highlighting of code blocks, is done here as the html writer does
    it; the writer's others are about constructs the docs do not use (rubric heading
    levels, ``:scale:`` without a size, figure numbers).
    """
    pytest.importorskip('pyarrow', reason='the API reference imports the fleet studies, '
                        'which need pyarrow (numpy 2): not on the library floor')
    doctrees = tmp_path / 'doctrees'
    result = subprocess.run(
        [sys.executable, '-c', SPHINX_HIGHLIGHTING_DUMMY, '-W', '--keep-going', '-q',
         '-b', 'dummy', '-d', str(doctrees), str(ROOT / 'docs'), str(tmp_path / 'out')],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    for page in ('getting_started', 'node', 'calibration', 'fleet', 'replay_report',
                 'security', 'reproducibility', 'performance', 'architecture', 'model', 'api'):
        assert (doctrees / f'{page}.doctree').is_file(), page
    # The API reference is generated from the docstrings and rendered as Python objects
    # (autodoc's reST parsed as reST, so a broken docstring is a warning above), not as
    # paragraphs of ``.. py:class::`` text.
    from sphinx import addnodes

    api = pickle.loads((doctrees / 'api.doctree').read_bytes())
    objects = {sig_id: desc['objtype'] for desc in api.findall(addnodes.desc)
               for sig in desc.findall(addnodes.desc_signature) for sig_id in sig['ids']}
    assert objects.get('qfa_ros.model.triad.QfaTriad') == 'class', sorted(objects)[:20]
    assert objects.get('qfa_ros.ros.calibration_keeper.CalibrationKeeper') == 'class'
    assert 'function' in objects.values() and 'method' in objects.values()
    assert '.. py:' not in api.astext()
    assert b'state.fresh' in (doctrees / 'node.doctree').read_bytes()


def test_readme_is_short_and_its_links_exist():
    text = (ROOT / 'README.md').read_text()
    # The interface tables are generated from the code (interface_docs) and grow with the
    # interface; what is written by hand stays within the 200 lines it had, less the
    # hand-kept table of 8 the generated block replaced.
    lines = text.splitlines()
    begin, end = lines.index('<!-- interfaces:begin -->'), lines.index('<!-- interfaces:end -->')
    assert len(lines) - (end + 1 - begin) <= 192
    assert '`make test`' in text or 'make test ' in text  # .ci/run runs the README's command
    links = re.findall(r'\]\(([^)#:]+)(?:#[^)]*)?\)', text)
    assert links
    for link in links:
        assert (ROOT / link).exists(), link


def _figures_table():
    path = ROOT / 'docs' / 'figures_table.py'
    spec = importlib.util.spec_from_file_location('figures_table', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_figures_table_is_what_bench_results_say():
    # docs/figures.md is generated from the `figures` blocks of bench/results/*.md.
    table = _figures_table()
    written = (ROOT / 'docs' / 'figures.md').read_text()
    assert written == table.render(table.load()), (
        'docs/figures.md is stale: python docs/figures_table.py > docs/figures.md')


def test_no_page_states_a_figure_differently_from_the_table():
    table = _figures_table()
    figures = table.load()
    assert any(figure.get('stated') for figure in figures)
    assert table.stated_differently(table.pages(), figures) == []


def test_a_page_that_states_a_figure_differently_is_found(tmp_path):
    table = _figures_table()
    figures = table.load()
    hour = next(figure for figure in figures if figure['id'] == 'sim_hour')
    page = tmp_path / 'page.md'
    page.write_text(f'An hour of the sensor takes about {hour["value"]} s on two cores.\n'
                    'An hour of the sensor takes about\n4.3 s on two cores.\n')
    assert table.stated_differently([page], figures) == [
        f'page.md:3: sim_hour states 4.3, the table {hour["value"]} (sim_limit.md)']
