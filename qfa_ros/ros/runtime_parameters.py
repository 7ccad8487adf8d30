"""
The node's parameters at run time: declared from the table, checked and applied on change.

Every parameter of :data:`~qfa_ros.ros.parameter_table.PARAMETERS` is declared with its
``ParameterDescriptor``; a change is accepted only if the whole set stays consistent and
its effect on the running sensor (one step per runtime effect,
:data:`~qfa_ros.ros.parameter_table.RUNTIME_EFFECTS`) has run.
"""

import collections

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, ParameterException

from qfa_ros.model.constants import PPM
from qfa_ros.model.triad import AXES
from qfa_ros.ros.model_settings import ambient_settings, input_profile
from qfa_ros.ros.parameter_checks import as_declared_type, check_all, descriptor
from qfa_ros.ros.parameter_table import (
    EFFECT_OF,
    FEEDBACK_COMPONENT,
    FORWARD_COMPONENT,
    PARAMETERS,
    RUNTIME_EFFECTS,
    THERMAL_RUNTIME_PARAMETERS,
)


def declare_parameters(node, managed=False, refused=None):
    """
    Declare every parameter of the table on ``node``; return their start values by name.

    Parameters
    ----------
    managed
        Declare for the managed node: read-only only the operator's parameters (``access``
        :data:`~qfa_ros.ros.parameter_table.OPERATOR`); it refuses the others of the plain node's
        read-only ones itself from ``configure`` to ``cleanup``. Otherwise every parameter that is
        not writable at run time is read-only.
    refused
        None, or a dict: a start value rclpy refuses (type, range) is then recorded there (name:
        reason) and the parameter declared with its default, instead of raising.

    Raises
    ------
    ValueError
        A start value has the wrong type; the message names the parameter.
    """
    # Integers typed for doubles ([1, 2, 3], 2000) become doubles: in every change
    # (pre-set callback) and at start, where declaration runs no pre-set callback.
    node.add_pre_set_parameters_callback(
        lambda parameters: [as_declared_type(p) for p in parameters])
    for spec in PARAMETERS:
        declared = descriptor(spec)
        declared.read_only = not spec.writable(configured=not managed)
        try:
            try:
                node.declare_parameter(spec.name, spec.default, declared)
            except InvalidParameterTypeException:
                # Read the start value untyped; declare the double it means, if any.
                given = node.declare_parameter(spec.name, spec.default,
                                               ParameterDescriptor(dynamic_typing=True))
                typed = as_declared_type(given)
                node.undeclare_parameter(spec.name)
                if typed is given:
                    raise
                node.declare_parameter(spec.name, typed.value, declared, ignore_override=True)
        except ParameterException as error:
            if refused is None:
                raise ValueError(str(error)) from None
            refused[spec.name] = str(error)
            node.declare_parameter(spec.name, spec.default, declared, ignore_override=True)
    return {spec.name: node.get_parameter(spec.name).value for spec in PARAMETERS}


def apply_drift(triad, values):
    """Set the drift steps, aging rates and time acceleration of ``triad`` from ``values``."""
    drift = triad.drift
    for axis in range(len(AXES)):
        drift.set_step(axis, FORWARD_COMPONENT, values['drift.forward_ppm'][axis] * PPM)
        drift.set_step(axis, FEEDBACK_COMPONENT, values['drift.feedback_ppm'][axis] * PPM)
        drift.set_aging(axis, FORWARD_COMPONENT,
                        values['drift.aging_forward_ppm_per_year'][axis])
        drift.set_aging(axis, FEEDBACK_COMPONENT,
                        values['drift.aging_feedback_ppm_per_year'][axis])
    drift.set_time_acceleration(values['drift.time_acceleration'])


def apply_ambient(triad, values):
    """Set the ambient of the thermal model (or the fixed temperature without one)."""
    if triad.thermal is None:
        triad.set_temperature(values['temperature_c'])
    else:
        triad.thermal.set_ambient(**ambient_settings(values))


class RuntimeParameters:
    """
    Check each parameter change, apply it to the running sensor, and only then accept it.

    Registers the node's set-parameters callback: a change is accepted once the whole set
    is consistent and the step of each runtime effect it has (:data:`RUNTIME_EFFECTS`) has
    run. A step that fails (the recording cannot start in the new directory, a value the
    model refuses, any unexpected exception) refuses the change with the reason, puts the
    old values back and runs the steps again with them, so the parameter and the sensor
    stay as they were; the node goes on either way.

    Parameters
    ----------
    node
        The node (callback, logger).
    lock
        The node lock (the model, the stream and the values are changed under it).
    values
        The node's live parameter values: written here only, under ``lock``.
    trajectory_file
        The trajectory file read at start, or None.
    triad
        The model.
    stream
        :class:`~qfa_ros.ros.stream.SampleStream`.
    recording
        :class:`~qfa_ros.ros.recording.StreamRecording`.
    schedules
        :class:`~qfa_ros.ros.schedule_service.ScheduleService` (busy, last error).
    """

    def __init__(self, node, lock, values, trajectory_file, triad, stream, recording,
                 schedules):
        self._node = node
        self._lock = lock  # the node lock: the live values and the model they drive
        self._values = values
        self._trajectory_file = trajectory_file
        self._triad = triad
        self._stream = stream
        self._recording = recording
        self._schedules = schedules
        # The step that applies each runtime effect of parameter_table.RUNTIME_EFFECTS, and how
        # often each ran for an accepted change (read by the tests; under the node lock).
        self.steps = {
            'live': lambda: None, 'drift': lambda: apply_drift(triad, values),
            'input': self._apply_input, 'frame': self._apply_frame_id,
            'ambient': lambda: apply_ambient(triad, values),
            'recorder': self._restart_recording}
        self.applied = collections.Counter()
        # rclpy runs the set-parameters callbacks last added first, and stores the values
        # once all accepted: this one applies the change, so it must be the last to run
        # (the first added).
        node.add_on_set_parameters_callback(self.set_callback)

    def set_callback(self, parameters):
        """Accept a parameter change only if the whole set stays consistent and it applies."""
        names = sorted({parameter.name for parameter in parameters})
        try:
            merged = dict(self._values)
            for parameter in parameters:
                merged[parameter.name] = parameter.value
            reason = check_all(merged, self._trajectory_file)
            if not reason and self._schedules.busy_kind == 'temperature' \
                    and THERMAL_RUNTIME_PARAMETERS.intersection(names):
                reason = 'busy: the temperature calibration controls the ambient until it ends'
            if not reason:
                reason = self._apply({name: merged[name] for name in names})
        except Exception as error:
            # A parameter callback must never raise: it would end the set_parameters call
            # (and the executor with it).
            reason = f'cannot check the change of {", ".join(names)}: {type(error).__name__}'
            self._node.get_logger().error(f'{reason}: {error}')
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply(self, changes):
        """Apply ``changes`` (name: value) to the sensor; return why they were undone, or None."""
        wanted = {EFFECT_OF[name] for name in changes}
        # One step per effect, each once, in the order of parameter_table.RUNTIME_EFFECTS.
        effects = [effect for effect in RUNTIME_EFFECTS if effect in wanted]
        with self._lock:
            old = {name: self._values[name] for name in changes}
            self._values.update(changes)
            ran = []
            try:
                for effect in effects:
                    ran.append(effect)  # a step that fails half-way is undone too
                    self.steps[effect]()
            except Exception as error:
                self._values.update(old)
                detail = str(error) if isinstance(error, (ValueError, OSError, EffectError)) \
                    else f'{type(error).__name__}: {error}'
                reason = f'{", ".join(changes)} not changed: applying it failed ({detail})'
                self._node.get_logger().error(reason + self._undo(ran))
                return reason
            for effect in effects:
                self.applied[effect] += 1
        return None

    def _undo(self, effects):
        """Run ``effects`` again with the restored values; return what could not be undone."""
        failed = []
        for effect in effects:
            try:
                self.steps[effect]()
            except Exception as error:
                failed.append(f'{effect} ({type(error).__name__}: {error})')
        if failed:
            self._schedules.last_error = 'a failed parameter change could not be undone: ' \
                + ', '.join(failed)
            return '; ' + self._schedules.last_error
        return '; old values restored'

    def _apply_frame_id(self):
        self._stream.set_frame_id(self._values['frame_id'])

    def _apply_input(self):
        self._triad.profile = input_profile(self._values, self._triad.time,
                                            self._trajectory_file)

    def _restart_recording(self):
        # What was published before the change goes to the recording it was in.
        with self._recording.lock:
            self._stream.flush_recording()
            self._recording.restart()
            if self._values['recorder.enabled'] and not self._recording.active:
                raise EffectError(self._recording.problem or 'the recording did not start')


class EffectError(Exception):
    """A runtime effect did not take: the message says why (no traceback needed)."""
