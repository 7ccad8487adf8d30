"""
Message types the bag writer knows: definitions, type hashes, encoders, times.

Every standard type this project records comes from :mod:`qfa_ros.bag.msgdefs`;
:func:`register_message_definition` adds more. Messages given as mappings are checked
against their definition and encoded to CDR with the public type store of rosbags.
"""

import ast
from collections.abc import Mapping
import operator
import re
import threading

import numpy as np
from rosbags.interfaces import Nodetype
from rosbags.typesys import get_types_from_msg, get_typestore, Stores

from qfa_ros.bag import msgdefs


def stamp(time_ns):
    """Convert integer nanoseconds to a ``builtin_interfaces/Time`` mapping.

    Parameters
    ----------
    time_ns : int
        Nanoseconds since the epoch of the clock in use.

    Returns
    -------
    dict
        ``{'sec': ..., 'nanosec': ...}``.
    """
    sec, nanosec = divmod(as_time_ns(time_ns, 'time_ns'), 1_000_000_000)
    return {'sec': sec, 'nanosec': nanosec}


def as_time_ns(value, what):
    """Return ``value`` as integer nanoseconds in [0, 2**64); ``what`` names it in errors."""
    try:
        time_ns = operator.index(value)
    except TypeError:
        raise TypeError(
            f'{what} must be integer nanoseconds, got {type(value).__name__} {value!r}'
        ) from None
    if not 0 <= time_ns < 2**64:
        raise ValueError(f'{what} must be in [0, 2**64) nanoseconds, got {time_ns}')
    return time_ns


def canonical_type(msgtype):
    """Return ``pkg/msg/Name`` for ``pkg/Name`` or ``pkg/msg/Name``."""
    parts = msgtype.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f'message type must look like pkg/msg/Name, got {msgtype!r}')
    return '/'.join(parts)


_REGISTERED = {}  # msgtype: (definition, type hash), by register_message_definition
_ENCODERS = {}
_CACHE_LOCK = threading.Lock()  # protects _REGISTERED and _ENCODERS


def supported_types():
    """Return the message types this module can write, sorted."""
    return sorted(set(msgdefs.RECORDED_TYPES) | set(_REGISTERED))


def register_message_definition(msgtype, definition, type_hash=''):
    """Add a message type the shipped definitions do not cover (or replace one).

    Parameters
    ----------
    msgtype : str
        Type name like ``'geometry_msgs/msg/Twist'``.
    definition : str
        Full ``ros2msg`` text with dependent definitions concatenated the way
        rosbag2 writes them (separator line of 80 ``=``, ``MSG: pkg/Name``).
    type_hash : str
        ``RIHS01_...`` type description hash, or empty when unknown.
    """
    msgtype = canonical_type(msgtype)
    with _CACHE_LOCK:
        _REGISTERED[msgtype] = (definition, type_hash)
        _ENCODERS.pop(msgtype, None)


def definition_of(msgtype):
    """Return the full ``ros2msg`` definition of a supported type."""
    if msgtype in _REGISTERED:
        return _REGISTERED[msgtype][0]
    if msgtype in msgdefs.RECORDED_TYPES:
        return msgdefs.definition(msgtype)
    raise ValueError(
        f'no message definition for {msgtype!r}; supported: {", ".join(supported_types())}'
        ' (add one with register_message_definition)'
    )


def _encoder(msgtype):
    encoder = _ENCODERS.get(msgtype)
    if encoder is None:
        with _CACHE_LOCK:
            encoder = _Encoder(msgtype, definition_of(msgtype))
            _ENCODERS[msgtype] = encoder
    return encoder


# numpy element type of each primitive in an array field (rosbags packs arrays as raw bytes).
_ARRAY_DTYPES = {
    'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'int8': np.int8, 'uint8': np.uint8,
    'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32, 'uint32': np.uint32,
    'int64': np.int64, 'uint64': np.uint64, 'float32': np.float32, 'float64': np.float64,
}


def _scalar(primitive):
    """Return ``(convert, default)`` for one primitive field, coercing as mcap-ros2-support did."""
    if primitive in ('string', 'wstring'):
        return str, ''
    if primitive.startswith('float'):
        return float, 0.0
    if primitive == 'bool':
        return bool, False
    if primitive == 'byte':
        # ROS 2 spells byte fields (DiagnosticStatus.level) as b'\x00'; CDR writes one
        # octet, which rosbags packs signed.
        def byte(value):
            value = value[0] if isinstance(value, bytes) and len(value) == 1 else int(value)
            return value - 256 if value > 127 else value
        return byte, 0
    return int, 0


class _Encoder:
    """Encode mappings of one message type to CDR with the public rosbags type store.

    Each type of the definition gets a builder that checks the field names (a misspelt
    key would otherwise be encoded as a zero), fills missing fields with their ROS
    defaults, coerces values and returns the rosbags message object that
    ``Typestore.serialize_cdr`` encodes.
    """

    def __init__(self, msgtype, definition):
        self._msgtype = msgtype
        self._store = get_typestore(Stores.EMPTY)
        self._store.register(get_types_from_msg(definition, msgtype))
        self._builders = {}
        self._defaults = _definition_defaults(msgtype, definition)
        self._build = self._builder(msgtype)

    def __call__(self, message):
        if not isinstance(message, Mapping):
            raise TypeError(
                f'{self._msgtype} message must be a mapping, got {type(message).__name__}')
        return bytes(self._store.serialize_cdr(self._build(message, self._msgtype),
                                               self._msgtype))

    def _builder(self, typename):
        if typename in self._builders:
            return self._builders[typename]
        cls = self._store.types[typename]
        short = msgdefs.short_name(typename)
        defaults = self._defaults.get(short, {})
        fields = [(name, *self._field(desc, defaults.get(name)))
                  for name, desc in self._store.fielddefs[typename][1]]
        names = frozenset(name for name, _, _ in fields)

        def build(value, where):
            if value is None:
                return cls(*[default() for _, _, default in fields])
            if isinstance(value, Mapping):
                unknown = value.keys() - names
                if unknown:
                    raise KeyError(
                        f'{where}: {short} has no field {sorted(unknown)[0]!r} '
                        f'(fields: {", ".join(name for name, _, _ in fields)})')
                get = value.get
            else:  # attribute-style objects such as rclpy messages
                def get(name):
                    return getattr(value, name, None)
            arguments = []
            for name, convert, default in fields:
                item = get(name)
                arguments.append(default() if item is None else convert(item, f'{where}.{name}'))
            return cls(*arguments)

        self._builders[typename] = build
        return build

    def _field(self, desc, default=None):
        """Return ``(convert(value, where), default())`` for a field description."""
        convert, make_default = self._converter(desc)
        if default is None:
            return convert, make_default
        value = convert(default, 'default')
        return convert, lambda: value.copy() if hasattr(value, 'copy') else value

    def _converter(self, desc):
        kind, detail = desc
        if kind == Nodetype.NAME:
            build = self._builder(detail)
            return build, lambda: build(None, '')
        if kind == Nodetype.BASE:
            convert, zero = _scalar(detail[0])
            return (lambda value, where: convert(value)), lambda: zero
        (element_kind, element), bound = detail
        fixed = bound if kind == Nodetype.ARRAY else None
        upper = bound if kind == Nodetype.SEQUENCE else 0

        def check(count, where):
            if (fixed is not None and count != fixed) or (upper and count > upper):
                expected = 'exactly' if fixed is not None else 'at most'
                raise ValueError(f'{where}: expected {expected} {bound} elements, got {count}')

        if element_kind == Nodetype.BASE and element[0] in _ARRAY_DTYPES:
            dtype = _ARRAY_DTYPES[element[0]]

            def array(value, where):
                if isinstance(value, (bytes, bytearray)):
                    value = np.frombuffer(value, dtype=np.uint8)
                value = np.ascontiguousarray(value, dtype=dtype)
                check(value.size, where)
                return value.reshape(-1)
            return array, lambda: np.zeros(fixed or 0, dtype=dtype)
        if element_kind == Nodetype.BASE:
            convert, zero = _scalar(element[0])

            def convert_each(value, where):
                check(len(value), where)
                return [convert(item) for item in value]
            return convert_each, lambda: [zero] * (fixed or 0)
        build = self._builder(element)

        def build_each(value, where):
            check(len(value), where)
            return [build(item, f'{where}[]') for item in value]
        return build_each, lambda: [build(None, '') for _ in range(fixed or 0)]


def _definition_defaults(root_type, definition):
    """Map each type of a concatenated definition to ``{field: default}`` (``float64 w 1``).

    rosbags keeps no default values, so they are read from the text; a missing field
    takes its default (``geometry_msgs/Quaternion`` is the identity, ``w`` = 1).
    """
    tables = {}
    current = msgdefs.short_name(root_type)
    for section in re.split(r'^={3,}$', definition, flags=re.MULTILINE):
        lines = section.strip().splitlines()
        if lines and lines[0].startswith('MSG:'):
            current = msgdefs.short_name(lines[0].split()[1])
            lines = lines[1:]
        defaults = {}
        for raw_line in lines:
            tokens = raw_line.split('#', 1)[0].split(maxsplit=2)
            if len(tokens) == 3 and '=' not in tokens[1] and not tokens[2].startswith('='):
                defaults[tokens[1]] = _literal(tokens[2].strip())
        tables[current] = defaults
    return tables


def _literal(text):
    """Return the Python value of a ros2msg default (number, bool, string or array)."""
    try:
        return ast.literal_eval(re.sub(r'\b(true|false)\b', lambda m: m[0].title(), text))
    except (ValueError, SyntaxError):
        return text  # an unquoted string


def check_cdr(data, topic):
    """Return ``data`` as bytes if it looks like CDR; raise ``ValueError`` naming ``topic``."""
    view = memoryview(data)
    # Every CDR payload starts with a 4-byte encapsulation header whose first byte is 0.
    if view.nbytes < 4 or view[0] != 0:
        raise ValueError(f'{topic}: data is not CDR (missing encapsulation header)')
    return data if isinstance(data, bytes) else view.tobytes()


def type_hash_of(msgtype):
    """Return the RIHS01 type hash of a supported type, or '' when unknown."""
    if msgtype in _REGISTERED:
        return _REGISTERED[msgtype][1]
    return msgdefs.type_hash(msgtype) if msgtype in msgdefs.RECORDED_TYPES else ''



def encode_message(message, msgtype):
    """Return the CDR bytes of ``message`` (a mapping or message object) of ``msgtype``."""
    return _encoder(msgtype)(message)
