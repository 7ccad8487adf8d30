"""
Plant the boundary's defects (issues 36 and 43), one at a time; the fuzz test fails on each.

Run: ``QFA_TEST_DOMAINS=<low>-<high> .venv/bin/python bench/planted_defects.py [--cases N]
[--only NAME ...] [--no-control] [--out bench/results/boundary_36.md]`` (without ``--cases``:
the suite's number, the one every defect must fail). Copies the working
tree (without its venvs and git directory) to a scratch directory once; for each defect,
puts the pristine file back, applies the defect there (never in the product) and runs
``test/test_node_fuzz.py`` on the copy (``-n 0``, ``QFA_FUZZ_CASES=N``; ``PYTHONPATH`` the
copy, so the nodes run the copy's code, forked or started), then records whether it failed,
the invariant that caught it (its assertion message), after how many cases, and the time.
A control run of the pristine copy comes first: a defect counts only if the same test on
the same copy passes without it. Writes the section ``## Planted defects`` of the results
file (``write_section`` of ``boundary_probes.py``).
"""

import argparse
import datetime
import os
from pathlib import Path
import re
import shutil
import subprocess
import sys
import tempfile
import time

from boundary_probes import write_section

ROOT = Path(__file__).resolve().parents[1]
HEADING = '## Planted defects'

DEFECTS = {
    'stamp window check removed': (
        'qfa_ros/ros/input_queue.py',
        '        if abs(time_ns - now_ns) > window_ns:\n',
        '        if False:  # planted: no stamp window\n'),
    'array size check removed': (
        'qfa_ros/ros/parameter_checks.py',
        "    if spec.max_length is not None and len(value) > spec.max_length:\n"
        "        return f'{name} must have at most {spec.max_length} elements, "
        "got {len(value)}'\n",
        ''),
    'a choices refusal quoting the whole value, before the length check': (
        'qfa_ros/ros/parameter_checks.py',
        "    limit = MAX_FRAME_ID_LENGTH if name == 'frame_id' else MAX_STRING_LENGTH\n",
        "    if spec.choices is not None and value not in spec.choices:\n"
        "        return f'{name} must be one of {\", \".join(spec.choices)}, got {value!r}'\n"
        "    limit = MAX_FRAME_ID_LENGTH if name == 'frame_id' else MAX_STRING_LENGTH\n"),
    'a directory refusal telling where the path resolves': (
        'qfa_ros/ros/bounds.py',
        "        raise ValueError(f'{rule}; this one leads outside it')\n",
        "        raise ValueError(f'{rule}; this one resolves to {directory}, outside it')\n"),
    'the rollback of a failed effect removed (the change accepted)': (
        'qfa_ros/ros/runtime_parameters.py',
        '                self._node.get_logger().error(reason + self._undo(ran))\n'
        '                return reason\n',
        '                self._node.get_logger().error(reason)\n'
        '                return None  # planted: accepted, though its effect failed\n'),
    'a recorder refusal quoting the OSError (the path, as long as the value)': (
        'qfa_ros/ros/recording.py',
        "            reason = f'recorder.directory: {system_reason(error)}' \\\n"
        '                if isinstance(error, OSError) else error\n',
        '            reason = error\n'),
    # Issue 43: the managed node's unconfigured window, one hole at a time.
    'state_file writable while the managed node is unconfigured': (
        'qfa_ros/ros/parameter_table.py',
        "                  'Persisted calibration state (JSON); empty: keep it in memory only', "
        "OPERATOR,\n",
        "                  'Persisted calibration state (JSON); empty: keep it in memory only', "
        "CONFIGURE,\n"),
    'output_dir writable while the managed node is unconfigured': (
        'qfa_ros/ros/parameter_table.py',
        "                  OPERATOR, why=FILES_WRITTEN),\n    ParameterSpec('min_free_bytes',",
        "                  CONFIGURE, why=FILES_WRITTEN),\n    ParameterSpec('min_free_bytes',"),
    'noise.imu_yaml writable while the managed node is unconfigured': (
        'qfa_ros/ros/parameter_table.py',
        "'by the operator only, so no participant can make the node read a file',\n"
        "                  OPERATOR, why=FILE_READ),\n",
        "'by the operator only, so no participant can make the node read a file',\n"
        "                  CONFIGURE, why=FILE_READ),\n"),
    'no confinement of trace_dir and recorder.directory while unconfigured': (
        'qfa_ros/ros/parameter_checks.py',
        '    if reason or name not in CONFINED:\n',
        '    if True:  # planted: no confinement while unconfigured\n'),
}
"""Name: (file, the text of the product, the defect put in its place)."""


def copy_tree(destination):
    """Copy the working tree to ``destination`` (mtimes kept: numba's caches stay valid)."""
    shutil.copytree(ROOT, destination, symlinks=True, ignore=shutil.ignore_patterns(
        '.venv*', '.git', '.hypothesis', '.pytest_cache', '.ruff_cache', 'bags'))


def plant(tree, name):
    """Put the pristine file back in ``tree`` and plant defect ``name`` (None: none)."""
    for path, _, _ in DEFECTS.values():
        shutil.copy2(ROOT / path, tree / path)
    if name is None:
        return
    path, product, defect = DEFECTS[name]
    text = (tree / path).read_text()
    if text.count(product) != 1:
        raise SystemExit(f'{name}: the product text is not once in {path}; update DEFECTS')
    (tree / path).write_text(text.replace(product, defect))


def run_fuzz(tree, cases):
    """Run the fuzz module on ``tree``; return (passed, what caught it, where, seconds, output).

    Where: the test that failed (the executable and state) and the random case, if one.
    """
    env = {**os.environ, 'PYTHONPATH': str(tree), 'PYTHONDONTWRITEBYTECODE': '1'}
    if cases is not None:
        env['QFA_FUZZ_CASES'] = str(cases)
    started = time.monotonic()
    result = subprocess.run(
        [sys.executable, '-m', 'pytest', 'test/test_node_fuzz.py', '-n', '0', '-q', '-x',
         '-p', 'no:cacheprovider', '-o', 'addopts=', '--timeout', '900'],
        cwd=tree, env=env, capture_output=True, text=True)
    seconds = time.monotonic() - started
    output = result.stdout + result.stderr
    if result.returncode == 0:
        return True, '', 'all', seconds, output
    lines = [line[4:].strip() for line in output.splitlines() if line.startswith('E   ')]
    caught = next((line for line in lines if line), output.strip()[-300:])
    failed = re.search(r'FAILED \S+::(\S+)', output)
    counted = re.search(r'case (\d+) of (\d+): ', caught)
    where = (failed.group(1) if failed else '?') + (
        f', random case {counted.group(1)} of {counted.group(2)}' if counted else '')
    caught = re.sub(r'^(AssertionError: )?(\w+ node, [\w ]+: )?case \d+ of \d+: ', '', caught)
    # A stranger's long string quoted back: its length, not its characters.
    caught = re.sub(r'(.)\1{19,}', lambda run: f'{run.group(1) * 3}...<{len(run.group(0))} '
                    f'characters>', caught)
    return False, caught[:300], where, seconds, output


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--cases', type=int, default=None,
                        help="QFA_FUZZ_CASES of each run (default: the suite's)")
    parser.add_argument('--only', nargs='*', choices=sorted(DEFECTS), default=None)
    parser.add_argument('--no-control', action='store_true', help='skip the pristine run')
    parser.add_argument('--out', type=Path, help='write the section into this file')
    args = parser.parse_args(argv)
    names = args.only or list(DEFECTS)
    commit = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    domains = os.environ.get('QFA_TEST_DOMAINS', '1-100')
    cases = f'QFA_FUZZ_CASES={args.cases}' if args.cases else "the suite's QFA_FUZZ_CASES"
    lines = [HEADING, '', f'`QFA_TEST_DOMAINS={domains} .venv/bin/python '
             'bench/planted_defects.py' + (f' --cases {args.cases}' if args.cases else '')
             + (f' --only {" ".join(repr(n) for n in args.only)}' if args.only else '')
             + (' --no-control' if args.no_control else '')
             + ' --out bench/results/boundary_36.md`', '',
             f'{datetime.date.today()}, commit {commit} (+ working tree), '
             f'`test/test_node_fuzz.py` with {cases} on a copy of the '
             'tree with one defect planted (the product untouched); load average '
             f'{os.getloadavg()[0]:.1f} at the start.', '',
             '| defect planted | file | fuzz test | caught by | at | time [s] | load |',
             '|---|---|---|---|---|---|---|']
    with tempfile.TemporaryDirectory(prefix='qfa_planted_') as scratch:
        tree = Path(scratch) / 'tree'
        copy_tree(tree)
        runs = ([] if args.no_control else [None]) + names
        for name in runs:
            plant(tree, name)
            print(f'{name or "control (no defect)"}: running ...', flush=True)
            passed, caught, after, seconds, output = run_fuzz(tree, args.cases)
            if name is None and not passed:
                print(output[-5000:])
                raise SystemExit(f'the pristine copy fails: {caught}')
            print(f'  {"passed" if passed else "FAILED"} ({after}), {seconds:.0f} s: '
                  f'{caught}', flush=True)
            label = name or 'none (control)'
            file = DEFECTS[name][0] if name else '—'
            lines.append(f'| {label} | `{file}` | {"passed" if passed else "**failed**"} | '
                         f'{caught.replace("|", "/") or "—"} | {after} | {seconds:.0f} | '
                         f'{os.getloadavg()[0]:.1f} |')
    text = '\n'.join(lines)
    print(text)
    if args.out:
        write_section(args.out, HEADING, text)


if __name__ == '__main__':
    main()
