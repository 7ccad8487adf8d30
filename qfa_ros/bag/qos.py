"""
Offered QoS of recorded publishers, as rosbag2 stores it (``offered_qos_profiles``).

:class:`QosProfile` mirrors ``rmw_qos_profile_t`` without ROS; :func:`offered_qos_yaml`
writes the YAML list rosbag2 (metadata version 9) keeps in channel metadata.
"""

import dataclasses

import yaml

# RMW_DURATION_INFINITE as rmw reports it for a publisher's unset durations.
_INFINITE_SEC = 9223372036
_INFINITE_NSEC = 854775807


@dataclasses.dataclass(frozen=True)
class QosProfile:
    """Offered QoS of a recorded publisher, as rosbag2 stores it.

    Parameters
    ----------
    history : str
        ``'keep_last'``, ``'keep_all'``, ``'system_default'`` or ``'unknown'``.
    depth : int
        History depth.
    reliability : str
        ``'reliable'``, ``'best_effort'``, ``'system_default'`` or ``'unknown'``.
    durability : str
        ``'volatile'``, ``'transient_local'``, ``'system_default'`` or ``'unknown'``.
    deadline_ns, lifespan_ns, liveliness_lease_duration_ns : int or None
        Durations in nanoseconds; None is infinite (what rmw reports when unset).
    liveliness : str
        ``'automatic'``, ``'manual_by_topic'``, ``'system_default'`` or ``'unknown'``.
    avoid_ros_namespace_conventions : bool
        As in ``rmw_qos_profile_t``.
    """

    history: str = 'keep_last'
    depth: int = 10
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline_ns: int | None = None
    lifespan_ns: int | None = None
    liveliness: str = 'automatic'
    liveliness_lease_duration_ns: int | None = None
    avoid_ros_namespace_conventions: bool = False

    def as_dict(self):
        """Return the profile as the mapping rosbag2 (metadata version 9) serializes."""
        return {
            'history': self.history,
            'depth': int(self.depth),
            'reliability': self.reliability,
            'durability': self.durability,
            'deadline': _rmw_time(self.deadline_ns),
            'lifespan': _rmw_time(self.lifespan_ns),
            'liveliness': self.liveliness,
            'liveliness_lease_duration': _rmw_time(self.liveliness_lease_duration_ns),
            'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions),
        }


# Reliable + volatile is what rclpy offers by default and matches every subscriber.
QOS_DEFAULT = QosProfile()
QOS_SENSOR_DATA = QosProfile(depth=5, reliability='best_effort')
# For settings and results: late joiners of `ros2 bag play` still receive them.
QOS_LATCHED = QosProfile(depth=1, durability='transient_local')
# The truth an INS is scored against (truth/odometry, truth/imu_errors), in the node and in
# the bags: reliable, so a reliable subscriber (rviz2's default, a scoring script) gets
# every message, live and from `ros2 bag play`; a best-effort one (SensorDataQoS) matches
# it too. Ten messages (1 s at the default 10 Hz) for a briefly late subscriber.
QOS_TRUTH = QosProfile(depth=10, reliability='reliable')


def _rmw_time(duration_ns):
    if duration_ns is None:
        return {'sec': _INFINITE_SEC, 'nsec': _INFINITE_NSEC}
    sec, nsec = divmod(int(duration_ns), 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}


def dump_yaml(data):
    """Return ``data`` as block YAML in key order, without a trailing newline."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False).rstrip('\n')


def offered_qos_yaml(profiles):
    """Serialize QoS profiles into rosbag2's ``offered_qos_profiles`` YAML list.

    Parameters
    ----------
    profiles : QosProfile or iterable of QosProfile
        One profile per recorded publisher.

    Returns
    -------
    str
        The YAML text stored in the channel metadata.
    """
    return dump_yaml([profile.as_dict() for profile in _qos_list(profiles)])


def _qos_list(qos):
    if qos is None:
        return [QOS_DEFAULT]
    if isinstance(qos, QosProfile):
        return [qos]
    profiles = list(qos)
    if not all(isinstance(profile, QosProfile) for profile in profiles):
        raise TypeError('qos must be a QosProfile or an iterable of QosProfile')
    return profiles
