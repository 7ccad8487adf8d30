"""Write self-describing estimation traces as rosbag2-compatible MCAP files.

One trace file per estimation run, every topic under a namespace (default
``/qfa/trace``) and of a standard type, so ``ros2 bag play`` needs no extra
packages and Foxglove / PlotJuggler show everything:

``/qfa/trace/settings`` and ``/qfa/trace/result`` : diagnostic_msgs/msg/DiagnosticArray
    One ``DiagnosticStatus`` whose ``values`` are the mapping as ``KeyValue``
    pairs, offered transient-local so that late subscribers of ``ros2 bag play``
    still get them. Nested mappings are flattened with ``.`` in the key.
    Values: strings as they are; numbers, booleans, None and sequences as JSON
    (``1.25``, ``true``, ``null``, ``[1.0, 2.0]``; floats round-trip exactly,
    non-finite ones are ``NaN``/``Infinity``). ``key_values_to_dict`` reverses it.
    DiagnosticArray rather than one JSON string so that viewers (Foxglove's
    diagnostics and raw-message panels, PlotJuggler, ``ros2 topic echo`` during
    ``ros2 bag play``) show one readable pair per setting instead of a blob.
``/qfa/trace/<table name>`` : std_msgs/msg/Float64MultiArray
    One message per table row, logged at that row's time, so a plot of
    ``/qfa/trace/<name>/data[i]`` against log time is the column against time.
    ``layout.dim[i].label`` names column ``i`` (each dim has size 1 and stride 1:
    the layout is used as a column header, which MultiArrayLayout has no other
    place for; ``data_offset`` is 0).
``/qfa/trace/imu/data_raw``, ``/qfa/trace/imu/temperature`` : pass-through
    sensor_msgs/msg/Imu and sensor_msgs/msg/Temperature samples, as mappings or
    CDR bytes.
"""

from collections.abc import Mapping
import json
import re

import numpy as np

from qfa_ros.bag.qos import QOS_DEFAULT, QOS_LATCHED, QOS_SENSOR_DATA
from qfa_ros.bag.types import stamp
from qfa_ros.bag.writer import DEFAULT_CHUNK_SIZE, McapBagWriter

__all__ = ['TraceWriter', 'encode_key_values', 'key_values_to_dict']

_NAME_RE = re.compile(r'^[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*$')
_RESERVED = frozenset({'settings', 'result', 'imu'})
# float64 holds every integer up to 2**53 exactly, nanosecond times are far beyond.
_FLOAT64_EXACT_INT = 2**53


def _value_text(value):
    if isinstance(value, str):
        return value
    if isinstance(value, (np.generic, np.ndarray)):
        value = value.tolist()  # a numpy scalar's is its Python value
    if isinstance(value, tuple):
        value = list(value)
    try:
        return json.dumps(value, allow_nan=True)
    except TypeError:
        raise TypeError(
            f'cannot record {type(value).__name__} {value!r}: use str, numbers, bool, None, '
            'sequences or numpy arrays'
        ) from None


def encode_key_values(mapping, prefix=''):
    """Flatten a mapping into ``diagnostic_msgs/KeyValue`` dicts.

    Parameters
    ----------
    mapping : mapping
        Keys are converted with ``str``; nested mappings are flattened with ``.``.
    prefix : str
        Prepended to every key.

    Returns
    -------
    list of dict
        ``[{'key': ..., 'value': ...}, ...]`` in the mapping's order.
    """
    pairs = []
    for key, value in mapping.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            pairs.extend(encode_key_values(value, f'{name}.'))
        else:
            pairs.append({'key': name, 'value': _value_text(value)})
    return pairs


def key_values_to_dict(values):
    """Decode ``KeyValue`` pairs written by ``TraceWriter`` back into a flat dict.

    Values that parse as JSON are returned parsed, others as strings, so a
    string that looks like a number (``'5'``) comes back as a number.

    Parameters
    ----------
    values : iterable
        KeyValue messages (objects with ``key``/``value`` or mappings).

    Returns
    -------
    dict
        Flattened keys (``'a.b'``) to values.
    """
    out = {}
    for pair in values:
        key, text = ((pair['key'], pair['value']) if isinstance(pair, Mapping)
                     else (pair.key, pair.value))
        try:
            out[key] = json.loads(text)
        except ValueError:
            out[key] = text
    return out


class TraceWriter:
    """Record one estimation trace; a context manager with an idempotent ``finish()``.

    Parameters
    ----------
    path : str or os.PathLike
        Final ``.mcap`` file name (written as ``.part`` until finished).
    namespace : str
        Absolute topic namespace for every trace topic.
    source : str
        ``hardware_id`` of the settings and result statuses, e.g. the node name.
    compression, chunk_size, storage_metadata, overwrite
        As for ``McapBagWriter``.

    Notes
    -----
    Leaving the ``with`` block by an exception aborts the trace (only the
    ``.part`` file remains), so a trace under its final name is always complete.
    The settings, each table and the result end a chunk: a trace cut short by a
    kill keeps every one written before it (``qfa-report recover``).
    """

    def __init__(self, path, *, namespace='/qfa/trace', source='qfa_ros', compression='zstd',
                 chunk_size=DEFAULT_CHUNK_SIZE, storage_metadata=None, overwrite=False,
                 bag=None):
        namespace = '/' + namespace.strip('/')
        if not _NAME_RE.match(namespace[1:]):
            raise ValueError(f'invalid namespace {namespace!r}')
        self.namespace = namespace
        self.source = str(source)
        if bag is None:
            bag = McapBagWriter(path, compression=compression, chunk_size=chunk_size,
                                storage_metadata=storage_metadata, overwrite=overwrite)
        self._bag = bag
        self._table_columns = {}

    @classmethod
    def in_bag(cls, bag, namespace, source='qfa_ros'):
        """Return a writer of trace topics under ``namespace`` inside an open ``bag``.

        The caller owns ``bag`` and finishes it; this writer's ``finish`` is not used.
        """
        return cls(bag.path, namespace=namespace, source=source, bag=bag)

    @property
    def path(self):
        """Final path of the trace file."""
        return self._bag.path

    @property
    def bag(self):
        """The underlying ``McapBagWriter``, for extra topics."""
        return self._bag

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        return self._bag.__exit__(exc_type, exc, traceback)

    def finish(self):
        """Complete and publish the trace file; idempotent. Returns the final path."""
        return self._bag.finish()

    def abort(self):
        """Stop without publishing; the ``.part`` file stays."""
        self._bag.abort()

    def topic(self, name):
        """Return the absolute trace topic for a relative name."""
        if not _NAME_RE.match(name):
            raise ValueError(f'invalid trace topic name {name!r}')
        return f'{self.namespace}/{name}'

    def _write_status(self, name, mapping, time_ns, level, summary):
        topic = self.topic(name)
        self._bag.add_topic(topic, 'diagnostic_msgs/msg/DiagnosticArray', QOS_LATCHED)
        if not isinstance(mapping, Mapping):
            raise TypeError(f'{name} must be a mapping, got {type(mapping).__name__}')
        self._bag.write(topic, {
            'header': {'stamp': stamp(time_ns), 'frame_id': ''},
            'status': [{
                'level': int(level),
                'name': f'{self.namespace.lstrip("/")}/{name}',
                'message': summary,
                'hardware_id': self.source,
                'values': encode_key_values(mapping),
            }],
        }, time_ns)
        self._bag.flush()

    def write_settings(self, settings, time_ns, *, summary='settings'):
        """Record the estimation settings as KeyValue pairs on ``<ns>/settings``.

        Parameters
        ----------
        settings : mapping
            Schedule parameters, model constants, seed, ...
        time_ns : int
            Log time in nanoseconds (typically the schedule start).
        summary : str
            ``DiagnosticStatus.message``.
        """
        self._write_status('settings', settings, time_ns, 0, summary)

    def write_result(self, result, time_ns, *, level=0, summary=''):
        """Record the estimation result as KeyValue pairs on ``<ns>/result``.

        Parameters
        ----------
        result : mapping
            Estimates, fit statistics, corrections applied, ...
        time_ns : int
            Log time in nanoseconds (typically the schedule end).
        level : int
            ``DiagnosticStatus`` level: 0 OK, 1 WARN, 2 ERROR.
        summary : str
            One-line human summary (``DiagnosticStatus.message``).
        """
        if level not in (0, 1, 2, 3):
            raise ValueError(f'level must be 0 (OK), 1 (WARN), 2 (ERROR) or 3, got {level!r}')
        self._write_status('result', result, time_ns, level, summary)

    def write_table(self, name, columns, time_ns):
        """Record a table, one Float64MultiArray per row, on ``<ns>/<name>``.

        Parameters
        ----------
        name : str
            Relative topic name, e.g. ``'forward/points'``; ``settings``,
            ``result`` and ``imu`` are reserved.
        columns : mapping of str to array_like
            Equal-length 1-D columns, converted to float64. Integer columns
            beyond 2**53 are refused (float64 would round them; pass times as
            seconds from a start, or as row times).
        time_ns : int or array_like of int
            Log time of every row, or one integer time per row.

        Returns
        -------
        int
            Number of rows written.
        """
        if name.split('/')[0] in _RESERVED:
            raise ValueError(f'table name {name!r} is reserved')
        topic = self.topic(name)
        labels, matrix = _table_matrix(name, columns)
        rows = matrix.shape[0]
        times = np.asarray(time_ns)
        if times.ndim == 0:
            times = np.full(rows, times)
        if times.shape != (rows,) or not np.issubdtype(times.dtype, np.integer):
            raise ValueError(
                f'table {name!r}: time_ns must be one integer or {rows} integers (ns), '
                f'got shape {times.shape} dtype {times.dtype}'
            )
        known = self._table_columns.setdefault(topic, labels)
        if known != labels:
            raise ValueError(f'table {name!r} was written with columns {known}, not {labels}')
        self._bag.add_topic(topic, 'std_msgs/msg/Float64MultiArray', QOS_DEFAULT)
        layout = {
            'dim': [{'label': label, 'size': 1, 'stride': 1} for label in labels],
            'data_offset': 0,
        }
        for row, row_time in zip(matrix.tolist(), times.tolist()):
            self._bag.write(topic, {'layout': layout, 'data': row}, row_time)
        self._bag.flush()
        return rows

    def write_message(self, name, msgtype, message, time_ns, *, qos=None):
        """Record any supported message on ``<ns>/<name>``.

        Parameters
        ----------
        name : str
            Relative topic name.
        msgtype : str
            Message type, e.g. ``'geometry_msgs/msg/AccelStamped'``.
        message : mapping or bytes-like
            A mapping to serialize, or CDR bytes.
        time_ns : int
            Log time in nanoseconds.
        qos : QosProfile, optional
            Offered QoS recorded for the topic.
        """
        topic = self.topic(name)
        self._bag.add_topic(topic, msgtype, qos)
        if isinstance(message, (bytes, bytearray, memoryview)):
            self._bag.write_serialized(topic, message, time_ns)
        else:
            self._bag.write(topic, message, time_ns)

    def write_imu(self, message, time_ns):
        """Record a sensor_msgs/msg/Imu sample (mapping or CDR) on ``<ns>/imu/data_raw``."""
        self.write_message('imu/data_raw', 'sensor_msgs/msg/Imu', message, time_ns,
                           qos=QOS_SENSOR_DATA)

    def write_temperature(self, message, time_ns):
        """Record a sensor_msgs/msg/Temperature sample on ``<ns>/imu/temperature``."""
        self.write_message('imu/temperature', 'sensor_msgs/msg/Temperature', message, time_ns,
                           qos=QOS_SENSOR_DATA)


def _table_matrix(name, columns):
    if not isinstance(columns, Mapping) or not columns:
        raise ValueError(f'table {name!r}: columns must be a non-empty mapping')
    labels = []
    arrays = []
    for label, values in columns.items():
        if not isinstance(label, str) or not label:
            raise ValueError(f'table {name!r}: column names must be non-empty strings')
        array = np.asarray(values)
        if array.ndim != 1:
            raise ValueError(f'table {name!r}: column {label!r} is not 1-D ({array.shape})')
        real = np.issubdtype(array.dtype, np.number) and not np.iscomplexobj(array)
        if not (real or array.dtype == np.bool_):
            raise ValueError(f'table {name!r}: column {label!r} is not real ({array.dtype})')
        if np.issubdtype(array.dtype, np.integer) and array.size and (
                np.abs(array.astype(np.float64)).max() > _FLOAT64_EXACT_INT):
            raise ValueError(
                f'table {name!r}: integer column {label!r} exceeds 2**53, which float64 '
                'cannot hold exactly'
            )
        labels.append(label)
        arrays.append(array.astype(np.float64))
    lengths = {array.shape[0] for array in arrays}
    if len(lengths) != 1:
        raise ValueError(f'table {name!r}: columns differ in length ({sorted(lengths)})')
    return labels, np.column_stack(arrays)
