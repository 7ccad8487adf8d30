"""Read a recorded IMU stream and the truth of a ``qfa-sim`` bag as arrays (no ROS)."""

from mcap.reader import make_reader
import numpy as np

from qfa_ros.bag.imu_cdr import decode_imu

BATCH = 65536
"""Messages decoded per numpy batch."""


def read_imu(path, topic='/imu/data_raw'):
    """
    Return (stamps_ns, accel (n, 3) [m/s^2], rate (n, 3) [rad/s]) of ``topic`` in ``path``.

    ``path`` is one MCAP file; the messages come in log-time order.
    """
    parts = []
    batch = []
    with open(path, 'rb') as stream:
        for _, _, message in make_reader(stream).iter_messages(topics=[topic],
                                                               log_time_order=True):
            batch.append(message.data)
            if len(batch) == BATCH:
                parts.append(decode_imu(batch))
                batch = []
    parts.append(decode_imu(batch))
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(3))
