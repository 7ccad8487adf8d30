"""
Command-line tools: thin entry points that parse arguments and call the layers below.

``qfa_node`` (``ros2 run qfa_ros qfa_node``), ``qfa-sim``, ``qfa-replay``,
``qfa-report`` and ``qfa-fleet``. Any layer may be imported here; nothing imports this
package. Ctrl-C ends every command with one line, never a traceback, also while it still
imports (:mod:`qfa_ros.cli.interrupt`).
"""

from qfa_ros.cli.interrupt import install_interrupt_hook

install_interrupt_hook()
