"""Batch CDR encoding of REP-145 IMU samples as ``sensor_msgs/msg/Imu`` (no ROS)."""

import struct

import numpy as np

NS_PER_S = 1_000_000_000
ENCAPSULATION = b'\x00\x01\x00\x00'
"""CDR encapsulation header: plain CDR, little endian (what rmw and rosbag2 write)."""

_DOUBLES_BEFORE_RATE = 4 + 9
"""orientation, orientation_covariance."""
_DOUBLES_BEFORE_ACCEL = _DOUBLES_BEFORE_RATE + 3 + 9
"""... then angular_velocity, angular_velocity_covariance."""

IMU_DOUBLES = _DOUBLES_BEFORE_ACCEL + 3 + 9
"""Doubles from the orientation on: ... then linear_acceleration and its covariance."""

UNKNOWN_COVARIANCE = (-1.0,) + (0.0,) * 8
"""REP-145: element 0 = -1 marks a quantity the sensor does not measure."""


class ImuEncoder:
    """
    Encode IMU samples as serialized ``sensor_msgs/msg/Imu`` (CDR) messages.

    The messages of one stream differ only in ``header.stamp``, ``angular_velocity``
    and ``linear_acceleration``, so the encoder serializes one template message and
    writes those fields of every sample into copies of it with numpy; the bytes equal
    ``rclpy.serialization.serialize_message`` of the same message. The orientation is
    marked unknown (REP-145: covariance element 0 = -1, identity quaternion); so is
    the angular velocity when no ``rate_covariance`` is given.

    Parameters
    ----------
    frame_id : str
        ``header.frame_id``.
    acceleration_covariance : sequence of 9 float
        ``linear_acceleration_covariance``, row major [(m/s^2)^2].
    rate_covariance : sequence of 9 float or None
        ``angular_velocity_covariance``, row major [(rad/s)^2]; None: no gyros.
    """

    def __init__(self, frame_id, acceleration_covariance, rate_covariance=None):
        covariance = [float(v) for v in acceleration_covariance]
        if len(covariance) != 9:
            raise ValueError('acceleration_covariance must have 9 elements, '
                             f'got {len(covariance)}')
        self.has_rate = rate_covariance is not None
        rate_covariance = UNKNOWN_COVARIANCE if rate_covariance is None \
            else [float(v) for v in rate_covariance]
        if len(rate_covariance) != 9:
            raise ValueError(f'rate_covariance must have 9 elements, got {len(rate_covariance)}')
        self.frame_id = frame_id
        name = frame_id.encode('utf-8')
        # Offsets count from the end of the encapsulation header (CDR alignment origin).
        string_end = 12 + len(name) + 1
        orientation = (string_end + 7) // 8 * 8
        self.accel_offset = len(ENCAPSULATION) + orientation + 8 * _DOUBLES_BEFORE_ACCEL
        self.rate_offset = len(ENCAPSULATION) + orientation + 8 * _DOUBLES_BEFORE_RATE
        body = bytearray(ENCAPSULATION)
        body += struct.pack('<iII', 0, 0, len(name) + 1) + name + b'\x00'
        body += bytes(orientation - string_end)
        # orientation (identity), orientation_covariance, angular_velocity,
        # angular_velocity_covariance, linear_acceleration, linear_acceleration_covariance.
        body += np.array([0.0, 0.0, 0.0, 1.0, *UNKNOWN_COVARIANCE, 0.0, 0.0, 0.0,
                          *rate_covariance, 0.0, 0.0, 0.0, *covariance], dtype='<f8').tobytes()
        self.template = np.frombuffer(bytes(body), dtype=np.uint8)
        self.size = len(body)

    def encode(self, stamps_ns, accel, rate=None):
        """
        Return one serialized message (``bytes``) per sample.

        Parameters
        ----------
        stamps_ns : int array_like, shape (n,)
            ``header.stamp`` of each sample [ns since the epoch], >= 0.
        accel : float array_like, shape (n, 3)
            Specific force per sample [m/s^2].
        rate : float array_like, shape (n, 3), optional
            Angular rate per sample [rad/s] (encoders built with ``rate_covariance``).
        """
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        accel = np.asarray(accel, dtype='<f8')
        count = len(stamps)
        if accel.shape != (count, 3):
            raise ValueError(f'accel must have shape ({count}, 3), got {accel.shape}')
        if count and stamps.min() < 0:
            raise ValueError('stamps_ns must not be negative')
        buffer = np.tile(self.template, (count, 1))
        stamp = np.empty((count, 2), dtype='<u4')
        stamp[:, 0], stamp[:, 1] = np.divmod(stamps, NS_PER_S)
        start = len(ENCAPSULATION)
        buffer[:, start:start + 8] = stamp.view(np.uint8).reshape(count, 8)
        buffer[:, self.accel_offset:self.accel_offset + 24] = \
            np.ascontiguousarray(accel).view(np.uint8).reshape(count, 24)
        if rate is not None:
            rate = np.asarray(rate, dtype='<f8')
            if rate.shape != (count, 3):
                raise ValueError(f'rate must have shape ({count}, 3), got {rate.shape}')
            buffer[:, self.rate_offset:self.rate_offset + 24] = \
                np.ascontiguousarray(rate).view(np.uint8).reshape(count, 24)
        data = buffer.tobytes()
        size = self.size
        return [data[i * size:(i + 1) * size] for i in range(count)]


def decode_imu(messages):
    """
    Return (stamps_ns int64[n], accel (n, 3), rate (n, 3)) of serialized Imu messages.

    The inverse of :meth:`ImuEncoder.encode` for any little-endian CDR ``sensor_msgs/msg/Imu``
    stream whose ``header.frame_id`` keeps one length (every message of a stream from
    one sensor): the fields are read at their offsets with numpy, not message by message.

    Raises
    ------
    ValueError
        a message is not little-endian CDR or differs in size.
    """
    messages = list(messages)
    if not messages:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3))
    first = messages[0]
    if first[:4] != ENCAPSULATION:
        raise ValueError('decode_imu reads little-endian plain CDR only')
    name_length = struct.unpack_from('<I', first, 12)[0]
    orientation = (12 + name_length + 7) // 8 * 8
    size = len(first)
    if size < len(ENCAPSULATION) + orientation + 8 * IMU_DOUBLES:
        raise ValueError('decode_imu: messages too short for sensor_msgs/msg/Imu')
    if any(len(m) != size for m in messages):
        raise ValueError('decode_imu needs messages of one size (one frame_id)')
    buffer = np.frombuffer(b''.join(messages), dtype=np.uint8).reshape(len(messages), size)
    start = len(ENCAPSULATION)
    stamp = np.ascontiguousarray(buffer[:, start:start + 8]).view('<u4').astype(np.int64)
    stamps = stamp[:, 0] * NS_PER_S + stamp[:, 1]

    def vectors(offset):
        return np.ascontiguousarray(buffer[:, offset:offset + 24]).view('<f8').astype(float)

    base = start + orientation
    return (stamps, vectors(base + 8 * _DOUBLES_BEFORE_ACCEL),
            vectors(base + 8 * _DOUBLES_BEFORE_RATE))
