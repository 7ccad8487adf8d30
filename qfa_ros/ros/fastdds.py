"""Find and apply the Fast DDS discovery profile shipped in ``config/`` (no ROS imports)."""

import os
from pathlib import Path
import sys

from qfa_ros.ros.distro import (
    FASTDDS_VARIABLE,
    FASTRTPS_VARIABLE,
    profiles_file_variable,
    ros_distribution,
)

FASTDDS_PROFILE_NAME = 'fastdds_discovery.xml'


def shipped_fastdds_profile():
    """
    Return the Fast DDS profile shipped with qfa_ros, or None if it cannot be found.

    Looked up in the source tree (``config/`` beside the package), the pip data
    directory (``<prefix>/share/qfa_ros/config``) and the ament package share.
    """
    for path in (Path(__file__).resolve().parents[2] / 'config' / FASTDDS_PROFILE_NAME,
                 Path(sys.prefix) / 'share' / 'qfa_ros' / 'config' / FASTDDS_PROFILE_NAME):
        if path.is_file():
            return path
    try:
        from ament_index_python.packages import get_package_share_directory
        path = Path(get_package_share_directory('qfa_ros')) / 'config' / FASTDDS_PROFILE_NAME
    except (ImportError, LookupError, OSError, ValueError):
        # Not installed through ament, or no AMENT_PREFIX_PATH in the environment.
        return None
    return path if path.is_file() else None


def use_shipped_fastdds_profile(environ=None, distribution=None):
    """
    Point the Fast DDS profile variable at the shipped profile unless one is set.

    Fast DDS 3.2 drops a running participant's discovery reply that lands before a
    new participant's receivers are up and repeats it only with its next periodic
    announcement (3 s by default). The shipped profile makes ten initial
    announcements 100 ms apart and then announces every 1 s (measured in
    ``bench/results/discovery.md``). Call before ``rclpy.init``.

    The variable is the one the running distribution's Fast DDS reads
    (:func:`qfa_ros.ros.distro.profiles_file_variable`: ``FASTRTPS_DEFAULT_PROFILES_FILE``
    on Jazzy, ``FASTDDS_DEFAULT_PROFILES_FILE`` on Kilted). A profile the user set under
    either name is the one in effect (Jazzy's Fast DDS would ignore the documented
    ``FASTDDS_DEFAULT_PROFILES_FILE``, so it is copied to the name Jazzy reads).

    Parameters
    ----------
    distribution
        The ROS 2 distribution (default: :func:`ros_distribution`).

    Returns
    -------
    The profile now in effect (the user's own or the shipped one), or None.
    """
    environ = os.environ if environ is None else environ
    distribution = ros_distribution(environ) if distribution is None else distribution
    variable = profiles_file_variable(distribution)
    other = FASTRTPS_VARIABLE if variable == FASTDDS_VARIABLE else FASTDDS_VARIABLE
    if not environ.get(variable):
        profile = environ.get(other) or shipped_fastdds_profile()
        if profile is not None:
            environ[variable] = str(profile)
    return environ.get(variable)
