"""ROS 2 message definitions (ros2msg) and type hashes of the types the recorder writes.

The own text of each ``.msg`` file is Kilted's, byte for byte, shipped beside this module
(``definitions/<pkg>/msg/<Name>.msg``, copied from the ``ros-*-msgs`` wheels), so that the
recorder needs no ROS installation and writes the same bytes under Jazzy, whose
``builtin_interfaces/Time`` and ``Duration`` only carry longer comments
(:mod:`qfa_ros.ros.distro`). rosbags' type stores hold the fields, constants and RIHS01
hashes but neither comments nor default values, which rosbag2 writes (``float64 w 1``):
the text stays ours, everything read from it is rosbags'. Each text is parsed by
``rosbags.typesys.get_types_from_msg`` (the fields, hence its dependencies) and the RIHS01
hash is ``Typestore.hash_rihs01`` of the parsed types, the hash rosbags' Jazzy and Kilted
stores give (``test/test_recorder.py`` checks both, and the texts against the installed
files when those are present).

:func:`definition` composes the full definition as rosbag2's local message definition
source does: the root text, then for every dependency, depth first in sorted order and
each only once, a newline, a line of 80 ``=``, ``MSG: pkg/Name`` and its text.
"""

import functools
from importlib import resources
import threading

from rosbags.interfaces import Nodetype
from rosbags.typesys import get_types_from_msg, get_typestore, Stores

RECORDED_TYPES = (
    'builtin_interfaces/msg/Time',
    'diagnostic_msgs/msg/DiagnosticArray',
    'diagnostic_msgs/msg/DiagnosticStatus',
    'diagnostic_msgs/msg/KeyValue',
    'geometry_msgs/msg/AccelStamped',
    'geometry_msgs/msg/Vector3Stamped',
    'nav_msgs/msg/Odometry',
    'rosgraph_msgs/msg/Clock',
    'sensor_msgs/msg/Imu',
    'sensor_msgs/msg/NavSatFix',
    'sensor_msgs/msg/Temperature',
    'std_msgs/msg/Bool',
    'std_msgs/msg/Float64',
    'std_msgs/msg/Float64MultiArray',
    'std_msgs/msg/Header',
    'std_msgs/msg/String',
)
"""Every type the recorder can write without a registered definition."""

DEFINITIONS = resources.files(__package__) / 'definitions'
"""Kilted's ``.msg`` files of the recorded types and their dependencies."""

SEPARATOR = '=' * 80
_STORE = get_typestore(Stores.EMPTY)
_STORE_LOCK = threading.Lock()  # writers on several threads may meet a type first together


def short_name(msgtype):
    """Return ``pkg/Name`` for ``pkg/msg/Name`` (how rosbag2 names a dependency), or pkg/Name."""
    parts = msgtype.split('/')
    return f'{parts[0]}/{parts[-1]}'


@functools.cache
def own_text(msgtype):
    """Return the text of the ``.msg`` file of ``msgtype``, without its dependencies."""
    return (DEFINITIONS / f'{msgtype}.msg').read_text()


@functools.cache
def dependencies(msgtype):
    """Return the message types the fields of ``msgtype`` use directly, sorted as rosbag2 does."""
    types = get_types_from_msg(own_text(msgtype), msgtype)
    with _STORE_LOCK:
        if msgtype not in _STORE.fielddefs:
            _STORE.register(types)
    found = set()
    for _, (kind, detail) in types[msgtype][1]:
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            kind, detail = detail[0]
        if kind == Nodetype.NAME:
            found.add(detail)
    return tuple(sorted(found, key=short_name))


@functools.cache
def definition(msgtype):
    """Return the full ros2msg definition of ``msgtype`` as rosbag2 writes it."""
    seen = set()

    def text(name):
        parts = [own_text(name)]
        for dependency in dependencies(name):
            if dependency not in seen:
                seen.add(dependency)
                parts.append(f'\n{SEPARATOR}\nMSG: {short_name(dependency)}\n'
                             + text(dependency))
        return ''.join(parts)

    return text(msgtype)


@functools.cache
def type_hash(msgtype):
    """Return the RIHS01 type description hash of ``msgtype`` (rosbags' ``hash_rihs01``)."""
    definition(msgtype)  # every type it uses parsed and registered
    with _STORE_LOCK:
        return _STORE.hash_rihs01(msgtype)
