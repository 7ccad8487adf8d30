"""The node's calibration services, one per row of the services table."""

import functools

from rclpy.callback_groups import ReentrantCallbackGroup

from qfa_ros.ros.service_table import SERVICES


class CalibrationServices:
    """
    Serve the services of :data:`~qfa_ros.ros.service_table.SERVICES`.

    A row with a schedule is served by :meth:`ScheduleService.run
    <qfa_ros.ros.schedule_service.ScheduleService.run>`, which awaits the schedule the sensor
    thread drives and answers once it has ended; a row with a handler by the method of that name
    (:meth:`set_compensation`, :meth:`cancel`).

    Parameters
    ----------
    node : rclpy.node.Node
        The node (services, guard condition, logger).
    lock : threading.Lock
        The node lock (the model, the stream and the calibration state are used under it).
    values : dict
        The node's live parameter values (read, never written).
    schedules : ScheduleService
        :class:`~qfa_ros.ros.schedule_service.ScheduleService`.
    keeper : CalibrationKeeper
        :class:`~qfa_ros.ros.calibration_keeper.CalibrationKeeper`.
    truth : TruthPublisher
        :class:`~qfa_ros.ros.truth.TruthPublisher` (marks applied corrections).
    publish_calibrated : callable
        Publishes ``~/is_calibrated``.
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
        for spec in SERVICES:
            if spec.schedule is None:
                callback = functools.partial(getattr(self, spec.handler), spec)
            else:
                callback = self._schedule_callback(spec)
            node.create_service(spec.srv_type, spec.name, callback, callback_group=group)
        # Triggered by the sensor thread when a schedule ends, so that the executor wakes
        # and resumes the service coroutine awaiting it.
        self.schedule_done = node.create_guard_condition(self.schedule_done_callback)

    def _schedule_callback(self, spec):
        """
        Return the service callback that runs the schedule of ``spec``.

        Parameters
        ----------
        spec : ServiceSpec
            The service's row.

        Returns
        -------
        callable
            A coroutine function ``(request, response)`` awaiting
            :meth:`~qfa_ros.ros.schedule_service.ScheduleService.run`.
        """
        async def run_schedule(request, response):
            return await self._schedules.run(response, spec)
        return run_schedule

    def set_compensation(self, spec, request, response):
        """
        Apply (true) the stored corrections or restore the nominal words (false).

        Parameters
        ----------
        spec : ServiceSpec
            Its row: the ``kind`` of the calibration event it marks.
        request : std_srvs.srv.SetBool.Request
            ``data``: true to apply, false to restore.
        response : std_srvs.srv.SetBool.Response
            The answer to fill.

        Returns
        -------
        std_srvs.srv.SetBool.Response
            ``response``, answered (``busy: ...`` while a schedule runs).
        """
        busy = self._schedules.busy_answer()
        if busy:
            response.success, response.message = False, busy
            return response
        with self._lock:
            response.success, response.message = self._keeper.set_compensation(request.data)
            self._truth.mark(spec.kind)
        if response.success:
            problem = self._keeper.save()
            if problem:
                response.success = False
                response.message += f'; {problem}'
            self._publish_calibrated()
        return response

    def cancel(self, spec, request, response):
        """
        Abort the running schedule, restore the sensor and let the stream resume.

        Parameters
        ----------
        spec : ServiceSpec
            Its row.
        request : std_srvs.srv.Trigger.Request
            Empty.
        response : std_srvs.srv.Trigger.Response
            The answer to fill.

        Returns
        -------
        std_srvs.srv.Trigger.Response
            ``response``, answered (``no schedule running`` when there is none).
        """
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
