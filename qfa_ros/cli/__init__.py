"""
Command-line tools: thin entry points that parse arguments and call the layers below.

``qfa_node`` (``ros2 run qfa_ros qfa_node``), ``qfa-sim``, ``qfa-replay``,
``qfa-report`` and ``qfa-fleet``. Any layer may be imported here; nothing imports this
package. Ctrl-C ends every command with one line, never a traceback, also while it still
imports (:mod:`qfa_ros.cli.interrupt`). ``qfa_node`` and ``qfa-replay`` started from
another ROS environment run on their own environment's ROS libraries
(:mod:`qfa_ros.cli.own_libraries`: checked here, before anything loads one), and every
command on its own venv's numba cache, before numba is imported.
"""

from qfa_ros.cli.interrupt import install_interrupt_hook
from qfa_ros.cli.own_libraries import use_own_numba_cache, use_own_ros_libraries

install_interrupt_hook()
use_own_ros_libraries()
use_own_numba_cache()
