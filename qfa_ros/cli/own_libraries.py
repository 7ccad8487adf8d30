"""
A ROS program of this environment runs on this environment's ROS 2 libraries, wherever started.

The ROS 2 wheels find their C libraries through ``LD_LIBRARY_PATH``: their ``.pth``
bootstrap (``ros_wheels_bootstrapper``) adds ``<prefix>/lib`` and the wheels'
``site-packages/ros_*.libs`` and re-executes Python once, marking that with
``_ROS_WHEELS_BOOTSTRAP_COMPLETE``. A process of *another* ROS environment hands both
down to what it starts (a launcher, a test harness, a supervisor; ``ros2 launch`` of
another venv; a shell with a sourced ROS 2 gives ``LD_LIBRARY_PATH`` and ``PYTHONPATH``):
the bootstrap then does nothing, or keeps the other environment's directories beside
ours in no fixed order, and ``qfa_node`` fails at start (``libfastdds.so.3.2: cannot
open shared object file``, ``UnsupportedTypeSupport ... nav_msgs``) or silently runs on
a mix of two distributions' libraries.

:func:`use_own_ros_libraries`, called when :mod:`qfa_ros.cli` is imported, checks this
before anything loads a ROS library and, for ``qfa_node`` and ``qfa-replay`` (the
programs that load them), re-executes the program once with this environment's library
directories first and the other environment's ROS library directories and ROS Python
packages left out; everything else in the environment stays as it was. A process whose
environment is already its own (every start from its own shell, ``make run``, the
tests) pays one directory listing, no re-execution. Should the environment still be
foreign after that one re-execution, the program refuses to start in one line.

Every program also keeps to this environment's numba cache (:func:`use_own_numba_cache`):
``make setup ROS_DISTRO=jazzy`` points ``NUMBA_CACHE_DIR`` into ``.venv-jazzy`` (its
``.pth``), and a process of that venv hands it down too.
"""

import os
from pathlib import Path
import sys

from qfa_ros.cli.interrupt import program_name

ROS_PROGRAMS = ('qfa_node', 'qfa_lifecycle_node', 'qfa-replay')
"""The programs that load ROS 2 libraries (a new ROS program's name goes here)."""

BOOTSTRAP_GUARD = '_ROS_WHEELS_BOOTSTRAP_COMPLETE'
"""Set by the wheels' bootstrap once ``LD_LIBRARY_PATH`` is made (ros_wheels_bootstrapper)."""

REEXEC_MARK = 'QFA_ROS_OWN_LIBRARIES'
"""Set on the one re-execution, so that a second one is refused instead of looping."""

ROS_CORE_LIBRARY = 'librcutils.so'
"""A library every ROS 2 installation and wheel environment has in its library directory."""

NUMBA_CACHE_ENV = 'NUMBA_CACHE_DIR'
"""numba's cache directory; unset, each kernel is cached in ``__pycache__`` beside its source."""

OWN_NUMBA_CACHE = 'numba_cache'
"""The cache directory a venv keeps inside itself (the Makefile's ``NUMBA_CACHE``)."""

ROS_PYTHON_PACKAGES = ('rclpy', 'rcl_interfaces', 'builtin_interfaces', 'std_msgs',
                       'sensor_msgs', 'std_srvs', 'geometry_msgs', 'diagnostic_msgs',
                       'rosgraph_msgs', 'nav_msgs', 'ament_index_python')
"""The ROS Python packages the programs import: another copy on ``PYTHONPATH`` shadows ours."""


def own_library_directories(prefix=None, site_packages=None):
    """
    Return this environment's ROS library directories, or None without ROS 2 wheels.

    The directories the wheels' bootstrap puts on ``LD_LIBRARY_PATH``: ``<prefix>/lib``
    and ``site-packages/ros_*.libs``. None when the wheels are not installed here (a
    sourced ROS 2, whose own ``setup.bash`` made the environment, or no ROS at all).
    """
    prefix = Path(sys.prefix if prefix is None else prefix)
    if site_packages is None:
        # Imported by its .pth at start-up wherever the wheels are installed: its place is
        # the wheels' site-packages, and finding it costs nothing.
        bootstrapper = sys.modules.get('ros_wheels_bootstrapper')
        if bootstrapper is None or not bootstrapper.__file__:
            return None
        site_packages = Path(bootstrapper.__file__).parents[1]
    site = Path(site_packages)
    if not (site / 'ros_wheels_bootstrapper').is_dir():
        return None
    return [str(prefix / 'lib')] + sorted(str(p.resolve()) for p in site.glob('ros_*.libs')
                                          if p.is_dir())


def is_ros_library_directory(path):
    """Whether ``path`` holds a ROS 2 installation's or wheel environment's libraries."""
    path = Path(path)
    return (path / ROS_CORE_LIBRARY).exists() or (
        path.name.startswith('ros_') and path.name.endswith('.libs')
        and path.parent.name == 'site-packages')


def holds_ros_python(path):
    """Whether the ``PYTHONPATH`` entry ``path`` has a ROS Python package the programs use."""
    return any((Path(path) / name).is_dir() for name in ROS_PYTHON_PACKAGES)


def own_environment(environ, own):
    """
    Return the environment a ROS program of this environment needs, or None if it has it.

    Parameters
    ----------
    environ : dict
        The process environment.
    own : list of str
        :func:`own_library_directories`.

    Returns
    -------
    dict or None
        A copy of ``environ`` with ``own`` first on ``LD_LIBRARY_PATH``, every other ROS
        library directory and every ``PYTHONPATH`` entry holding ROS Python packages left
        out, and the bootstrap marked complete; None when nothing needs to change.
    """
    current = [p for p in environ.get('LD_LIBRARY_PATH', '').split(os.pathsep) if p]
    foreign = [p for p in current if p not in own and is_ros_library_directory(p)]
    python_path = [p for p in environ.get('PYTHONPATH', '').split(os.pathsep) if p]
    shadowing = [p for p in python_path if holds_ros_python(p)]
    if set(own) <= set(current) and not foreign and not shadowing:
        return None
    env = dict(environ)
    env['LD_LIBRARY_PATH'] = os.pathsep.join(
        own + [p for p in current if p not in own and p not in foreign])
    env[BOOTSTRAP_GUARD] = '1'
    kept = [p for p in python_path if p not in shadowing]
    if kept:
        env['PYTHONPATH'] = os.pathsep.join(kept)
    else:
        env.pop('PYTHONPATH', None)
    return env


def use_own_ros_libraries(environ=None, program=None):
    """
    Re-execute ``qfa_node``/``qfa-replay`` on this environment's ROS libraries if need be.

    Does nothing for other programs (the offline tools load no ROS library), without ROS 2
    wheels here, or when the environment is already this one's. Exits with status 1 and one
    line on stderr if the environment is still foreign after one re-execution.
    """
    environ = os.environ if environ is None else environ
    program = program_name() if program is None else program
    if program not in ROS_PROGRAMS:
        return
    own = own_library_directories()
    if own is None:
        return
    env = own_environment(environ, own)
    if env is None:
        return
    if environ.get(REEXEC_MARK):
        print(f"{program}: cannot start on this environment's ROS 2 libraries ({own[0]}): "
              f"LD_LIBRARY_PATH still holds another ROS environment's after one restart; "
              f'start it with `env -u LD_LIBRARY_PATH -u {BOOTSTRAP_GUARD} -u PYTHONPATH '
              f'{program} ...`', file=sys.stderr, flush=True)
        sys.exit(1)
    env[REEXEC_MARK] = '1'
    os.execve(sys.executable, sys.orig_argv, env)


def venv_of(path):
    """Return the venv directory (the one with ``pyvenv.cfg``) ``path`` lies in, or None."""
    path = Path(os.path.realpath(path))
    return next((p for p in (path, *path.parents) if (p / 'pyvenv.cfg').is_file()), None)


def use_own_numba_cache(environ=None, prefix=None):
    """
    Keep another venv's numba cache out of this environment's programs; return the change.

    A ``NUMBA_CACHE_DIR`` inside another venv holds that venv's numba version's index: this
    numba would find it stale, compile every kernel (~10 CPU-s before the node's first
    sample, at every start) and overwrite it, so that the other venv's next program
    compiles too. It is replaced by this venv's own ``numba_cache`` if it has one, else
    removed (``__pycache__``). A directory outside any venv (the user's) stays. Runs before
    numba is imported (numba reads the variable once, at import).

    Parameters
    ----------
    environ : dict, optional
        The environment to correct (default ``os.environ``).
    prefix : str, optional
        This venv (default ``sys.prefix``).

    Returns
    -------
    str or None or bool
        The directory now used (None: ``__pycache__``), or False if nothing changed.
    """
    environ = os.environ if environ is None else environ
    prefix = Path(os.path.realpath(sys.prefix if prefix is None else prefix))
    cache = environ.get(NUMBA_CACHE_ENV)
    venv = venv_of(cache) if cache else None
    if venv is None or venv == prefix:
        return False
    own = prefix / OWN_NUMBA_CACHE
    if own.is_dir():
        environ[NUMBA_CACHE_ENV] = str(own)
        return str(own)
    del environ[NUMBA_CACHE_ENV]
    return None
