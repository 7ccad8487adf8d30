"""The node's calibration services: each one starts a schedule or switches the corrections."""

from rclpy.callback_groups import ReentrantCallbackGroup
from std_srvs.srv import SetBool, Trigger

from qfa_ros.calibration.estimation import (
    capture_reference,
    feedback_schedule,
    forward_schedule,
    self_calibrate,
)
from qfa_ros.calibration.gyro_bias import gyro_bias_schedule
from qfa_ros.calibration.temperature import temperature_calibration
from qfa_ros.ros.model_settings import gyro_bias_settings, temperature_settings


class CalibrationServices:
    """
    Serve the calibration services of the node and the cancellation of their schedules.

    ``~/capture_reference``, ``~/estimate_forward_gain``, ``~/estimate_feedback_gain``,
    ``~/self_calibrate``, ``~/calibrate_temperature``, ``~/calibrate_gyros``,
    ``~/set_compensation`` and ``~/cancel``. The schedule services await the schedule the
    sensor thread drives (:class:`~qfa_ros.ros.schedules.ScheduleService`); they answer
    once it has ended.

    :param node: The node (services, guard condition, logger).
    :param lock: The node lock (the model, the stream and the calibration state are used
        under it).
    :param values: The node's live parameter values (read, never written).
    :param schedules: :class:`~qfa_ros.ros.schedules.ScheduleService`.
    :param keeper: :class:`~qfa_ros.ros.calibration_keeper.CalibrationKeeper`.
    :param truth: :class:`~qfa_ros.ros.truth.TruthPublisher` (marks applied corrections).
    :param publish_calibrated: Callable publishing ``~/is_calibrated``.
    """

    def __init__(self, node, lock, values, schedules, keeper, truth, publish_calibrated):
        self._node = node
        self._lock = lock  # the node lock: the calibration state and the sensor words
        self._values = values
        self._schedules = schedules
        self._keeper = keeper
        self._truth = truth
        self._publish_calibrated = publish_calibrated
        # A schedule service awaits the schedule the sensor thread drives. In the default
        # mutually exclusive group the pending coroutine would keep the other services
        # from answering 'busy'; the reentrant group lets them run meanwhile.
        group = ReentrantCallbackGroup()
        for srv_type, name, callback in (
                (Trigger, '~/capture_reference', self.capture_reference_callback),
                (Trigger, '~/estimate_forward_gain', self.estimate_forward_gain_callback),
                (Trigger, '~/estimate_feedback_gain', self.estimate_feedback_gain_callback),
                (Trigger, '~/self_calibrate', self.self_calibrate_callback),
                (Trigger, '~/calibrate_temperature', self.calibrate_temperature_callback),
                (Trigger, '~/calibrate_gyros', self.calibrate_gyros_callback),
                (SetBool, '~/set_compensation', self.set_compensation_callback),
                (Trigger, '~/cancel', self.cancel_callback)):
            node.create_service(srv_type, name, callback, callback_group=group)
        # Triggered by the sensor thread when a schedule ends, so that the executor wakes
        # and resumes the service coroutine awaiting it.
        self.schedule_done = node.create_guard_condition(self.schedule_done_callback)

    async def capture_reference_callback(self, request, response):
        """Measure and persist the forward and feedback reference gains."""
        keeper = self._keeper
        return await self._schedules.run(response, 'reference', lambda f, b: capture_reference(
            keeper.triad, keeper.state, f, b))

    async def estimate_forward_gain_callback(self, request, response):
        """Run the forward schedule and apply the correction in place."""
        keeper = self._keeper
        return await self._schedules.run(response, 'forward', lambda f, b: forward_schedule(
            keeper.triad, keeper.state, f))

    async def estimate_feedback_gain_callback(self, request, response):
        """Run the feedback schedule and apply the correction in place."""
        keeper = self._keeper
        return await self._schedules.run(response, 'feedback', lambda f, b: feedback_schedule(
            keeper.triad, keeper.state, b))

    async def self_calibrate_callback(self, request, response):
        """Run the forward, then the feedback schedule and apply both corrections."""
        keeper = self._keeper
        return await self._schedules.run(response, 'self_calibrate', lambda f, b: self_calibrate(
            keeper.triad, keeper.state, f, b))

    async def calibrate_temperature_callback(self, request, response):
        """
        Run an accelerated chamber cycle, fit bias and scale factor, switch compensation on.

        With ``temperature_calibration.reference_steps`` the I_ref step is measured at every
        plateau and its temperature coefficient stored in the calibration state.
        """
        keeper = self._keeper
        return await self._schedules.run(
            response, 'temperature', lambda f, b: temperature_calibration(
                keeper.triad, keeper.state, temperature_settings(self._values)),
            fast=True)

    async def calibrate_gyros_callback(self, request, response):
        """Average the gyros at rest, remove the Earth rate and correct their bias."""
        keeper = self._keeper
        return await self._schedules.run(
            response, 'gyro_bias', lambda f, b: gyro_bias_schedule(
                keeper.triad, keeper.state, gyro_bias_settings(self._values)))

    def set_compensation_callback(self, request, response):
        """Apply (true) the stored corrections or restore the nominal words (false)."""
        busy = self._schedules.busy_answer()
        if busy:
            response.success, response.message = False, busy
            return response
        with self._lock:
            response.success, response.message = self._keeper.set_compensation(request.data)
            self._truth.mark('set_compensation')
        if response.success:
            problem = self._keeper.save()
            if problem:
                response.success = False
                response.message += f'; {problem}'
            self._publish_calibrated()
        return response

    def cancel_callback(self, request, response):
        """Abort the running schedule, restore the sensor and let the stream resume."""
        if self._schedules.refusal is not None:
            response.success, response.message = False, self._schedules.refusal
            return response
        with self._lock:
            try:
                response.success, response.message = self._schedules.cancel()
            except Exception as error:
                # Restoring a word the model refuses: say so instead of killing the call.
                response.success, response.message = False, f'cancel failed: {error}'
        self._node.get_logger().info(f'~/cancel: {response.message}')
        return response

    def schedule_done_callback(self):
        """Do nothing: the wake-up itself lets the executor resume the service coroutine."""
