"""
What differs between the ROS 2 distributions qfa_ros runs on, Jazzy (the LTS) and Kilted.

Everything the package does differently on one of them is decided here, and nothing here
imports rclpy, so that it can be asked before ``rclpy.init``. Compared in the wheels of
both (rclpy 7.1.6 and 9.1.2, the message packages 5.3.6 and 5.5.1):

- **Fast DDS.** Jazzy's Fast DDS 2.14 reads its XML profile from
  ``FASTRTPS_DEFAULT_PROFILES_FILE`` only; Kilted's 3.2 from
  ``FASTDDS_DEFAULT_PROFILES_FILE`` (its rmw still takes the old name, with a deprecation
  warning at every start). :func:`profiles_file_variable` names the one the running
  distribution reads; :mod:`qfa_ros.ros.fastdds` sets it.
- **Message definitions.** Jazzy's ``builtin_interfaces/Time`` and ``Duration`` carry
  longer comments than Kilted's; every field, and so every type hash (RIHS01, over the
  fields only), is the same. The recorder embeds Kilted's text under both
  (:mod:`qfa_ros.bag.msgdefs`), so that a bag is the same bytes whichever is installed;
  readers of both take it: rosbags' Jazzy and Kilted type stores parse it to the same
  fields and RIHS01 hashes, and rosbag2 plays a topic by its type name (a generic
  publisher) with the hash beside it, not by the text (``test/test_recorder.py``,
  ``docs/replay_report.md``).
- **rclpy.** The API the package calls is the same in 7 and 9 (the suite runs on both,
  ``make test ROS_DISTRO=jazzy``); an API that differs goes here.
- **Bag metadata.** ``ros_distro`` says ``kilted`` under both: the distribution whose
  message definitions the bag embeds (readers take the definitions, not this name).
- **The version line** (``qfa_node --version``) names the running one
  (:func:`ros_distribution`).
"""

import importlib.util
import os
from pathlib import Path

SUPPORTED_DISTRIBUTIONS = ('jazzy', 'kilted')
"""The distributions the suite runs on (``make test ROS_DISTRO=...``)."""

DISTRIBUTION_OF_RCLPY = {7: 'jazzy', 9: 'kilted'}
"""The ROS 2 distribution of each ``ros-rclpy`` wheel's major version."""

FASTDDS_VARIABLE = 'FASTDDS_DEFAULT_PROFILES_FILE'
"""Fast DDS 3 (Kilted and later): the XML profile file."""

FASTRTPS_VARIABLE = 'FASTRTPS_DEFAULT_PROFILES_FILE'
"""Fast DDS 2 (Jazzy, Humble): the XML profile file."""

FAST_DDS_2_DISTRIBUTIONS = ('humble', 'iron', 'jazzy')
"""Distributions whose Fast DDS (2.x) knows only :data:`FASTRTPS_VARIABLE`."""


def wheel_rclpy_version(spec=None):
    """
    Return the version of the ``ros-rclpy`` wheel this interpreter imports, or None.

    Read from the name of its ``.dist-info`` beside the ``rclpy`` package (a directory
    listing, not ``importlib.metadata``, which walks every distribution); None for an
    rclpy that is no wheel (a sourced ROS 2, a colcon workspace) or none at all.
    """
    spec = importlib.util.find_spec('rclpy') if spec is None else spec
    if spec is None or not spec.origin:
        return None
    for info in Path(spec.origin).parents[1].glob('ros_rclpy-*.dist-info'):
        return info.name[len('ros_rclpy-'):-len('.dist-info')]
    return None


def ros_distribution(environ=None):
    """
    Return the ROS 2 distribution of the rclpy this interpreter imports, or None.

    For the ROS 2 wheels, from the ``ros-rclpy`` version (:data:`DISTRIBUTION_OF_RCLPY`;
    ``rclpy X.Y.Z`` for a major version not listed); otherwise ``ROS_DISTRO``, which a
    sourced ROS 2 sets.
    """
    environ = os.environ if environ is None else environ
    version = wheel_rclpy_version()
    if version is not None:
        major = int(version.split('.')[0])
        return DISTRIBUTION_OF_RCLPY.get(major, f'rclpy {version}')
    return environ.get('ROS_DISTRO') or None


def profiles_file_variable(distribution):
    """Return the variable the Fast DDS of ``distribution`` reads its XML profile from."""
    if distribution in FAST_DDS_2_DISTRIBUTIONS:
        return FASTRTPS_VARIABLE
    return FASTDDS_VARIABLE
