"""
How a parameter value is judged: rclpy descriptors, type conversion, one value, the whole set.

Each refusal names the parameter (or the family of parameters a rule spans) and the rule, and
quotes at most :data:`~qfa_ros.ros.parameter_table.MAX_SHOWN` characters of a value.
"""


from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from qfa_ros.model.checks import is_finite
from qfa_ros.ros.bounds import confined_directory, forward_sweep_problem
from qfa_ros.ros.model_settings import (
    feedback_settings,
    forward_settings,
    input_profile,
    temperature_settings,
    triad_config,
)
from qfa_ros.ros.parameter_table import (
    CONFINED,
    MAX_FRAME_ID_LENGTH,
    MAX_SHOWN,
    MAX_STRING_LENGTH,
    SPECS,
)
from qfa_ros.ros.service_table import budget_problem


def descriptor(spec):
    """
    Return the ``ParameterDescriptor`` of ``spec``.

    An array's element range goes into ``floating_point_range`` (rclpy enforces ranges
    on scalars only; :func:`check_value` checks the elements) and, with its length, into
    ``additional_constraints``: ``ros2 param describe`` shows both.
    """
    text = spec.description
    if spec.choices:
        text += f' (one of: {", ".join(spec.choices)})'
    result = ParameterDescriptor(description=text, read_only=spec.read_only)
    if spec.low is not None and isinstance(spec.default, int):
        result.integer_range = [IntegerRange(from_value=int(spec.low), to_value=int(spec.high),
                                             step=0)]
    elif spec.low is not None:
        result.floating_point_range = [FloatingPointRange(
            from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
    if isinstance(spec.default, list):
        length = (f'exactly {spec.length} elements' if spec.length
                  else f'1 to {spec.max_length} elements')
        bounds = f' in [{spec.low:g}, {spec.high:g}]' if spec.low is not None else ''
        result.additional_constraints = (f'{length}, each a finite number{bounds}; '
                                         'integers are accepted and stored as doubles')
    elif spec.choices:
        result.additional_constraints = f'one of: {", ".join(spec.choices)}'
    return result


def as_declared_type(parameter):
    """
    Return ``parameter`` with integers turned into doubles where the parameter is a double.

    Users type ``[1, 2, 3]`` or ``2000`` on the command line and in YAML files; ROS 2
    parameters are statically typed and would refuse them ("Wrong parameter type").
    Used as the node's pre-set callback and on the start-up overrides, so the stored
    value is always a double (array) and then validated like any other.

    Parameters
    ----------
    parameter
        An :class:`rclpy.parameter.Parameter`.
    """
    spec = SPECS.get(parameter.name)
    if spec is None or isinstance(spec.default, bool):
        return parameter
    if isinstance(spec.default, list) and parameter.type_ == Parameter.Type.INTEGER_ARRAY:
        return Parameter(parameter.name, Parameter.Type.DOUBLE_ARRAY,
                         [float(v) for v in parameter.value])
    if isinstance(spec.default, float) and parameter.type_ == Parameter.Type.INTEGER:
        return Parameter(parameter.name, Parameter.Type.DOUBLE, float(parameter.value))
    return parameter


def shown(value):
    """Return ``value`` as a refusal quotes it: its repr, at most :data:`MAX_SHOWN` characters."""
    if isinstance(value, str) and len(value) > MAX_SHOWN:
        value = value[:MAX_SHOWN]  # the repr of a stranger's megabyte is never built
    text = repr(value)
    return text if len(text) <= MAX_SHOWN else text[:MAX_SHOWN - 3] + '...'


def check_value(name, value):
    """
    Return why ``value`` is not acceptable for parameter ``name``, or None.

    The reason names the parameter and the rule; it quotes at most :data:`MAX_SHOWN`
    characters of a scalar value and never an array (sizes are checked before anything
    else is looked at).
    """
    spec = SPECS.get(name)
    if spec is None:
        return f'{shown(name)}: unknown parameter'
    default = spec.default
    if isinstance(default, list):
        return _check_array(spec, value)
    if isinstance(default, str):
        return _check_string(spec, value)
    if isinstance(default, bool):
        return None if isinstance(value, bool) else f'{name} must be true or false'
    return _check_number(name, value, spec, integer=isinstance(default, int))


def _check_number(label, value, spec, integer=False):
    """Return why ``value`` (``label``: a parameter or an element) is no ``spec`` number."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'{label} must be a number'
    if not integer and not is_finite(value):
        return f'{label} must be finite, got {shown(value)}'
    if integer and not isinstance(value, int):
        return f'{label} must be an integer'
    if spec.low is not None and not spec.low <= value <= spec.high:
        return f'{label} must be in [{spec.low:g}, {spec.high:g}], got {shown(value)}'
    return None


def check_alone(name, value, output_dir):
    """
    Return why ``value`` is not acceptable for ``name`` on its own, or None.

    What can be judged without the rest of the set: :func:`check_value`, and a directory
    confined to ``output_dir`` (:data:`~qfa_ros.ros.parameter_table.CONFINED`). A managed
    node judges each change so while unconfigured; ``configure`` checks the whole set.
    """
    reason = check_value(name, value)
    if reason or name not in CONFINED:
        return reason
    try:
        confined_directory({'output_dir': output_dir, name: value}, name)
    except (ValueError, OSError) as error:
        # OSError: a symlink loop or an unreadable component while resolving a directory.
        return str(error)
    return None


def _check_string(spec, value):
    """Return why ``value`` is not acceptable for the string parameter ``spec``, or None."""
    name = spec.name
    if not isinstance(value, str):
        return f'{name} must be a string'
    limit = MAX_FRAME_ID_LENGTH if name == 'frame_id' else MAX_STRING_LENGTH
    if len(value) > limit:
        return f'{name} must be at most {limit} characters, got {len(value)}'
    if not value.isprintable():
        return f'{name} must be printable text (no control characters)'
    if spec.choices is not None and value not in spec.choices:
        return f'{name} must be one of {", ".join(spec.choices)}, got {shown(value)}'
    if name == 'frame_id' and not value:
        return 'frame_id must not be empty'
    return None


def _check_array(spec, value):
    """Return why ``value`` is not acceptable for the array parameter ``spec``, or None."""
    name = spec.name
    if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
        return f'{name} must be an array of numbers'
    if spec.length is not None and len(value) != spec.length:
        return f'{name} must have exactly {spec.length} elements, got {len(value)}'
    if spec.max_length is not None and len(value) > spec.max_length:
        return f'{name} must have at most {spec.max_length} elements, got {len(value)}'
    if not len(value):
        return f'{name} must not be empty'
    for index, element in enumerate(value):
        reason = _check_number(f'{name}[{index}]', element, spec)
        if reason:
            return reason
    return None


def check_all(values, trajectory_file=None, imu_noise=None):
    """
    Return why the parameter set ``values`` is inconsistent, or None.

    Reads no file: ``trajectory_file`` is what :func:`load_trajectory_file` read at start,
    ``imu_noise`` what :func:`load_imu_noise` read.
    """
    for name, value in values.items():
        reason = check_value(name, value)
        if reason:
            return reason
    if values['stream.batch_s'] >= values['stream.lead_s']:
        return (f'stream.batch_s ({values["stream.batch_s"]:g}) must be shorter than '
                f'stream.lead_s ({values["stream.lead_s"]:g})')
    try:
        config = triad_config(values, imu_noise=imu_noise)
        forward = forward_settings(values)
        problem = forward_sweep_problem(forward, config.hardware, values['drift.forward_ppm'])
        if problem:
            return problem
        # Built for the reasons their checks give; the budget below takes the values.
        feedback_settings(values)
        temperature_settings(values)
        input_profile(values, trajectory_file=trajectory_file)
        if not values['output_dir']:
            return 'output_dir must not be empty'
        for name in CONFINED:
            confined_directory(values, name)
    except (ValueError, OSError) as error:
        # OSError: a symlink loop or an unreadable component while resolving a directory.
        return str(error)
    return budget_problem(values)
