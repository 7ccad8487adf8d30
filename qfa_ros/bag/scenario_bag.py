"""Record a simulated scenario as a rosbag2-compatible MCAP (no ROS needed)."""

import numpy as np

from qfa_ros.bag.estimation_trace import write_results
from qfa_ros.bag.imu_cdr import ImuEncoder
from qfa_ros.bag.qos import QOS_LATCHED, QOS_SENSOR_DATA, QOS_TRUTH
from qfa_ros.bag.trace_writer import TraceWriter
from qfa_ros.bag.types import stamp
from qfa_ros.bag.writer import McapBagWriter
from qfa_ros.model.design import published_acceleration_variance

IMU_TOPIC = '/imu/data_raw'
TRUTH_TOPIC = '/truth/odometry'
ORIGIN_TOPIC = '/truth/origin'
IMU_ERRORS_TOPIC = '/truth/imu_errors'
ORIGIN_METADATA = 'truth_origin'
"""Name of the MCAP metadata record of the truth origin (docs/ins.md)."""
NAVSAT_STATUS_FIX = 0
NAVSAT_COVARIANCE_TYPE_KNOWN = 3
TEMPERATURE_TOPIC = '/imu/temperature'
PHASE_TOPIC = '/qfa/scenario/phase'


class ScenarioBag:
    """
    The output of a ``qfa-sim`` scenario: IMU stream, temperature, phases and traces.

    Topics: ``/imu/data_raw`` (sensor_msgs/Imu, REP-145, log time = header stamp =
    the triad's stamps [ns]: ``qfa-sim``'s ``--start-time`` + sensor time; angular
    velocity from the gyros when ``rate_variance`` is given), with ``truth_frame_id``
    the truth: ``/truth/odometry`` (nav_msgs/Odometry, see :meth:`write_truth`) and
    ``/truth/origin`` (sensor_msgs/NavSatFix, transient local, and the MCAP metadata
    record ``truth_origin``; see :meth:`write_origin`) and ``/truth/imu_errors``
    (sensor_msgs/Imu, :meth:`write_imu_errors`),
    ``/imu/temperature`` (sensor_msgs/Temperature [degC]),
    ``/qfa/scenario/phase`` (std_msgs/String naming the phase that starts at its log
    time) and estimation traces under ``/qfa/trace/<run>/...`` (see
    :mod:`qfa_ros.bag.estimation_trace`). A context manager with an idempotent ``finish()``.
    ``config`` (:class:`qfa_ros.model.triad_config.TriadConfig`) sets the published
    ``linear_acceleration_covariance``
    (:func:`qfa_ros.model.design.published_acceleration_variance`).
    """

    def __init__(self, path, config, frame_id='imu_link', rate_variance=None,
                 truth_frame_id=None):
        self.bag = McapBagWriter(path, compression='zstd')
        self.frame_id = frame_id
        variance = published_acceleration_variance(config)
        rate_covariance = None if rate_variance is None else \
            list(np.diag(np.broadcast_to(rate_variance, 3)).ravel())
        self._imu = ImuEncoder(frame_id, np.diag(np.full(3, variance)).ravel(), rate_covariance)
        self.truth_frame_id = truth_frame_id
        if truth_frame_id is not None:
            self.bag.add_topic(TRUTH_TOPIC, 'nav_msgs/msg/Odometry', QOS_TRUTH)
            self.bag.add_topic(ORIGIN_TOPIC, 'sensor_msgs/msg/NavSatFix', QOS_LATCHED)
            self.bag.add_topic(IMU_ERRORS_TOPIC, 'sensor_msgs/msg/Imu', QOS_TRUTH)
        self.bag.add_topic(IMU_TOPIC, 'sensor_msgs/msg/Imu', QOS_SENSOR_DATA)
        self.bag.add_topic(TEMPERATURE_TOPIC, 'sensor_msgs/msg/Temperature', QOS_SENSOR_DATA)
        self.bag.add_topic(PHASE_TOPIC, 'std_msgs/msg/String', QOS_LATCHED)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        return self.bag.__exit__(exc_type, exc, traceback)

    def finish(self):
        """Complete the bag under its final name; idempotent."""
        return self.bag.finish()

    def write_imu(self, output):
        """Write the valid samples of a ``TriadOutput`` to ``/imu/data_raw``."""
        valid = output.valid.all(axis=1)
        stamps = output.stamps_ns[valid]
        rate = output.gyro[valid] if self._imu.has_rate else None
        self.bag.write_serialized_many(IMU_TOPIC,
                                       self._imu.encode(stamps, output.accel[valid], rate),
                                       stamps.tolist())

    def write_truth(self, stamps_ns, position, orientation, velocity, body_rate):
        """
        Write the true pose and twist on ``/truth/odometry`` (nav_msgs/Odometry).

        ``header.frame_id`` is the ENU tangent plane of the trajectory's start,
        ``child_frame_id`` the IMU frame; position [m] and orientation (x, y, z, w) in
        the tangent plane, linear velocity [m/s] and angular rate (w.r.t. the local
        ENU frame) [rad/s] in IMU axes, as the message defines; covariances zero.
        """
        zero = [0.0] * 36
        for k, time_ns in enumerate(np.asarray(stamps_ns).tolist()):
            p, q, v, w = (np.asarray(a[k], dtype=float).tolist()
                          for a in (position, orientation, velocity, body_rate))
            self.bag.write(TRUTH_TOPIC, {
                'header': {'stamp': stamp(time_ns), 'frame_id': self.truth_frame_id},
                'child_frame_id': self.frame_id,
                'pose': {'pose': {'position': dict(zip('xyz', p)),
                                  'orientation': dict(zip('xyzw', q))},
                         'covariance': zero},
                'twist': {'twist': {'linear': dict(zip('xyz', v)),
                                    'angular': dict(zip('xyz', w))},
                          'covariance': zero}}, time_ns)

    def write_origin(self, time_ns, latitude_deg, longitude_deg, height_m):
        """
        Write the truth origin: the geodetic point of the odometry's ENU tangent plane.

        On ``/truth/origin`` (sensor_msgs/NavSatFix at ``time_ns``, ``header.frame_id``
        the truth frame, status fix, the position exact: covariance zero of the known
        type) and as the MCAP metadata record ``truth_origin`` (``latitude_deg``,
        ``longitude_deg``, ``height_m`` above the WGS-84 ellipsoid, ``frame_id``,
        ``datum``), so that a reader without a message decoder finds it too.
        """
        self.bag.write(ORIGIN_TOPIC, origin_fix(time_ns, self.truth_frame_id, latitude_deg,
                                                longitude_deg, height_m), int(time_ns))
        self.bag.add_metadata(ORIGIN_METADATA, {
            'latitude_deg': repr(float(latitude_deg)),
            'longitude_deg': repr(float(longitude_deg)),
            'height_m': repr(float(height_m)), 'frame_id': self.truth_frame_id,
            'datum': 'WGS-84', 'topic': TRUTH_TOPIC})

    def write_imu_errors(self, time_ns, truth):
        """Write an :class:`~qfa_ros.model.error_truth.ErrorTruth` on ``/truth/imu_errors``."""
        fields = truth.imu_fields()
        message = {'header': {'stamp': stamp(int(time_ns)), 'frame_id': self.frame_id},
                   'orientation': {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0}}
        for name in ('linear_acceleration', 'angular_velocity'):
            message[name] = dict(zip('xyz', fields[name]))
        for name in ('linear_acceleration_covariance', 'angular_velocity_covariance',
                     'orientation_covariance'):
            message[name] = fields[name]
        self.bag.write(IMU_ERRORS_TOPIC, message, int(time_ns))

    def write_temperature(self, stamps_ns, celsius, variance=0.0):
        """Write sensor temperatures [degC] at ``stamps_ns``."""
        for time_ns, value in zip(np.asarray(stamps_ns).tolist(),
                                  np.asarray(celsius, dtype=float).tolist()):
            self.bag.write(TEMPERATURE_TOPIC, {
                'header': {'stamp': stamp(time_ns), 'frame_id': self.frame_id},
                'temperature': value, 'variance': variance}, time_ns)

    def write_phase(self, name, time_ns):
        """Mark the start of phase ``name`` at ``time_ns``."""
        self.bag.write(PHASE_TOPIC, {'data': name}, int(time_ns))

    def write_trace(self, run, kind, results, context=None):
        """Write ``results`` under ``/qfa/trace/<run>`` (``run`` None: ``/qfa/trace``)."""
        namespace = '/qfa/trace' if run is None else f'/qfa/trace/{run}'
        trace = TraceWriter.in_bag(self.bag, namespace)
        write_results(trace, kind, results, context)


def origin_fix(time_ns, frame_id, latitude_deg, longitude_deg, height_m):
    """Return the sensor_msgs/NavSatFix mapping of a truth origin (exact, a fix)."""
    return {'header': {'stamp': stamp(int(time_ns)), 'frame_id': frame_id},
            'status': {'status': NAVSAT_STATUS_FIX, 'service': 0},
            'latitude': float(latitude_deg), 'longitude': float(longitude_deg),
            'altitude': float(height_m), 'position_covariance': [0.0] * 9,
            'position_covariance_type': NAVSAT_COVARIANCE_TYPE_KNOWN}
