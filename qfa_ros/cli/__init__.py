"""
Command-line tools: thin entry points that parse arguments and call the layers below.

``qfa_node`` (``ros2 run qfa_ros qfa_node``), ``qfa-sim``, ``qfa-replay`` and
``qfa-report``. Any layer may be imported here; nothing imports this package.
"""
