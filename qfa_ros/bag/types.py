"""
Message types the bag writer knows: definitions, type hashes, encoders, times.

Every standard type this project records is registered from :mod:`qfa_ros.bag.msgdefs`;
:func:`register_message_definition` adds more. Messages given as mappings are checked
against their definition and encoded to CDR with mcap-ros2-support.
"""

from collections.abc import Mapping
import operator
import re
import threading

from mcap_ros2._dynamic import serialize_dynamic

from qfa_ros.bag.msgdefs import MESSAGE_DEFINITIONS, PRIMITIVE_TYPES, TYPE_HASHES


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


def stamp_to_ns(time_msg):
    """Convert a ``builtin_interfaces/Time`` (mapping or object) to integer nanoseconds."""
    if isinstance(time_msg, Mapping):
        return int(time_msg['sec']) * 1_000_000_000 + int(time_msg['nanosec'])
    return int(time_msg.sec) * 1_000_000_000 + int(time_msg.nanosec)


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


_DEFINITIONS = dict(MESSAGE_DEFINITIONS)
_HASHES = dict(TYPE_HASHES)
_ENCODERS = {}
_FIELDS = {}
_CACHE_LOCK = threading.Lock()


def supported_types():
    """Return the message types this module can write, sorted."""
    return sorted(_DEFINITIONS)


def register_message_definition(msgtype, definition, type_hash=''):
    """Add a message type the embedded definitions do not cover.

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
        _DEFINITIONS[msgtype] = definition
        _HASHES[msgtype] = type_hash
        _ENCODERS.pop(msgtype, None)
        _FIELDS.pop(msgtype, None)


def definition_of(msgtype):
    """Return the full ``ros2msg`` definition of a registered type."""
    try:
        return _DEFINITIONS[msgtype]
    except KeyError:
        raise ValueError(
            f'no message definition for {msgtype!r}; supported: {", ".join(supported_types())}'
            ' (add one with register_message_definition)'
        ) from None


def _encoder(msgtype):
    encoder = _ENCODERS.get(msgtype)
    if encoder is None:
        with _CACHE_LOCK:
            encoder = serialize_dynamic(msgtype, definition_of(msgtype))[msgtype]
            _ENCODERS[msgtype] = encoder
            _FIELDS[msgtype] = _parse_fields(msgtype, definition_of(msgtype))
    return encoder


def _parse_fields(root_type, definition):
    """Map each type in a concatenated definition to ``{field: (nested type or None, is_array)}``.

    Only field names and nesting are needed (to reject misspelt keys, which the
    CDR encoder would otherwise silently encode as zeros).
    """
    tables = {}
    current = _short_type(root_type)
    for section in re.split(r'^={3,}$', definition, flags=re.MULTILINE):
        lines = section.strip().splitlines()
        if lines and lines[0].startswith('MSG:'):
            current = _short_type(lines[0].split()[1])
            lines = lines[1:]
        package = current.split('/')[0]
        fields = {}
        for raw_line in lines:
            line = raw_line.split('#', 1)[0].strip()
            if not line:
                continue
            tokens = line.split()
            if len(tokens) < 2 or '=' in tokens[1] or (len(tokens) > 2 and tokens[2][0] == '='):
                continue  # constant, not a field
            base = re.sub(r'\[.*\]$', '', tokens[0])
            is_array = base != tokens[0]
            base = base.split('<=')[0]
            if base in PRIMITIVE_TYPES:
                fields[tokens[1]] = (None, is_array)
            else:
                nested = base if '/' in base else f'{package}/{base}'
                fields[tokens[1]] = (_short_type(nested), is_array)
        tables[current] = fields
    return tables


def _short_type(msgtype):
    parts = msgtype.split('/')
    return f'{parts[0]}/{parts[-1]}'


def _normalized(message, msgtype):
    """Return a copy of ``message`` checked against its definition, numpy arrays as lists."""
    tables = _FIELDS[msgtype]
    builtin_time = {'sec': (None, False), 'nanosec': (None, False)}

    def walk(value, short_type, where):
        if not isinstance(value, Mapping):
            return value  # attribute-style objects are encoded as given
        fields = tables.get(short_type, builtin_time if short_type.startswith(
            'builtin_interfaces/') else None)
        out = {}
        for key, item in value.items():
            if key not in fields:
                raise KeyError(
                    f'{where}: {short_type} has no field {key!r} (fields: {", ".join(fields)})'
                )
            nested, is_array = fields[key]
            if hasattr(item, 'tolist') and not isinstance(item, (str, bytes)):
                item = item.tolist()
            if nested is None and not is_array and isinstance(item, bytes) and len(item) == 1:
                item = item[0]  # rclpy spells byte fields (DiagnosticStatus.level) as b'\x00'
            elif nested is not None:
                if is_array:
                    item = [walk(element, nested, f'{where}.{key}[]') for element in item]
                else:
                    item = walk(item, nested, f'{where}.{key}')
            out[key] = item
        return out

    if not isinstance(message, Mapping):
        raise TypeError(f'{msgtype} message must be a mapping, got {type(message).__name__}')
    return walk(message, _short_type(msgtype), msgtype)


def check_cdr(data, topic):
    """Return ``data`` as bytes if it looks like CDR; raise ``ValueError`` naming ``topic``."""
    view = memoryview(data)
    # Every CDR payload starts with a 4-byte encapsulation header whose first byte is 0.
    if view.nbytes < 4 or view[0] != 0:
        raise ValueError(f'{topic}: data is not CDR (missing encapsulation header)')
    return data if isinstance(data, bytes) else view.tobytes()


def type_hash_of(msgtype):
    """Return the RIHS01 type hash of a registered type, or '' when unknown."""
    return _HASHES.get(msgtype, '')


def encode_message(message, msgtype):
    """Return the CDR bytes of ``message`` (a mapping or message object) of ``msgtype``."""
    return _encoder(msgtype)(_normalized(message, msgtype))
