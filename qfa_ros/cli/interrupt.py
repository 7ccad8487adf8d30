"""Ctrl-C ends a command with one line on stderr and status 130, never a traceback."""

import functools
import sys

INTERRUPTED_STATUS = 130
"""Exit status of a command stopped by SIGINT (128 + 2, as a shell reports it)."""


def stops_quietly(prog):
    """
    Wrap a command's ``main(argv)`` so that Ctrl-C prints ``PROG: interrupted`` only.

    A command that has more to say (what was kept, how to resume) catches
    :class:`KeyboardInterrupt` itself and returns :data:`INTERRUPTED_STATUS`.

    :param prog: The command's name, the start of the line.
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
