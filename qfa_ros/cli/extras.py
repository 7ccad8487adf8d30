"""A command missing an optional package says which, and how to install it, in one line."""

import functools
import sys

TOOLS_PACKAGES = frozenset({'matplotlib', 'dask', 'distributed', 'pyarrow'})
"""The packages of ``requirements/tools.txt``: figures and fleet studies, not the node."""


def needs_tools(prog):
    """
    Wrap a command's ``main(argv)`` so that a missing tools package is one line, status 2.

    ``make run`` installs only what the node and ``qfa-sim`` need; ``make setup`` (and
    ``make test``) add the tools. Any other missing module is a real error and propagates.

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
            except ModuleNotFoundError as error:
                package = (error.name or '').partition('.')[0]
                if package not in TOOLS_PACKAGES:
                    raise
                print(f'{prog}: needs {package}, one of the figure and fleet tools: install '
                      'them with `make setup` or `pip install -r requirements/tools.txt`',
                      file=sys.stderr, flush=True)
                return 2
        return run
    return wrap
