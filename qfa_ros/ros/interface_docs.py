"""
The interface tables of ``docs/node.md`` and the README, from the topic and service tables.

``python -m qfa_ros.ros.interface_docs write``, run in the source tree, rewrites every
generated block there in place (each between its ``<!-- <name>:begin -->`` and
``<!-- <name>:end -->`` markers); ``... topics``, ``... services`` and ``... readme`` print
one. ``test_interfaces.py`` fails when a block is stale.
"""

from pathlib import Path
import sys

from qfa_ros.ros.parameter_docs import print_output
from qfa_ros.ros.parameter_table import PARAMETERS, SPECS
from qfa_ros.ros.service_table import SERVICES, stream_effect, TIMING
from qfa_ros.ros.topic_table import PUBLISHER, TOPICS

COMMAND = 'python -m qfa_ros.ros.interface_docs write'
"""The command that regenerates every block."""
DEFAULTS = {spec.name: spec.default for spec in PARAMETERS}
SOURCE = ('<!-- Generated from qfa_ros/ros/topic_table.py and qfa_ros/ros/service_table.py by '
          f'`{COMMAND}`: edit the tables, not this block. -->')


def _value(value):
    return f'{value:g}' if isinstance(value, float) else str(value)


def qos_text(qos):
    """
    Return a QoS profile as the docs state it: ``reliable, transient local, depth 1``.

    Parameters
    ----------
    qos : QosProfile
        The profile (:class:`~qfa_ros.bag.qos.QosProfile`).

    Returns
    -------
    str
        Reliability, durability when not volatile, and the history.
    """
    words = [qos.reliability.replace('_', ' ')]
    if qos.durability != 'volatile':
        words.append(qos.durability.replace('_', ' '))
    words.append('keep all' if qos.history == 'keep_all' else f'depth {qos.depth}')
    return ', '.join(words)


def rate_text(spec):
    """
    Return the rate of a topic row: its parameter's default with the parameter's name.

    Parameters
    ----------
    spec : TopicSpec
        The topic's row.

    Returns
    -------
    str
        ``1000 Hz (`sample_rate_hz`)``, or the row's words when no parameter sets it.
    """
    if spec.rate in SPECS:
        return f'{_value(DEFAULTS[spec.rate])} Hz (`{spec.rate}`)'
    return spec.rate


def frame_text(spec):
    """
    Return the ``header.frame_id`` of a topic row: the parameter's default and name.

    Parameters
    ----------
    spec : TopicSpec
        The topic's row.

    Returns
    -------
    str
        ```imu_link` (`frame_id`)``, the frame itself, or a dash without a header.
    """
    if not spec.frame:
        return '—'
    if spec.frame in SPECS:
        return f'`{DEFAULTS[spec.frame]}` (`{spec.frame}`)'
    return f'`{spec.frame}`'


def condition_text(spec):
    """
    Return when the node has a topic.

    Parameters
    ----------
    spec : TopicSpec
        The topic's row.

    Returns
    -------
    str
        ``with `truth.enabled: true``` for a row with ``only_if``, else ''.
    """
    if spec.only_if is None:
        return ''
    name, value = spec.only_if
    shown = str(value).lower() if isinstance(value, bool) else value
    return f'with `{name}: {shown}`'


def topics_table():
    """Return the Markdown table of every topic (``docs/node.md``)."""
    rows = ['| kind | name | type | QoS | rate | frame | what |', '|---|---|---|---|---|---|---|']
    for spec in TOPICS:
        qos = qos_text(spec.qos)
        if spec.overridable:
            qos += f'; `qos_overrides./{spec.name}.publisher.{{history,depth,reliability}}`'
        condition = condition_text(spec)
        what = f'{condition}: {spec.doc}' if condition else spec.doc
        rows.append(f'| {spec.direction} | `{spec.name}` | {spec.type_name} | {qos} | '
                    f'{rate_text(spec)} | {frame_text(spec)} | {what} |')
    return '\n'.join(rows) + '\n'


def services_table():
    """Return the Markdown table of every service (``docs/node.md``)."""
    rows = ['| name | type | kind | what | the stream meanwhile |', '|---|---|---|---|---|']
    for spec in SERVICES:
        what = f'{spec.doc}; {spec.details}' if spec.details else spec.doc
        stream = stream_effect(spec, DEFAULTS)
        if spec.schedule is not None:
            stream += f'; the stream diagnostic says `paused: {spec.pause}`'
        kind = f'`{spec.kind}`' if spec.kind else '—'
        rows.append(f'| `{spec.name}` | {spec.type_name} | {kind} | {what} | {stream} |')
    return '\n'.join(rows + ['', TIMING]) + '\n'


def _alternatives(topics):
    """Group consecutive rows that are alternatives (one ``only_if`` parameter, its values)."""
    groups = []
    for spec in topics:
        last = groups[-1][-1] if groups else None
        if (last is not None and spec.only_if and last.only_if
                and spec.only_if[0] == last.only_if[0] and spec.only_if[1] != last.only_if[1]):
            groups[-1].append(spec)
        else:
            groups.append([spec])
    return groups


def readme_block():
    """Return the README's interface tables: topics with QoS, rate and frame; the services."""
    rows = ['| topic | type | QoS | rate | frame |', '|---|---|---|---|---|']
    for group in _alternatives(TOPICS):
        spec = group[0]
        kind = 'pub' if spec.direction == PUBLISHER else 'sub'
        if len(group) > 1:
            names = ', '.join(f'`{s.name}`' for s in group[:-1]) + f' or `{group[-1].name}`'
            name = f'{kind} {names} (per `{spec.only_if[0]}`)'
            types = ' / '.join(f'`{s.type_name}`' for s in group)
        else:
            condition = condition_text(spec)
            name = f'{kind} `{spec.name}`' + (f' ({condition})' if condition else '')
            types = f'`{spec.type_name}`'
        qos = qos_text(spec.qos) + (' (overridable)' if spec.overridable else '')
        rows.append(f'| {name} | {types} | {qos} | {rate_text(spec)} | {frame_text(spec)} |')
    rows += ['', '| service | type | what | the stream meanwhile |', '|---|---|---|---|']
    for spec in SERVICES:
        rows.append(f'| `{spec.name}` | `{spec.type_name}` | {spec.doc} | '
                    f'{stream_effect(spec, DEFAULTS)} |')
    rows += ['', f'{TIMING} Every field, the diagnostics and the answers: '
                 f'[docs/node.md](docs/node.md#topics). {SOURCE}']
    return '\n'.join(rows) + '\n'


def _with_source(generate):
    def generated():
        return f'{SOURCE}\n{generate()}'
    return generated


BLOCKS = (('README.md', 'interfaces', readme_block),
          ('docs/node.md', 'topics', _with_source(topics_table)),
          ('docs/node.md', 'services', _with_source(services_table)))
"""Each generated block: the file, the marker name, the function that generates it."""


def _span(text, name, path):
    begin, end = f'<!-- {name}:begin -->\n', f'<!-- {name}:end -->'
    start = text.find(begin)
    stop = text.find(end, start + 1)
    if start < 0 or stop < 0:
        raise ValueError(f'{path}: no {begin.strip()} ... {end} markers')
    return start + len(begin), stop


def stale_blocks(root):
    """
    Return the generated blocks under ``root`` that differ from what the tables give.

    Parameters
    ----------
    root : pathlib.Path
        The source tree.

    Returns
    -------
    list of str
        ``<file>: <marker name>`` of each stale block.

    Raises
    ------
    ValueError
        A file lacks the markers of its block.
    """
    stale = []
    for path, name, generate in BLOCKS:
        text = (Path(root) / path).read_text()
        start, stop = _span(text, name, path)
        if text[start:stop] != generate():
            stale.append(f'{path}: {name}')
    return stale


def write(root):
    """
    Rewrite every generated block under ``root`` in place.

    Parameters
    ----------
    root : pathlib.Path
        The source tree.

    Returns
    -------
    list of str
        ``<file>: <marker name>`` of each block that changed.

    Raises
    ------
    ValueError
        A file lacks the markers of its block.
    """
    written = []
    for path, name, generate in BLOCKS:
        file = Path(root) / path
        text = file.read_text()
        start, stop = _span(text, name, path)
        new = text[:start] + generate() + text[stop:]
        if new != text:
            file.write_text(new)
            written.append(f'{path}: {name}')
    return written


def main(argv=None):
    """Print one block (``topics``, ``services``, ``readme``) or rewrite all (``write``)."""
    args = sys.argv[1:] if argv is None else argv
    return print_output(args, {
        'write': lambda: ''.join(f'rewrote {block}\n' for block in write(Path.cwd())),
        'topics': topics_table, 'services': services_table, 'readme': readme_block},
        'qfa_ros.ros.interface_docs')

if __name__ == '__main__':
    sys.exit(main())
