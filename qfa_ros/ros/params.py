"""Parameters of the QFA node: declarations, validation and mapping onto the model."""

from contextlib import contextmanager
from dataclasses import dataclass
import math
import sys
import textwrap

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from qfa_ros.calibration.estimation import (
    FEEDBACK_ORDERS,
    FeedbackSettings,
    FORWARD_ORDERS,
    ForwardSettings,
)
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model.hardware import STANDARD_GRAVITY
from qfa_ros.model.noise import MICRO_G, NoiseConfig
from qfa_ros.model.profiles import SineProfile, StaticProfile, StepProfile, tumble_profile
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import QfaTriad, TriadConfig
from qfa_ros.model.unit import draw_unit

INPUT_MODES = ('static', 'profile', 'topic')
INPUT_PROFILES = ('sine', 'tumble', 'steps')
INPUT_TOPIC_TYPES = ('imu', 'accel')
RELIABILITIES = ('reliable', 'best_effort')
AMBIENT_PROFILES = ('constant', 'ramp', 'cycle', 'room')
THERMAL_BIAS_MODELS = ('double_exp', 'none')

FORWARD_COMPONENT = 'k_amp'
"""Drift component behind ``drift.forward_ppm``: the in-amp gain resistor (seed 1 §IV)."""

FEEDBACK_COMPONENT = 'k_vi'
"""Drift component behind ``drift.feedback_ppm``: the V/I sense resistor (seed 1 §IV)."""

_NOISE = NoiseConfig()
_FORWARD = ForwardSettings()
_FEEDBACK = FeedbackSettings()
_THERMAL = ThermalConfig()
_CHAMBER = TemperatureSettings()


@dataclass(frozen=True)
class ParameterSpec:
    """
    One node parameter.

    :param name: Parameter name.
    :param default: Default value; its Python type fixes the ROS parameter type.
    :param description: Human description with the unit.
    :param read_only: True where a runtime change makes no sense.
    :param low, high: Inclusive range of a scalar number (None: no range).
    :param choices: Allowed strings.
    :param length: Required length of an array (None: any, but non-empty).
    """

    name: str
    default: object
    description: str
    read_only: bool = False
    low: float = None
    high: float = None
    choices: tuple = None
    length: int = None


def _vector(name, default, description, read_only=False):
    return ParameterSpec(name, [float(v) for v in default], description, read_only, length=3)


PARAMETERS = (
    ParameterSpec('sample_rate_hz', 1000.0, 'Published sample rate [Hz]', True, 1.0, 10000.0),
    ParameterSpec('loop_rate_hz', 10000.0,
                  'Digital loop rate [Hz]; an integer multiple of sample_rate_hz', True,
                  1.0, 1.0e6),
    ParameterSpec('tick_rate_hz', 100.0,
                  'Rate at which the sensor thread runs the model and publishes every sample '
                  'due since its last tick [Hz]', True, 1.0, 10000.0),
    ParameterSpec('frame_id', 'imu_link', 'frame_id of imu/data_raw and imu/temperature'),
    ParameterSpec('seed', 1, 'Seed of every random number: same seed, same output', True,
                  0, 2 ** 31 - 1),
    ParameterSpec('hardware_id', 'qfa_triad', 'hardware_id of the diagnostic statuses', True),
    ParameterSpec('temperature_rate_hz', 10.0, 'Rate of imu/temperature [Hz]', True,
                  0.1, 1000.0),
    ParameterSpec('temperature_c', 25.0,
                  'Ambient temperature [degC]: the constant ambient, the centre of the room '
                  'wander, the start of the ramp (without the thermal model: the sensor '
                  'temperature)', False, -60.0, 125.0),
    ParameterSpec('thermal.enabled', True,
                  'Thermal model: body lag, on-board temperature sensor, zero bias and '
                  'scale-factor error versus temperature (seed 2)', True),
    ParameterSpec('thermal.ambient_profile', 'constant', 'Ambient temperature profile',
                  choices=AMBIENT_PROFILES),
    ParameterSpec('thermal.ramp_rate_c_per_s', _THERMAL.ramp_rate_c_per_s,
                  'Ramp rate of the ramp profile [degC/s], clipped to the cycle limits',
                  False, -10.0, 10.0),
    ParameterSpec('thermal.cycle_low_c', _THERMAL.cycle_low_c,
                  'Low limit of the cycle and the ramp [degC]', False, -60.0, 125.0),
    ParameterSpec('thermal.cycle_high_c', _THERMAL.cycle_high_c,
                  'High limit of the cycle and the ramp [degC]', False, -60.0, 125.0),
    ParameterSpec('thermal.cycle_period_s', _THERMAL.cycle_period_s,
                  'Period of the trapezoid cycle profile [s]', False, 1.0, 1.0e7),
    ParameterSpec('thermal.room_amplitude_c', _THERMAL.room_amplitude_c,
                  'Bound of the room profile wander around temperature_c [degC]', False,
                  0.0, 50.0),
    ParameterSpec('thermal.sensor_tau_s', _THERMAL.sensor_tau_s,
                  'Thermal time constant of the sensor body [s]', True, 1.0, 1.0e5),
    ParameterSpec('thermal.bias_model', _THERMAL.bias_model,
                  'Zero bias versus temperature: the double exponential of seed 2 eq. 1 or '
                  'none', True, choices=THERMAL_BIAS_MODELS),
    ParameterSpec('diagnostics_rate_hz', 1.0, 'Rate of /diagnostics [Hz]', True, 0.1, 10.0),
    ParameterSpec('qos.reliability', 'reliable',
                  'Reliability of imu/data_raw and imu/temperature', True,
                  choices=RELIABILITIES),
    ParameterSpec('qos.depth', 100, 'History depth of imu/data_raw and imu/temperature', True,
                  1, 100000),
    ParameterSpec('noise.density_ug_per_rthz', _NOISE.noise_density / MICRO_G,
                  'White acceleration noise density (velocity random walk) [ug/sqrt(Hz)]',
                  True, 0.0, 10000.0),
    ParameterSpec('noise.bias_instability_ug', _NOISE.bias_instability / MICRO_G,
                  'Bias instability, flicker floor of the Allan deviation [ug]', True,
                  0.0, 100000.0),
    ParameterSpec('noise.adc_counts', _NOISE.adc_noise, 'ADC input noise [count rms]', True,
                  0.0, 10000.0),
    ParameterSpec('unit.draw', True,
                  'Draw the sensor as one unit within the datasheet spreads (turn-on bias, '
                  'thermal curves, aging, K2, misalignment; qfa_ros.model.unit); false: the '
                  'nominal sensor (seed 2 default curves, no turn-on bias)', True),
    ParameterSpec('unit.seed', -1,
                  'Seed of the drawn unit: the same seed, the same unit; -1: the unit of seed',
                  True, -1, 2 ** 31 - 1),
    _vector('model.bias_ug', (0.0, 0.0, 0.0),
            "IEEE 1293 bias per axis x, y, z, added to the unit's [ug]", True),
    _vector('model.k2_ug_per_g2', (0.0, 0.0, 0.0),
            "IEEE 1293 second-order coefficient per axis, added to the unit's [ug/g^2]", True),
    ParameterSpec('model.misalignment_mrad', [0.0] * 9,
                  "Mounting misalignment / cross-coupling M added to the unit's, row-major "
                  '3x3 (each loop senses ((I + M) f)_i) [mrad]', True, length=9),
    _vector('drift.forward_ppm', (0.0, 0.0, 0.0),
            'Step drift of the forward gain (in-amp gain resistor) per axis [ppm]'),
    _vector('drift.feedback_ppm', (0.0, 0.0, 0.0),
            'Step drift of the feedback gain (V/I sense resistor) per axis [ppm]'),
    _vector('drift.aging_forward_ppm_per_year', (0.0, 0.0, 0.0),
            'Linear aging of the forward gain per axis [ppm/year of sensor time]'),
    _vector('drift.aging_feedback_ppm_per_year', (0.0, 0.0, 0.0),
            'Linear aging of the feedback gain per axis [ppm/year of sensor time]'),
    ParameterSpec('drift.time_acceleration', 1.0,
                  'Aging time-acceleration factor (3.15e7: a year per second)', False,
                  0.0, 1.0e12),
    ParameterSpec('input.mode', 'static',
                  'Input: static orientation, scripted profile, or ground-truth topic',
                  choices=INPUT_MODES),
    ParameterSpec('input.roll', 0.0, 'Static roll [rad] (also the topic fallback)', False,
                  -math.pi, math.pi),
    ParameterSpec('input.pitch', 0.0, 'Static pitch [rad] (also the topic fallback)', False,
                  -math.pi / 2, math.pi / 2),
    ParameterSpec('input.profile', 'sine', 'Scripted profile of input.mode profile',
                  choices=INPUT_PROFILES),
    ParameterSpec('input.sine.frequency_hz', 5.0, 'Sine vibration frequency [Hz]', False,
                  1.0e-3, 5000.0),
    _vector('input.sine.amplitude', (0.0, 0.0, 0.1 * STANDARD_GRAVITY),
            'Sine vibration amplitude per axis [m/s^2]'),
    _vector('input.sine.offset', (0.0, 0.0, STANDARD_GRAVITY),
            'Static specific force under the sine vibration per axis [m/s^2]'),
    ParameterSpec('input.tumble.dwell_s', 10.0, 'Dwell per tumble position [s]', False,
                  1.0e-3, 1.0e6),
    ParameterSpec('input.steps.times_s', [0.0, 10.0],
                  'Start of each step level in sensor time [s], increasing'),
    ParameterSpec('input.steps.levels', [0.0, 0.0, STANDARD_GRAVITY,
                                         STANDARD_GRAVITY, 0.0, 0.0],
                  'Step levels, x, y, z per entry of input.steps.times_s [m/s^2]'),
    ParameterSpec('input.topic_type', 'imu',
                  'Ground-truth message: imu (sensor_msgs/Imu on input/imu) or accel '
                  '(geometry_msgs/AccelStamped on input/accel)', True,
                  choices=INPUT_TOPIC_TYPES),
    ParameterSpec('input.timeout_s', 0.1,
                  'Ground-truth input older than this is stale: imu/data_raw pauses [s]',
                  False, 1.0e-3, 3600.0),
    ParameterSpec('estimation.realtime', True,
                  'true: a schedule takes its sensor time at the node clock; false: as fast '
                  'as the CPU allows'),
    ParameterSpec('estimation.forward.points', _FORWARD.points,
                  'Forward sweep steps n (N_FPGA + i dN0, i = 0..n)', False, 2, 1000),
    ParameterSpec('estimation.forward.step', _FORWARD.step,
                  'Forward sweep increment dN0 [count]', False, 1, 2 ** 14),
    ParameterSpec('estimation.forward.settle_s', _FORWARD.settle_s,
                  'Discarded time per forward point [s]', False, 0.0, 60.0),
    ParameterSpec('estimation.forward.average_s', _FORWARD.average_s,
                  'Averaged time per forward point [s]', False, 1.0e-3, 600.0),
    ParameterSpec('estimation.forward.order', _FORWARD.order, 'Forward sweep order',
                  choices=FORWARD_ORDERS),
    ParameterSpec('estimation.feedback.cycles', _FEEDBACK.cycles,
                  'I_ref on/off cycles (chopped: off-on-on-off quadruples)', False, 1, 10000),
    ParameterSpec('estimation.feedback.settle_s', _FEEDBACK.settle_s,
                  'Discarded time per I_ref segment [s]', False, 0.0, 60.0),
    ParameterSpec('estimation.feedback.average_s', _FEEDBACK.average_s,
                  'Averaged time per I_ref segment [s]', False, 1.0e-3, 600.0),
    ParameterSpec('estimation.feedback.order', _FEEDBACK.order, 'I_ref switching order',
                  choices=FEEDBACK_ORDERS),
    ParameterSpec('estimation.feedback.motion_limit_ug', _FEEDBACK.motion_limit / MICRO_G,
                  'Scatter of 10 ms means beyond the noise that counts as a moving input '
                  '[ug]', False, 1.0e-3, 1.0e6),
    ParameterSpec('estimation.feedback.reference_tc_ppm', _FEEDBACK.reference_tc_ppm,
                  'Temperature coefficient of I_ref for the co-regression [ppm/degC] '
                  '(0: the paper schedule)', False, -1.0e4, 1.0e4),
    ParameterSpec('temperature_calibration.low_c', _CHAMBER.low_c,
                  'Lowest chamber plateau of calibrate_temperature [degC]', False,
                  -60.0, 125.0),
    ParameterSpec('temperature_calibration.high_c', _CHAMBER.high_c,
                  'Highest chamber plateau of calibrate_temperature [degC]', False,
                  -60.0, 125.0),
    ParameterSpec('temperature_calibration.period_s', _CHAMBER.period_s,
                  'Chamber program of calibrate_temperature (all plateaus, six-position '
                  'tumble) in sensor time [s], plus the soaks at the extremes and back to the '
                  'starting temperature (always run as fast as the CPU allows)', False,
                  60.0, 1.0e6),
    ParameterSpec('temperature_calibration.cycles', _CHAMBER.cycles,
                  'Chamber programs of calibrate_temperature', False, 1, 100),
    ParameterSpec('temperature_calibration.m_bits', _CHAMBER.m_bits,
                  'Fraction bits M of the fixed-point CORDIC zero-bias compensator (seed 2: '
                  '16; the scale factor uses 24)', False,
                  8, 30),
    ParameterSpec('trace_dir', '~/.ros/qfa_ros/traces',
                  'Directory of the estimation traces (MCAP), created when needed'),
    ParameterSpec('state_file', '~/.ros/qfa_ros/calibration.json',
                  'Persisted calibration state (JSON); empty: keep it in memory only', True),
    ParameterSpec('recorder.enabled', False,
                  'Record imu/data_raw, imu/temperature and /diagnostics to MCAP'),
    ParameterSpec('recorder.directory', '~/.ros/qfa_ros/recordings',
                  'Directory of the flight recordings, created when needed'),
    ParameterSpec('recorder.max_bytes', 1 << 30,
                  'Start a new recording file before this size [bytes]; 0: no limit', False,
                  0, 2 ** 62),
    ParameterSpec('recorder.max_duration_s', 600.0,
                  'Start a new recording file after this long [s]; 0: no limit', False,
                  0.0, 1.0e7),
)

SPECS = {spec.name: spec for spec in PARAMETERS}

THERMAL_RUNTIME_PARAMETERS = frozenset({'temperature_c', 'thermal.ambient_profile',
                                        'thermal.ramp_rate_c_per_s', 'thermal.cycle_low_c',
                                        'thermal.cycle_high_c', 'thermal.cycle_period_s',
                                        'thermal.room_amplitude_c'})
"""Parameters that change the ambient of the running thermal model."""


def descriptor(spec):
    """Return the ``ParameterDescriptor`` of ``spec``."""
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
    return result


def check_value(name, value):
    """Return why ``value`` is not acceptable for parameter ``name``, or None."""
    spec = SPECS.get(name)
    if spec is None:
        return f'{name}: unknown parameter'
    if isinstance(spec.default, list):
        try:
            values = [float(v) for v in value]
        except (TypeError, ValueError):
            return f'{name} must be an array of numbers, got {value!r}'
        if spec.length is not None and len(values) != spec.length:
            return f'{name} must have exactly {spec.length} elements (x, y, z), ' \
                   f'got {len(values)}'
        if not values:
            return f'{name} must not be empty'
        if not all(math.isfinite(v) for v in values):
            return f'{name} must be finite, got {list(value)!r}'
        return None
    if isinstance(spec.default, float):
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            return f'{name} must be a number, got {value!r}'
        if not math.isfinite(value):
            return f'{name} must be finite, got {value!r}'
    if spec.low is not None and not spec.low <= value <= spec.high:
        return f'{name} must be in [{spec.low:g}, {spec.high:g}], got {value!r}'
    if spec.choices is not None and value not in spec.choices:
        return f'{name} must be one of {", ".join(spec.choices)}, got {value!r}'
    if name == 'frame_id' and not value:
        return 'frame_id must not be empty'
    return None


@contextmanager
def _named(prefix):
    """Prefix a model settings ``ValueError`` with the parameters it comes from."""
    try:
        yield
    except ValueError as error:
        raise ValueError(f'{prefix}: {error}') from None


def ambient_settings(values):
    """Return the :class:`ThermalConfig` ambient fields of ``temperature_c`` and ``thermal.*``."""
    limits = (values['thermal.cycle_low_c'], values['thermal.cycle_high_c'])
    return {'ambient_profile': values['thermal.ambient_profile'],
            'ambient_c': values['temperature_c'],
            'ramp_rate_c_per_s': values['thermal.ramp_rate_c_per_s'],
            'ramp_limits_c': limits, 'cycle_low_c': limits[0], 'cycle_high_c': limits[1],
            'cycle_period_s': values['thermal.cycle_period_s'],
            'room_amplitude_c': values['thermal.room_amplitude_c']}


def thermal_config(values):
    """Return the :class:`ThermalConfig` of ``thermal.*``, or None when it is disabled."""
    if not values['thermal.enabled']:
        return None
    with _named('thermal'):
        return ThermalConfig(**ambient_settings(values),
                             sensor_tau_s=values['thermal.sensor_tau_s'],
                             bias_model=values['thermal.bias_model'])


def temperature_settings(values):
    """Return the :class:`TemperatureSettings` of ``temperature_calibration.*``."""
    with _named('temperature_calibration'):
        return TemperatureSettings(low_c=values['temperature_calibration.low_c'],
                                   high_c=values['temperature_calibration.high_c'],
                                   period_s=values['temperature_calibration.period_s'],
                                   cycles=values['temperature_calibration.cycles'],
                                   m_bits=values['temperature_calibration.m_bits'])


def unit_of(values):
    """Return the drawn :class:`~qfa_ros.model.unit.Unit` of ``unit.*``, or None."""
    if not values['unit.draw']:
        return None
    seed = values['unit.seed']
    return draw_unit(values['seed'] if seed < 0 else seed)


def make_triad(values, profile=None):
    """Return the :class:`QfaTriad` of the parameter ``values``: the unit, its aging."""
    triad = QfaTriad(triad_config(values), rng=values['seed'], profile=profile)
    unit = unit_of(values)
    if unit is not None:
        unit.install_aging(triad)
    return triad


def triad_config(values):
    """Return the :class:`TriadConfig` of the parameter ``values`` (ValueError names them)."""
    thermal = thermal_config(values)
    with _named('noise'):
        noise = NoiseConfig(noise_density=values['noise.density_ug_per_rthz'] * MICRO_G,
                            bias_instability=values['noise.bias_instability_ug'] * MICRO_G,
                            adc_noise=values['noise.adc_counts'])
    mrad = values['model.misalignment_mrad']
    misalignment = tuple(tuple(v * 1e-3 for v in mrad[3 * k:3 * k + 3]) for k in range(3))
    with _named('sample_rate_hz / loop_rate_hz / model'):
        config = TriadConfig.from_datasheet(
            bias_ug=tuple(values['model.bias_ug']),
            k2_ug_per_g2=tuple(values['model.k2_ug_per_g2']),
            loop_rate_hz=values['loop_rate_hz'], sample_rate_hz=values['sample_rate_hz'],
            noise=noise, thermal=thermal, misalignment=misalignment)
    unit = unit_of(values)
    return config if unit is None else unit.configure(config)


def forward_settings(values):
    """Return the :class:`ForwardSettings` of ``estimation.forward.*``."""
    with _named('estimation.forward'):
        return ForwardSettings(points=values['estimation.forward.points'],
                               step=values['estimation.forward.step'],
                               settle_s=values['estimation.forward.settle_s'],
                               average_s=values['estimation.forward.average_s'],
                               order=values['estimation.forward.order'])


def feedback_settings(values):
    """Return the :class:`FeedbackSettings` of ``estimation.feedback.*``."""
    with _named('estimation.feedback'):
        return FeedbackSettings(
            cycles=values['estimation.feedback.cycles'],
            settle_s=values['estimation.feedback.settle_s'],
            average_s=values['estimation.feedback.average_s'],
            order=values['estimation.feedback.order'],
            motion_limit=values['estimation.feedback.motion_limit_ug'] * MICRO_G,
            reference_tc_ppm=values['estimation.feedback.reference_tc_ppm'])


def static_profile(values):
    """Return the static orientation of ``input.roll`` / ``input.pitch``."""
    return StaticProfile.orientation(values['input.roll'], values['input.pitch'])


def input_profile(values):
    """Return the profile that drives the model in ``static`` and ``profile`` modes."""
    if values['input.mode'] != 'profile':
        return static_profile(values)
    kind = values['input.profile']
    with _named(f'input.{kind}'):
        if kind == 'sine':
            return SineProfile(frequency_hz=values['input.sine.frequency_hz'],
                               amplitude=tuple(values['input.sine.amplitude']),
                               offset=tuple(values['input.sine.offset']))
        if kind == 'tumble':
            return tumble_profile(values['input.tumble.dwell_s'])
        levels = list(values['input.steps.levels'])
        times = tuple(values['input.steps.times_s'])
        if len(levels) != 3 * len(times):
            raise ValueError(f'levels needs 3 values per time: {len(times)} times, '
                             f'{len(levels)} values')
        return StepProfile(times=times, levels=tuple(tuple(levels[3 * k:3 * k + 3])
                                                     for k in range(len(times))))


def check_all(values):
    """Return why the parameter set ``values`` is inconsistent, or None."""
    for name, value in values.items():
        reason = check_value(name, value)
        if reason:
            return reason
    try:
        triad_config(values)
        forward_settings(values)
        feedback_settings(values)
        temperature_settings(values)
        input_profile(values)
    except ValueError as error:
        return str(error)
    return None


def _yaml_value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, list):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    return repr(value)


def config_yaml(node_name='qfa_node'):
    """Return ``config/qfa.yaml``: every parameter with its default and description."""
    lines = ['# Every parameter of qfa_ros/node.py with its default (see docs/node.md).',
             '# Generated by `python -m qfa_ros.ros.params yaml`; doubles keep their decimal',
             '# point because ROS 2 does not turn 1000 into 1000.0.',
             f'{node_name}:', '  ros__parameters:']
    for spec in PARAMETERS:
        text = descriptor(spec).description + (' (read-only)' if spec.read_only else '')
        lines += textwrap.wrap(text, 95, initial_indent='    # ', subsequent_indent='    # ')
        lines.append(f'    {spec.name}: {_yaml_value(spec.default)}')
    return '\n'.join(lines) + '\n'


def parameter_table():
    """Return the Markdown table of every parameter (docs/node.md)."""
    rows = ['| parameter | type | default | range / choices | runtime | meaning |',
            '|---|---|---|---|---|---|']
    for spec in PARAMETERS:
        default = spec.default
        kind = {bool: 'bool', int: 'int', float: 'double', str: 'string'}.get(type(default))
        if isinstance(default, list):
            kind = f'double[{spec.length}]' if spec.length else 'double[]'
        limits = ''
        if spec.low is not None:
            limits = f'{spec.low:g} … {spec.high:g}'
        elif spec.choices:
            limits = ' \\| '.join(spec.choices)
        runtime = 'read-only' if spec.read_only else 'yes'
        rows.append(f'| `{spec.name}` | {kind} | `{_yaml_value(default)}` | {limits} | '
                    f'{runtime} | {spec.description} |')
    return '\n'.join(rows) + '\n'


def main(argv=None):
    """Print ``config/qfa.yaml`` (``yaml``) or the docs parameter table (``markdown``)."""
    args = sys.argv[1:] if argv is None else argv
    if args not in (['yaml'], ['markdown']):
        print('usage: python -m qfa_ros.ros.params {yaml|markdown}', file=sys.stderr)
        return 2
    print(config_yaml() if args == ['yaml'] else parameter_table(), end='')
    return 0


if __name__ == '__main__':
    sys.exit(main())
