"""Ctrl-C ends every command with one line, never a traceback (qfa-fleet's run: test_fleet)."""

import importlib
import os
from pathlib import Path
import signal
import subprocess
import sys

import pytest

from qfa_ros.cli.interrupt import INTERRUPTED_STATUS, program_name, stops_quietly

ROOT = Path(__file__).resolve().parents[1]


def test_an_interrupted_command_prints_one_line_and_returns_130(capsys):
    @stops_quietly('qfa-example')
    def main(argv=None):
        raise KeyboardInterrupt

    assert main([]) == INTERRUPTED_STATUS == 130
    captured = capsys.readouterr()
    assert captured.out == ''
    assert captured.err == 'qfa-example: interrupted\n'


def test_other_errors_are_not_swallowed():
    @stops_quietly('qfa-example')
    def main(argv=None):
        raise ValueError('not an interrupt')

    with pytest.raises(ValueError, match='not an interrupt'):
        main([])


@pytest.mark.parametrize('module', ['sim', 'replay', 'report', 'fleet'])
def test_every_offline_command_is_wrapped(module):
    main = importlib.import_module(f'qfa_ros.cli.{module}').main
    assert main.__wrapped__.__module__ == f'qfa_ros.cli.{module}'


@pytest.mark.parametrize('error, expected', [
    ('KeyboardInterrupt', 'qfa-example: interrupted\n'),
    ('ValueError("a real error")', 'Traceback'),
])
def test_a_ctrl_c_while_a_command_imports_is_one_line_too(tmp_path, error, expected):
    # Importing qfa_ros.cli (every command's first import) installs the hook; a Ctrl-C
    # before main() runs reaches it uncaught. Other errors keep their traceback.
    script = tmp_path / 'qfa-example'
    script.write_text(f'import qfa_ros.cli\nraise {error}\n')
    env = {**os.environ, 'PYTHONPATH': str(ROOT)}
    result = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=60)
    if error == 'KeyboardInterrupt':
        assert result.stderr == expected
        assert result.returncode == -signal.SIGINT  # ended by SIGINT, as Python does
    else:
        assert expected in result.stderr and 'a real error' in result.stderr


def test_the_program_is_named_also_when_run_as_a_module(monkeypatch):
    monkeypatch.setattr(sys, 'orig_argv', ['python3', '-m', 'qfa_ros.cli.sim', 'static'])
    assert program_name() == 'qfa-sim'
    monkeypatch.setattr(sys, 'orig_argv', ['/x/.venv/bin/python', '/x/.venv/bin/qfa-fleet'])
    monkeypatch.setattr(sys, 'argv', ['/x/.venv/bin/qfa-fleet', 'study.yaml'])
    assert program_name() == 'qfa-fleet'
