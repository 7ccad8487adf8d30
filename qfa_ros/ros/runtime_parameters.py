"""
The node's parameters at run time: declared from the table, checked and applied on change.

Every parameter of :data:`~qfa_ros.ros.params.PARAMETERS` is declared with its
``ParameterDescriptor``; a change is accepted only if the whole set stays consistent and is
then applied to the running sensor through one step per runtime effect
(:data:`~qfa_ros.ros.params.RUNTIME_EFFECTS`).
"""

import collections

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, ParameterException

from qfa_ros.model.triad import AXES
from qfa_ros.model.units import PPM
from qfa_ros.ros.params import (
    ambient_settings,
    as_declared_type,
    check_all,
    descriptor,
    EFFECT_OF,
    FEEDBACK_COMPONENT,
    FORWARD_COMPONENT,
    input_profile,
    PARAMETERS,
    RUNTIME_EFFECTS,
    THERMAL_RUNTIME_PARAMETERS,
)


def declare_parameters(node, read_only=True, refused=None):
    """
    Declare every parameter of the table on ``node``; return their start values by name.

    :param read_only: False declares every parameter writable (the managed node refuses a
        change of a read-only one itself, except in its unconfigured state).
    :param refused: None, or a dict: a start value rclpy refuses (type, range) is then
        recorded there (name: reason) and the parameter declared with its default, instead
        of raising.
    :raises ValueError: A start value has the wrong type; the message names the parameter.
    """
    # Integers typed for doubles ([1, 2, 3], 2000) become doubles: in every change
    # (pre-set callback) and at start, where declaration runs no pre-set callback.
    node.add_pre_set_parameters_callback(
        lambda parameters: [as_declared_type(p) for p in parameters])
    for spec in PARAMETERS:
        declared = descriptor(spec)
        declared.read_only = declared.read_only and read_only
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
    Check each parameter change and apply the accepted ones to the running sensor.

    Registers the node's set-parameters and post-set-parameters callbacks.

    :param node: The node (callbacks, logger).
    :param lock: The node lock (the model, the stream and the values are changed under it).
    :param values: The node's live parameter values: written here only, under ``lock``.
    :param trajectory_file: The trajectory file read at start, or None.
    :param triad: The model.
    :param stream: :class:`~qfa_ros.ros.stream.SampleStream`.
    :param recording: :class:`~qfa_ros.ros.recording.StreamRecording`.
    :param schedules: :class:`~qfa_ros.ros.schedules.ScheduleService` (busy, last error).
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
        # The step that applies each runtime effect of params.RUNTIME_EFFECTS, and how
        # often each ran (read by the tests; under the node lock).
        self.steps = {
            'live': lambda: None, 'drift': lambda: apply_drift(triad, values),
            'input': self._apply_input, 'frame': self._apply_frame_id,
            'ambient': lambda: apply_ambient(triad, values),
            'recorder': self._restart_recording}
        self.applied = collections.Counter()
        node.add_on_set_parameters_callback(self.validate_callback)
        node.add_post_set_parameters_callback(self.apply_callback)

    def validate_callback(self, parameters):
        """Accept a parameter change only if the whole set stays consistent."""
        try:
            merged = dict(self._values)
            for parameter in parameters:
                merged[parameter.name] = parameter.value
            reason = check_all(merged, self._trajectory_file)
            names = {parameter.name for parameter in parameters}
            if not reason and self._schedules.busy_kind == 'temperature' \
                    and names & THERMAL_RUNTIME_PARAMETERS:
                reason = 'busy: the temperature calibration controls the ambient until it ends'
        except Exception as error:
            # A parameter callback must never raise: it would kill the set_parameters call.
            reason = f'cannot check the change: {error}'
        if reason:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def apply_callback(self, parameters):
        """Apply accepted parameter changes to the running sensor at once."""
        names = {parameter.name for parameter in parameters}
        # One step per effect, each once, in the order of params.RUNTIME_EFFECTS.
        wanted = {EFFECT_OF[name] for name in names}
        effects = [effect for effect in RUNTIME_EFFECTS if effect in wanted]
        with self._lock:
            for parameter in parameters:
                self._values[parameter.name] = parameter.value
            try:
                for effect in effects:
                    self.steps[effect]()
                    self.applied[effect] += 1
            except (ValueError, OSError) as error:
                self._schedules.last_error = f'applying {", ".join(sorted(names))}: {error}'
                self._node.get_logger().error(self._schedules.last_error)

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
