"""Ctrl-C ends a command with one line on stderr and status 130, never a traceback."""

import functools
import os
import sys

INTERRUPTED_STATUS = 130
"""Exit status of a command stopped by SIGINT (128 + 2, as a shell reports it)."""

PROGRAMS = {'qfa_ros.cli.node': 'qfa_node', 'qfa_ros.cli.sim': 'qfa-sim',
            'qfa_ros.cli.replay': 'qfa-replay', 'qfa_ros.cli.report': 'qfa-report',
            'qfa_ros.cli.fleet': 'qfa-fleet'}
"""The command of each module run as ``python -m MODULE``."""


def stops_quietly(prog):
    """
    Wrap a command's ``main(argv)`` so that Ctrl-C prints ``PROG: interrupted`` only.

    A command that has more to say (what was kept, how to resume) catches
    :class:`KeyboardInterrupt` itself and returns :data:`INTERRUPTED_STATUS`.

    Parameters
    ----------
    prog : str
        The command's name, the start of the line.
    """
    def wrap(main):
        @functools.wraps(main)
        def run(argv=None):
            try:
                return main(argv)
            except KeyboardInterrupt:
                print(f'{prog}: interrupted', file=sys.stderr, flush=True)
                return INTERRUPTED_STATUS
        return run
    return wrap


def install_interrupt_hook():
    """
    Make a Ctrl-C that no command caught (one while it still imports) one line as well.

    Installed when :mod:`qfa_ros.cli` is imported, which a command's imports start with;
    a hook someone else installed is kept. The process still ends by SIGINT, as Python
    ends it after an uncaught :class:`KeyboardInterrupt`.
    """
    if sys.excepthook is sys.__excepthook__:
        sys.excepthook = one_line_on_interrupt


def one_line_on_interrupt(kind, value, traceback):
    """Print ``PROG: interrupted`` for a KeyboardInterrupt, the usual report otherwise."""
    if issubclass(kind, KeyboardInterrupt):
        print(f'{program_name()}: interrupted', file=sys.stderr, flush=True)
    else:
        sys.__excepthook__(kind, value, traceback)


def program_name():
    """Return the running command's name, also for ``python -m qfa_ros.cli.<module>``."""
    argv = sys.orig_argv
    if '-m' in argv[:-1]:
        module = argv[argv.index('-m') + 1]
        return PROGRAMS.get(module, module)
    return os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else 'python'
