"""Ctrl-C ends every offline command with one line and status 130 (qfa-fleet: test_fleet)."""

import importlib

import pytest

from qfa_ros.cli.interrupt import INTERRUPTED_STATUS, stops_quietly


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
