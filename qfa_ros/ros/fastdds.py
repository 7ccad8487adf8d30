"""Find and apply the Fast DDS discovery profile shipped in ``config/`` (no ROS imports)."""

import os
from pathlib import Path
import sys

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


def use_shipped_fastdds_profile(environ=None):
    """
    Point ``FASTDDS_DEFAULT_PROFILES_FILE`` at the shipped profile unless it is set.

    Fast DDS 3.2 drops a running participant's discovery reply that lands before a
    new participant's receivers are up and repeats it only with its next periodic
    announcement (3 s by default). The shipped profile makes ten initial
    announcements 100 ms apart and then announces every 1 s (measured in
    ``bench/results/discovery.md``). Call before ``rclpy.init``.

    Returns
    -------
    str or None
        The profile now in effect (the user's own or the shipped one).
    """
    environ = os.environ if environ is None else environ
    if not environ.get('FASTDDS_DEFAULT_PROFILES_FILE'):
        profile = shipped_fastdds_profile()
        if profile is not None:
            environ['FASTDDS_DEFAULT_PROFILES_FILE'] = str(profile)
    return environ.get('FASTDDS_DEFAULT_PROFILES_FILE')
