"""Ground-truth input topic: one subscription, its messages queued for the model."""


from qfa_ros.model.triad import NS_PER_S
from qfa_ros.ros.topic_table import create_subscription


def input_time_ns(stamp, now_ns):
    """Return the header ``stamp`` in ns, or ``now_ns`` when the stamp is zero (unset)."""
    time_ns = stamp.sec * NS_PER_S + stamp.nanosec
    return time_ns if time_ns else now_ns


class InputSubscription:
    """
    Subscribe to the ground-truth topic ``input.topic_type`` names and queue its messages.

    ``input/imu`` (``sensor_msgs/Imu``), ``input/odometry`` (``nav_msgs/Odometry``) or
    ``input/accel`` (``geometry_msgs/AccelStamped``), with the QoS of its row in the topic
    table (:data:`~qfa_ros.ros.topic_table.TOPICS`). Each message
    is handed to the :class:`~qfa_ros.ros.input_queue.GroundTruthInput` under the node
    lock, then the stream is woken to compute the samples it makes due.

    Parameters
    ----------
    node
        The node (subscription, clock).
    lock
        The node lock (the input queue is shared with the sensor thread).
    values
        The node's live parameter values (``input.topic_type``; read only).
    ground_truth
        :class:`~qfa_ros.ros.input_queue.GroundTruthInput`.
    stream
        :class:`~qfa_ros.ros.stream.SampleStream` (woken by each input).
    """

    def __init__(self, node, lock, values, ground_truth, stream):
        self._node = node
        self._lock = lock  # the node lock: the input queue the sensor thread reads
        self._ground_truth = ground_truth
        self._stream = stream
        topic_type = values['input.topic_type']
        callbacks = {'imu': self.imu_callback, 'odometry': self.odometry_callback,
                     'accel': self.accel_callback}
        create_subscription(node, f'input/{topic_type}', callbacks[topic_type])

    def imu_callback(self, message):
        """Take the specific force (and angular rate, if given) of a ground-truth Imu."""
        rate = None
        if message.angular_velocity_covariance[0] != -1.0:
            w = message.angular_velocity
            rate = (w.x, w.y, w.z)
        self._accept(message.header.stamp, message.linear_acceleration, rate)

    def odometry_callback(self, message):
        """Take the specific force and rate implied by a ground-truth ``nav_msgs/Odometry``."""
        pose, twist = message.pose.pose, message.twist.twist
        now_ns = self._node.get_clock().now().nanoseconds
        with self._lock:
            self._ground_truth.accept_odometry(
                input_time_ns(message.header.stamp, now_ns),
                (pose.position.x, pose.position.y, pose.position.z),
                (pose.orientation.x, pose.orientation.y, pose.orientation.z,
                 pose.orientation.w),
                (twist.linear.x, twist.linear.y, twist.linear.z),
                (twist.angular.x, twist.angular.y, twist.angular.z), now_ns)
        self._stream.input_arrived()

    def accel_callback(self, message):
        """Take the specific force of a ground-truth ``geometry_msgs/AccelStamped``."""
        self._accept(message.header.stamp, message.accel.linear)

    def _accept(self, stamp, vector, rate=None):
        now_ns = self._node.get_clock().now().nanoseconds
        with self._lock:
            self._ground_truth.accept(input_time_ns(stamp, now_ns),
                                      (vector.x, vector.y, vector.z), rate, now_ns)
        self._stream.input_arrived()
