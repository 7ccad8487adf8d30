"""
The node's topics, as data: one row per publisher and subscription, with its QoS.

:data:`TOPICS` is the one table. The node creates its publishers and its input subscription
from it (:func:`create_publisher`, :func:`create_subscription`), the flight recording takes
their QoS from it, and the interface tables of ``docs/node.md`` and the README are
generated from it (:mod:`qfa_ros.ros.interface_docs`); ``test_node_truth.py`` compares it
with what a running node offers.
"""

from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import AccelStamped
from nav_msgs.msg import Odometry
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, NavSatFix, Temperature
from std_msgs.msg import Bool

from qfa_ros.bag.qos import QOS_LATCHED, QOS_TRUTH, QosProfile
from qfa_ros.ros.stream import ros_qos

PUBLISHER = 'pub'
SUBSCRIPTION = 'sub'

TRUTH_FRAME_ID = 'enu_origin'
"""Frame of ``truth/odometry``: the ENU tangent plane at ``truth/origin``."""

# REP-2003: a sensor driver offers the system-default (reliable) QoS; a depth of 100 lets
# a reliable subscriber be briefly late. Users override it the ROS way:
# qos_overrides./<namespace>/imu/data_raw.publisher.{history,depth,reliability}.
QOS_STREAM = QosProfile(depth=100)
"""QoS of ``imu/data_raw`` and ``imu/temperature`` before a user's overrides."""
QOS_EVENTS = QosProfile(depth=20, durability='transient_local')
"""QoS of ``~/calibration_events``: the last 20 events reach a late subscriber too."""
# Best effort matches reliable and best-effort publishers alike.
QOS_INPUT = QosProfile(depth=100, reliability='best_effort')
"""QoS of the ground-truth input subscription."""


@dataclass(frozen=True)
class TopicSpec:
    """
    One topic of the node.

    Parameters
    ----------
    name : str
        Topic name as the node creates it (``imu/data_raw``, ``~/is_calibrated``).
    direction : str
        :data:`PUBLISHER` or :data:`SUBSCRIPTION`.
    msg_type : type
        Message type (``sensor_msgs.msg.Imu``).
    qos : QosProfile
        Its QoS (:class:`~qfa_ros.bag.qos.QosProfile`: reliability, durability, history
        depth), as the node offers or requests it.
    doc : str
        What it carries, in one line (``docs/node.md``).
    rate : str
        The parameter that sets its rate, or how often it comes when no parameter does.
    frame : str
        The parameter that sets its ``header.frame_id``, the frame itself, or '' (no header).
    only_if : tuple or None
        ``(parameter, value)``: the node has it only with that value. None: always.
    overridable : bool
        Its QoS may be changed with ``qos_overrides`` parameters at start.
    """

    name: str
    direction: str
    msg_type: type
    qos: QosProfile
    doc: str
    rate: str = ''
    frame: str = ''
    only_if: tuple = None
    overridable: bool = False

    def __post_init__(self):
        if self.direction not in (PUBLISHER, SUBSCRIPTION):
            raise ValueError(f'{self.name}: direction must be {PUBLISHER!r} or '
                             f'{SUBSCRIPTION!r}, got {self.direction!r}')

    @property
    def type_name(self):
        """Return the message type as ROS names it (``sensor_msgs/msg/Imu``)."""
        return f'{self.msg_type.__module__.split(".")[0]}/msg/{self.msg_type.__name__}'

    def offered(self, values):
        """
        Return whether the node has this topic.

        Parameters
        ----------
        values : dict
            The node's parameter values (``only_if``'s parameter among them).

        Returns
        -------
        bool
            True without ``only_if``, or when its parameter has its value.
        """
        return self.only_if is None or values[self.only_if[0]] == self.only_if[1]


def _input(kind, msg_type, fields):
    return TopicSpec(
        f'input/{kind}', SUBSCRIPTION, msg_type, QOS_INPUT,
        f'ground truth for `input.mode: topic` ({fields}); a message stamped further than '
        '`input.stamp_window_s` from the node clock is refused', rate="the sender's",
        only_if=('input.topic_type', kind))


TRUTH = ('truth.enabled', True)

TOPICS = (
    TopicSpec(
        'imu/data_raw', PUBLISHER, Imu, QOS_STREAM,
        'REP-145 specific force [m/s²] and angular velocity [rad/s] (gyro triad; '
        '`gyro.enabled: false` marks it unknown, covariance[0] = -1); '
        '`orientation_covariance[0] = -1`; `angular_velocity_covariance` diagonal '
        '`N²/T + B² + (q/T)²/6` (`GyroTriad.variance`); `linear_acceleration_covariance` '
        'diagonal: the variance of one published sample of the white noise through the loop '
        'and the averaging decimator (`qfa_ros.model.design.published_acceleration_variance`;'
        ' the bias instability is not in it: '
        '[model](model.md#noise-and-the-published-covariance)); `header.stamp` = sample '
        'instant',
        rate='sample_rate_hz', frame='frame_id', overridable=True),
    TopicSpec(
        'imu/temperature', PUBLISHER, Temperature, QOS_STREAM,
        "the on-board temperature sensor's reading [°C] (its noise and 16-bit ADC steps "
        'included), stamped with the instant of the sample it belongs to; `variance` is the '
        "reading's (≈ 4e-4 °C²); without the thermal model the constant `temperature_c` "
        'with variance 0', rate='temperature_rate_hz', frame='frame_id', overridable=True),
    TopicSpec(
        '/diagnostics', PUBLISHER, DiagnosticArray, QosProfile(depth=10),
        'four statuses: stream, calibration, temperature, input (below)',
        rate='diagnostics_rate_hz'),
    TopicSpec(
        '~/is_calibrated', PUBLISHER, Bool, QOS_LATCHED,
        'true when references are captured and the stored corrections are applied (latched, '
        'as phidgets_spatial)', rate='at start and on every change'),
    TopicSpec(
        '~/calibration_events', PUBLISHER, DiagnosticStatus, QOS_EVENTS,
        "one per correction applied in place (a schedule's result, `~/set_compensation`): "
        "its kind (the service's, in the services table), first stamp, the stamp from which "
        "the output has settled and the transient's size, the steps of scale factor and bias "
        'per axis (`docs/ins.md`)', rate='one per correction'),
    TopicSpec(
        'truth/odometry', PUBLISHER, Odometry, QOS_TRUTH,
        'the true pose in the ENU tangent plane `enu_origin` (child frame `frame_id`), '
        'stamped as the stream sample it belongs to, while `input.mode` is static or '
        'trajectory (`docs/ins.md`)', rate='truth.rate_hz', frame=TRUTH_FRAME_ID,
        only_if=TRUTH),
    TopicSpec(
        'truth/origin', PUBLISHER, NavSatFix, QOS_LATCHED,
        'the geodetic origin of `enu_origin`, while `input.mode` is static or trajectory',
        rate='at start and whenever the input changes',
        frame=TRUTH_FRAME_ID, only_if=TRUTH),
    TopicSpec(
        'truth/imu_errors', PUBLISHER, Imu, QOS_TRUTH,
        'the errors the model holds (bias in `linear_acceleration` / `angular_velocity`, '
        'scale factor and misalignment in the covariance fields; layout in `docs/ins.md`)',
        rate='truth.rate_hz', frame='frame_id', only_if=TRUTH),
    _input('imu', Imu, '`linear_acceleration`, `angular_velocity`'),
    _input('accel', AccelStamped, '`accel.linear`'),
    _input('odometry', Odometry, 'pose, twist'),
)
"""Every topic of the node, in the order the docs list them."""

TOPIC = {spec.name: spec for spec in TOPICS}
"""The rows of :data:`TOPICS` by topic name."""


def create_publisher(node, name):
    """
    Create the publisher of the row ``name`` of :data:`TOPICS` on ``node``.

    Parameters
    ----------
    node : rclpy.node.Node
        The node (a managed node makes it a lifecycle publisher).
    name : str
        The topic's row.

    Returns
    -------
    rclpy.publisher.Publisher
        The publisher, with the row's QoS (and its ``qos_overrides`` parameters when the
        row is overridable).
    """
    spec = TOPIC[name]
    options = {}
    if spec.overridable:
        options['qos_overriding_options'] = QoSOverridingOptions.with_default_policies()
    return node.create_publisher(spec.msg_type, spec.name, ros_qos(spec.qos), **options)


def create_subscription(node, name, callback):
    """
    Create the subscription of the row ``name`` of :data:`TOPICS` on ``node``.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    name : str
        The topic's row.
    callback : callable
        Called with each message.

    Returns
    -------
    rclpy.subscription.Subscription
        The subscription, with the row's QoS.
    """
    spec = TOPIC[name]
    return node.create_subscription(spec.msg_type, spec.name, callback, ros_qos(spec.qos))
