"""
The managed (REP-2004 lifecycle) variant of the node, ``qfa_lifecycle_node``.

:class:`QfaLifecycleNode` runs the same unit as :class:`~qfa_ros.ros.node.QfaNode` (one
wiring, :class:`~qfa_ros.ros.node.SensorWiring`), driven by the lifecycle transitions instead
of its construction:

``configure``
    the parameters checked as a whole, the trajectory and state files read, the model
    built, the unit's publishers (lifecycle publishers), services, timers and
    subscriptions created, the flight recording opened and the sensor thread started:
    the sensor runs, nothing is published. An invalid configuration answers FAILURE,
    logs why and leaves the node unconfigured.
``activate``
    publishing from the first sample stamped after the transition, on the sample grid
    the sensor has kept; diagnostics, truth and the calibration services live.
``deactivate``
    nothing published after the answer; a running schedule cancelled as ``~/cancel``
    does; the services answer ``success: false`` with why; the recording's current file
    finished; the model, its sensor time and calibration state run on.
``cleanup``, ``shutdown``, error processing
    the sensor thread stopped, the calibration state saved, the recording finished, the
    unit's entities removed (a ``cleanup`` whose state cannot be saved answers FAILURE
    and stays inactive, nothing lost).

A recording stopped by the free-space floor (``min_free_bytes``) is a fault the unit cannot
ride out: the node leaves its state with ERROR and ends, after error processing,
unconfigured. ``docs/node.md`` (*Managed bring-up*) has the transition table.
"""

from diagnostic_msgs.msg import DiagnosticStatus
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.msg import SetParametersResult
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.lifecycle import LifecycleNode, LifecyclePublisher, TransitionCallbackReturn

from qfa_ros.ros.node import SensorWiring
from qfa_ros.ros.parameter_checks import check_alone
from qfa_ros.ros.parameter_table import OPERATOR, PARAMETERS, SPECS
from qfa_ros.ros.runtime_parameters import declare_parameters

TRANSITION_CLOSE_TIMEOUT_S = 2.0
"""How long cleanup, shutdown and error processing wait for the sensor thread to stop
before the state and the recording are written without the node lock [s]."""

INACTIVE = ('inactive: the node is managed and not active; its services answer once it is '
            'activated (ros2 lifecycle set <node> activate)')
"""What a calibration service answers while the node is configured but not active."""

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
ERROR = TransitionCallbackReturn.ERROR


def answer_unavailable_transitions(node):
    """
    Make ``~/change_state`` answer ``success: false`` to a transition the state does not have.

    rclpy 7 (Jazzy) lets the ``RCLError`` of an unavailable transition (``activate`` while
    unconfigured) out of the service callback, which ends the spin loop and the process;
    rclpy 9 (Kilted) answers ``success: false`` itself, and this wrapper never sees one.
    """
    for service in node.services:
        if service.srv_type is not ChangeState:
            continue
        callback = service.callback

        def answer(request, response, callback=callback):
            try:
                return callback(request, response)
            except rclpy_implementation.RCLError:
                node.get_logger().error(
                    f'change_state: transition {request.transition.label or request.transition.id}'
                    ' is not available in the present state')
                response.success = False
                return response
        service.callback = answer


def _destroyers(node):
    """Return ``(entities of the node, how to destroy one)`` pairs, kind by kind."""
    def destroy_publisher(publisher):
        if isinstance(publisher, LifecyclePublisher):
            return node.destroy_lifecycle_publisher(publisher)
        return node.destroy_publisher(publisher)
    return ((node.publishers, destroy_publisher),
            (node.subscriptions, node.destroy_subscription),
            (node.services, node.destroy_service), (node.clients, node.destroy_client),
            (node.timers, node.destroy_timer), (node.guards, node.destroy_guard_condition))


class QfaLifecycleNode(SensorWiring, LifecycleNode):
    """
    The emulated IMU as a managed node: the unit wired at ``configure``, published while active.

    Its parameters are declared at construction; who may set each, and when, is the table's
    (:data:`~qfa_ros.ros.parameter_table.PARAMETERS`, ``access``): the operator's alone
    (files, directories, rates, resources) are read-only in every state, as in the plain
    node; the sensor's own settings are writable while unconfigured, each change judged on
    its own (range, size, a directory confined to ``output_dir``) and ``configure`` checking
    the whole set; from ``configure`` to ``cleanup`` the plain node's read-only ones are
    refused. A start value rclpy refuses (type, range) does not stop the process:
    ``configure`` answers FAILURE naming it until it is set (an operator's one: until the
    node is started again with a valid one).

    Parameters
    ----------
    node_name
        Node name.
    process_tuning
        The process's interpreter settings (see :class:`~qfa_ros.ros.stream.SampleStream`); its
        ``released()`` is called when a unit is removed, so that the next ``configure`` freezes its
        own start-up objects.
    kwargs
        Passed to :class:`rclpy.lifecycle.LifecycleNode`.
    """

    _publishers_managed = False
    """Whether :meth:`create_publisher` makes lifecycle publishers (not during rclpy's set-up)."""

    def __init__(self, node_name='qfa_node', *, process_tuning=None, **kwargs):
        super().__init__(node_name, **kwargs)
        self._publishers_managed = True
        self._process_tuning = process_tuning
        # Start values rclpy refused at declaration (name: reason); set, they are forgotten.
        self._refused = {}
        self._start_values = declare_parameters(self, managed=True, refused=self._refused)
        self.add_on_set_parameters_callback(self._check_by_state)
        self.add_post_set_parameters_callback(self._forget_refused)
        # The unit's entities by kind (what wire_sensor created), or None while unconfigured;
        # the node attributes wire_sensor set; its parameter checks. Executor thread only, as
        # is _active.
        self._unit_entities = None
        self._unit_attributes = ()
        # Whether a configure's StartupRecovery looked everywhere: what an earlier run of
        # the node left unfinished is recovered once per process, not at every configure
        # (each look stats every bag directory: O(recordings) per cycle, and what it
        # allocated kept the process growing over a thousand cycles).
        self._recovered = False
        self._parameter_changes = None
        self._active = False
        # A fault the unit cannot ride out (any thread sets it), handled on the executor.
        self._fault = None
        self._fault_guard = self.create_guard_condition(self._handle_fault)
        answer_unavailable_transitions(self)

    def create_publisher(self, *args, **kwargs):
        """Create a lifecycle publisher (publishing only while active), like rclcpp_lifecycle."""
        if not self._publishers_managed:
            # rclpy's own (/parameter_events) during construction.
            return super().create_publisher(*args, **kwargs)
        return self.create_lifecycle_publisher(*args, **kwargs)

    # Parameters -------------------------------------------------------------------------
    def _check_by_state(self, parameters):
        """
        Refuse what the state does not allow; judge each value on its own while unconfigured.

        The operator's parameters are read-only (rclpy refuses them before this callback);
        the others of the plain node's read-only ones are refused from ``configure`` to
        ``cleanup``. While unconfigured a change is judged alone (``check_alone``: the
        directories confined to ``output_dir`` as in the plain node); ``configure`` checks
        the whole set.
        """
        configured = self._unit_entities is not None
        for parameter in parameters:
            name = parameter.name
            spec = SPECS.get(name)
            if spec is None:
                continue  # rclpy's own (use_sim_time, qos_overrides...)
            if spec.access == OPERATOR:
                reason = (f'{name} is set by the operator only, at start (command line, '
                          'parameters file, launch file)')
            elif not spec.writable(configured):
                reason = (f'{name} is read-only while the node is configured: set it while '
                          'unconfigured (ros2 lifecycle set <node> cleanup first)')
            elif configured:
                reason = None  # the unit's own callback checks the whole set
            else:
                reason = check_alone(name, parameter.value,
                                     self.get_parameter('output_dir').value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _forget_refused(self, parameters):
        for parameter in parameters:
            self._refused.pop(parameter.name, None)

    # Transitions (executor thread; each logs what it did) -------------------------------
    def on_configure(self, state):
        """Check the parameters, read the files, build the model, start the sensor unpublished."""
        refused = '; '.join(
            f'start value of {name} refused: {reason}' + (
                f' ({name} is set by the operator only: start the node again with a valid '
                'one)' if SPECS[name].access == OPERATOR else '')
            for name, reason in self._refused.items())
        if refused:
            return self._refuse('configure', refused)
        values = {spec.name: self.get_parameter(spec.name).value for spec in PARAMETERS}
        before = [set(entities) for entities, _ in _destroyers(self)], set(vars(self))
        try:
            self.wire_sensor(values, self._process_tuning)
        except ValueError as error:
            self._keep_unit_entities(before)
            self._release_unit()
            return self._refuse('configure', str(error))
        except Exception as error:
            self._keep_unit_entities(before)
            return self._failed('configure', error)
        self._keep_unit_entities(before)
        # rclpy runs the set-parameters callbacks last added first and stops at the first
        # refusal: the state's rules (read-only while configured) must come before the
        # unit's callback, which applies the change (RuntimeParameters).
        self.remove_on_set_parameters_callback(self._check_by_state)
        self.add_on_set_parameters_callback(self._check_by_state)
        if self._recording.problem_level == DiagnosticStatus.ERROR:
            # The recorder could not start for lack of free space.
            problem = self._recording.problem
            self._release_unit()
            return self._refuse('configure', problem)
        self._recording.on_free_space_floor = self._fault_found
        self._schedules.refusal = INACTIVE
        self._diagnostics.timer.cancel()
        self._truth.timer.cancel()
        self._stream.publish_from_ns = None
        self._stream.start()
        for line in self._start_lines:
            self.get_logger().info(line)
        if not self._recovered:
            self._startup_recovery.start()
        self.get_logger().info('configure: done (inactive: the sensor runs, nothing is '
                               'published until activate)')
        return SUCCESS

    def on_activate(self, state):
        """Publish from the next sample on the grid; diagnostics, truth and services live."""
        result = super().on_activate(state)
        if result != SUCCESS:
            return result
        self._schedules.refusal = None
        self._stream.resume()
        self._diagnostics.timer.reset()
        self._truth.timer.reset()
        self.publish_calibrated()
        self._active = True
        self.get_logger().info(f'activate: publishing {self._values["sample_rate_hz"]:g} Hz on '
                               f'imu/data_raw from stamp {self._stream.publish_from_ns} on')
        return SUCCESS

    def on_deactivate(self, state):
        """Stop publishing at once; cancel a running schedule; finish the recording's file."""
        self._stop_publishing('deactivate', state)
        if self._fault is not None:
            return ERROR
        self.get_logger().info('deactivate: nothing published from now on (the sensor runs '
                               'on, its calibration state kept)')
        return SUCCESS

    def on_cleanup(self, state):
        """Save the state, stop the sensor, finish the recording, remove the unit."""
        with self._lock:
            problem = self._keeper.save() if self._keeper.unsaved else None
        if problem:
            # Nothing is lost: the state stays in the running unit until it can be saved.
            return self._refuse('cleanup', f'{problem}; the node stays inactive')
        self._release_unit()
        if self._fault is not None:
            return ERROR
        self.get_logger().info('cleanup: calibration state saved, recording finished, unit '
                               'removed (unconfigured)')
        return SUCCESS

    def on_shutdown(self, state):
        """Stop publishing, save the state, finish the recording, remove the unit."""
        if self._active:
            self._stop_publishing('shutdown', state)
        problem = self._release_unit()
        if problem:
            self.get_logger().error(f'shutdown: {problem}')
            return FAILURE
        self.get_logger().info(f'shutdown from {state.label}: finalized')
        return SUCCESS

    def on_error(self, state):
        """Stop publishing, save the state, finish the recording, remove the unit; log why."""
        fault, self._fault = self._fault, None
        cause = f'error processing (from {state.label}): {fault or "a transition failed"}'
        if self._unit_entities is None:
            self.get_logger().error(f'{cause}; nothing configured')
            return SUCCESS
        self.get_logger().error(f'{cause}; stopping publishing, saving the calibration '
                                'state, finishing the recording')
        if self._active:
            self._stop_publishing('error processing', state)
        problem = self._release_unit()
        if problem:
            self.get_logger().error(f'error processing: {problem}; finalized')
            return FAILURE
        self.get_logger().info('error processing: done (unconfigured: configure again once '
                               'the cause is gone)')
        return SUCCESS

    def finalize(self):
        """
        Run the ``shutdown`` transition unless finalized (the entry point, on a stop signal).

        Managers see it on ``~/transition_event`` like any other; call it on the executor's
        thread, with the executor not spinning.
        """
        try:
            self.trigger_shutdown()
        except rclpy_implementation.RCLError:
            pass  # finalized already

    # Faults -----------------------------------------------------------------------------
    def _fault_found(self, problem):
        """Note a fault the unit cannot ride out (any thread); the executor handles it."""
        self._fault = problem
        self._fault_guard.trigger()

    def _handle_fault(self):
        """Leave the present state with ERROR (guard condition, executor thread)."""
        if self._fault is None:
            return
        self.get_logger().error(f'fault: {self._fault}: the unit cannot ride it out')
        try:
            if self._active:
                self.trigger_deactivate()
            elif self._unit_entities is not None:
                self.trigger_cleanup()
        except rclpy_implementation.RCLError as error:
            # A transition already under way: it ends with ERROR on its own (_fault).
            self.get_logger().error(f'fault: no transition possible now ({error})')

    # Helpers ----------------------------------------------------------------------------
    def _refuse(self, transition, reason):
        self.get_logger().error(f'{transition} refused: {reason}')
        return FAILURE

    def _failed(self, transition, error):
        self.get_logger().error(f'{transition} failed: {type(error).__name__}: {error}')
        return ERROR

    def _keep_unit_entities(self, before):
        """Note what ``wire_sensor`` made: its entities by kind and the attributes it set."""
        entities, attributes = before
        self._unit_entities = [set(now) - known
                               for (now, _), known in zip(_destroyers(self), entities)]
        self._unit_attributes = set(vars(self)) - attributes

    def _stop_publishing(self, transition, state):
        """Publish nothing more; cancel a running schedule; record and finish the file."""
        self._active = False
        self._stream.pause()
        super().on_deactivate(state)
        self._diagnostics.timer.cancel()
        self._truth.timer.cancel()
        self._schedules.refusal = INACTIVE
        if self._schedules.busy_kind is not None:
            # Only then the node lock: the sensor thread holds it for each batch.
            with self._lock:
                try:
                    cancelled, message = self._schedules.cancel(
                        f'by the {transition} transition')
                except Exception as error:
                    cancelled, message = True, f'cancel failed: {error}'
            if cancelled:
                self.get_logger().warning(f'{transition}: {message}')
        self._stream.flush_recording()
        self._recording.split()

    def _release_unit(self):
        """Stop and remove the unit (idempotent); return why the state is not saved, or None."""
        if self._unit_entities is None:
            return None
        problem = None
        if self._stream is not None:  # else wire_sensor refused before it made anything
            self.close(TRANSITION_CLOSE_TIMEOUT_S)
            problem = self._keeper.problem if self._keeper.unsaved else None
        if self._parameter_changes is not None:
            self.remove_on_set_parameters_callback(self._parameter_changes.set_callback)
        for (_, destroy), entities in zip(_destroyers(self), self._unit_entities):
            for entity in entities:
                destroy(entity)
        recovery = getattr(self, '_startup_recovery', None)
        self._recovered = self._recovered or (recovery is not None and recovery.completed)
        # Nothing of the unit stays reachable from the node: its collaborators, which
        # reference each other, are garbage now (collected below in a process of its own,
        # else in the collector's time), not held until the next configure replaces them.
        for name in self._unit_attributes:
            delattr(self, name)
        self._unit_attributes = ()
        self._unit_entities = self._parameter_changes = None
        self._active = False
        if self._process_tuning is not None:
            self._process_tuning.released()
        # rclpy's callback group keeps a weak reference to every entity ever made in it
        # (rclpy 7 and 9): forget those of the units gone, or each cycle adds some.
        group = self.default_callback_group
        group.entities.difference_update([ref for ref in list(group.entities) if ref() is None])
        return problem
