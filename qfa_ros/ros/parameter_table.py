"""
The node's parameter table, as data: every parameter with its type, default, range, who may set it.

:data:`PARAMETERS` is the one table; :data:`RUNTIME_EFFECTS` says what a runtime change of each
writable parameter does to the running sensor. What is derived from the table lives beside it:
the checks and rclpy descriptors (:mod:`qfa_ros.ros.parameter_checks`), the model and schedule
settings (:mod:`qfa_ros.ros.model_settings`), ``config/qfa.yaml`` and the docs table
(:mod:`qfa_ros.ros.parameter_docs`).
"""

from dataclasses import dataclass
import math

from qfa_ros.calibration import kalibr_yaml
from qfa_ros.calibration.estimation import (
    FEEDBACK_ORDERS,
    FeedbackSettings,
    FORWARD_ORDERS,
    ForwardSettings,
)
from qfa_ros.calibration.gyro_bias import GyroBiasSettings
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model import motion_scripts
from qfa_ros.model.constants import DEG_PER_HOUR, DEG_PER_ROOT_HOUR, MICRO_G, STANDARD_GRAVITY
from qfa_ros.model.error_profiles import ERROR_PROFILES, PaperRoom
from qfa_ros.model.gyro import GyroConfig
from qfa_ros.model.noise import NoiseConfig
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.ros.bounds import (
    CHAMBER_BOUND,
    CHAMBER_MAX_CYCLES,
    CHAMBER_MAX_PERIOD_S,
    ESTIMATION_BOUND,
    FEEDBACK_MAX_AVERAGE_S,
    FEEDBACK_MAX_CYCLES,
    FEEDBACK_MAX_SETTLE_S,
    FORWARD_MAX_AVERAGE_S,
    FORWARD_MAX_POINTS,
    FORWARD_MAX_SETTLE_S,
    FORWARD_MAX_SPAN,
    FORWARD_SPAN_BOUND,
)

INPUT_MODES = ('static', 'profile', 'trajectory', 'topic')
INPUT_TRAJECTORIES = tuple(sorted(motion_scripts.SCRIPTS)) + ('file',)
INPUT_PROFILES = ('sine', 'tumble', 'steps')
INPUT_TOPIC_TYPES = ('imu', 'accel', 'odometry')
AMBIENT_PROFILES = ('constant', 'ramp', 'cycle', 'room')
THERMAL_BIAS_MODELS = ('double_exp', 'none')

MAX_STRING_LENGTH = 4096
"""Longest string parameter [characters] (PATH_MAX): a stranger's megabyte is refused."""
MAX_FRAME_ID_LENGTH = 256
"""Longest ``frame_id`` [characters]: it rides on every published message."""
MAX_STEPS = 1000
"""Most entries of ``input.steps.times_s`` (three levels each in ``input.steps.levels``)."""
MAX_SHOWN = 64
"""Most characters of a refused value a refusal quotes back."""

FORWARD_COMPONENT = 'k_amp'
"""Drift component behind ``drift.forward_ppm``: the in-amp gain resistor (Ran et al. §IV)."""

FEEDBACK_COMPONENT = 'k_vi'
"""Drift component behind ``drift.feedback_ppm``: the V/I sense resistor (Ran et al. 2019, §IV)."""

_NOISE = NoiseConfig()
_FORWARD = ForwardSettings()
_FEEDBACK = FeedbackSettings()
_THERMAL = ThermalConfig()
_CHAMBER = TemperatureSettings()
_GYRO = GyroConfig()
_ROOM = PaperRoom()
_GYRO_BIAS = GyroBiasSettings()


OPERATOR = 'operator'
"""Who sets it: the operator only, at start (command line, parameters file, launch file).
Read-only in ``qfa_node`` and ``qfa_lifecycle_node``, in every state: what names a file or
a directory, or bounds the CPU, memory or disk the node takes."""
CONFIGURE = 'configure'
"""Who sets it: the operator at start; fixed while the sensor runs (read-only in ``qfa_node``,
and in ``qfa_lifecycle_node`` from ``configure`` to ``cleanup``); any participant may set it
while the managed node is unconfigured, for the reason its ``why`` gives."""
RUNTIME = 'runtime'
"""Who sets it: anyone on the domain, at any time, within its checks (range, size, the whole
set, a directory confined to ``output_dir``)."""
ACCESS = {OPERATOR: 'operator only', CONFIGURE: 'operator; anyone while unconfigured',
          RUNTIME: 'anyone, any time'}
"""How the docs say who may set a parameter (the three rules above)."""

# Why a parameter is the operator's alone, or why a participant may set it while the managed
# node is unconfigured (docs/security.md lists each with its parameters).
FILE_READ = 'names a file the node reads: no participant chooses what is read'
FILES_WRITTEN = ('names where the node writes (the state file is also read): no participant '
                 'chooses where files go')
STATE_READ = ("decides whether the operator's calibration state is read at configure: no "
              'participant may have it ignored, and replaced by the next save')
CPU_RATE = 'a rate or a wake-up period: it sets the CPU the node spends'
COMPUTED_AHEAD = 'how far ahead the model is computed: it sets the memory and CPU of each batch'
DISK = 'the free space the node leaves on the disk'
RETENTION = ('how much of the flight recordings the node keeps, deleting the oldest: a '
             'participant who could set it could have the recordings deleted')
STALL = ("how long one stranger's message stamped ahead may hold the honest input back")
SENSOR = ('which sensor is emulated (its unit, errors and noise): it changes what the stream '
          'says, as drift.* does at any time; no file, and no more CPU or memory than the '
          "default sensor (every source on) at the operator's rates")
LABEL = ('a label of the diagnostic statuses, at most 4096 characters; frame_id, on every '
         'message, is writable at any time')
TRUTH = ("whether the model's truth is published, at the operator's truth.rate_hz; no file")
TOPIC_TYPE = ('which message type input.mode topic subscribes to (input.mode is writable at any '
              'time); each message is judged the same')


@dataclass(frozen=True)
class ParameterSpec:
    """
    One node parameter.

    Parameters
    ----------
    name
        Parameter name.
    default
        Default value; its Python type fixes the ROS parameter type.
    description
        Human description with the unit.
    access
        Who may set it, and when: :data:`OPERATOR`, :data:`CONFIGURE` or :data:`RUNTIME`.
    low, high
        Inclusive range of a scalar number (None: no range).
    choices
        Allowed strings.
    length
        Required length of an array (None: one to ``max_length`` elements).
    max_length
        Most elements of an array without a required ``length``.
    why
        Why the operator alone sets it (:data:`OPERATOR`), or why a participant may set it while
        the managed node is unconfigured (:data:`CONFIGURE`).
    confined
        A directory confined to ``output_dir`` (checked whenever it is set).
    """

    name: str
    default: object
    description: str
    access: str = RUNTIME
    low: float = None
    high: float = None
    choices: tuple = None
    length: int = None
    max_length: int = None
    why: str = None
    confined: bool = False

    def __post_init__(self):
        if self.access not in ACCESS or (self.why is None) != (self.access == RUNTIME):
            # A programming error, caught at import by every test.
            raise RuntimeError(f'{self.name}: access one of {sorted(ACCESS)}, with a why '
                               'unless it is runtime')

    @property
    def read_only(self):
        """Return whether ``qfa_node`` refuses a change once started (every non-runtime one)."""
        return self.access != RUNTIME

    def writable(self, configured):
        """Return whether a participant may set it, the unit configured (always in qfa_node)."""
        return self.access == RUNTIME or (self.access == CONFIGURE and not configured)


def _vector(name, default, description, access=RUNTIME, low=-1.0e6, high=1.0e6, why=None):
    return ParameterSpec(name, [float(v) for v in default], description, access, low, high,
                         length=3, why=why)


PARAMETERS = (
    ParameterSpec('sample_rate_hz', 1000.0, 'Published sample rate [Hz]', OPERATOR, 1.0, 10000.0,
                  why=CPU_RATE),
    ParameterSpec('loop_rate_hz', 10000.0,
                  'Digital loop rate [Hz]; an integer multiple of sample_rate_hz', OPERATOR,
                  1.0, 1.0e6, why=CPU_RATE),
    ParameterSpec('stream.lead_s', 0.15,
                  'How far ahead of the clock the sensor thread computes the model [s]; each '
                  'sample is still published at its own instant. A parameter change reaches '
                  'the samples stamped up to this much later; a stall shorter than this '
                  'delays no sample', OPERATOR, 0.002, 1.0, why=COMPUTED_AHEAD),
    ParameterSpec('stream.batch_s', 0.1,
                  'How often the sensor thread wakes to compute the model up to '
                  'stream.lead_s ahead [s] (shorter than stream.lead_s); also the longest '
                  'wait for a ground-truth input before a sample holds the last one', OPERATOR,
                  0.001, 1.0, why=CPU_RATE),
    ParameterSpec('frame_id', 'imu_link', 'frame_id of imu/data_raw and imu/temperature'),
    ParameterSpec('seed', 1, 'Seed of every random number: same seed, same output', CONFIGURE,
                  0, 2 ** 31 - 1, why=SENSOR),
    ParameterSpec('hardware_id', 'qfa_triad', 'hardware_id of the diagnostic statuses', CONFIGURE,
                  why=LABEL),
    ParameterSpec('temperature_rate_hz', 10.0, 'Rate of imu/temperature [Hz]', OPERATOR,
                  0.1, 1000.0, why=CPU_RATE),
    ParameterSpec('temperature_c', 25.0,
                  'Ambient temperature [degC]: the constant ambient, the centre of the room '
                  'wander, the start of the ramp (without the thermal model: the sensor '
                  'temperature)', RUNTIME, -60.0, 125.0),
    ParameterSpec('thermal.enabled', True,
                  'Thermal model: body lag, on-board temperature sensor, zero bias and '
                  'scale-factor error versus temperature (Liu, Li and Shen)', CONFIGURE,
                  why=SENSOR),
    ParameterSpec('sensor.error_profile', 'paper',
                  "Error sources of the sensor (qfa_ros.model.error_profiles, docs/ins.md): "
                  "paper, the sensor with its errors (the drawn unit, noise.*, gyro.*, the "
                  "thermal curves and Ran et al.'s component temperature coefficients: DA1 "
                  'reference +20, k_tz +7, in-amp +6, I_ref +30, magnet/k_t +10 ppm/degC); '
                  'ideal, every source off (no unit draw, no noise, ideal gyros, no thermal '
                  'curves or coefficients; '
                  'model.* and drift.* still add what they set)', CONFIGURE,
                  choices=ERROR_PROFILES, why=SENSOR),
    ParameterSpec('thermal.ambient_profile', 'room',
                  "Ambient temperature profile (room: the paper's laboratory, wandering "
                  'within thermal.room_amplitude_c of temperature_c)', choices=AMBIENT_PROFILES),
    ParameterSpec('thermal.ramp_rate_c_per_s', _THERMAL.ramp_rate_c_per_s,
                  'Ramp rate of the ramp profile [degC/s], clipped to the cycle limits',
                  RUNTIME, -10.0, 10.0),
    ParameterSpec('thermal.cycle_low_c', _THERMAL.cycle_low_c,
                  'Low limit of the cycle and the ramp [degC]', RUNTIME, -60.0, 125.0),
    ParameterSpec('thermal.cycle_high_c', _THERMAL.cycle_high_c,
                  'High limit of the cycle and the ramp [degC]', RUNTIME, -60.0, 125.0),
    ParameterSpec('thermal.cycle_period_s', _THERMAL.cycle_period_s,
                  'Period of the trapezoid cycle profile [s]', RUNTIME, 1.0, 1.0e7),
    ParameterSpec('thermal.room_amplitude_c', _ROOM.room_amplitude_c,
                  'Bound of the room profile wander around temperature_c [degC] (Ran et al. '
                  '2019: the room within 3 degC)', RUNTIME, 0.0, 50.0),
    ParameterSpec('thermal.room_correlation_s', _ROOM.room_correlation_s,
                  'Correlation time of the room profile wander [s] (12 h: a room following '
                  'the day; chosen)', RUNTIME, 1.0, 1.0e7),
    ParameterSpec('thermal.sensor_tau_s', _THERMAL.sensor_tau_s,
                  'Thermal time constant of the sensor body [s]', CONFIGURE, 1.0, 1.0e5,
                  why=SENSOR),
    ParameterSpec('thermal.bias_model', _THERMAL.bias_model,
                  'Zero bias versus temperature: the double exponential of Liu, Li and Shen, '
                  'eq. 1 or none', CONFIGURE, choices=THERMAL_BIAS_MODELS, why=SENSOR),
    ParameterSpec('diagnostics_rate_hz', 1.0, 'Rate of /diagnostics [Hz]', OPERATOR, 0.1, 10.0,
                  why=CPU_RATE),
    ParameterSpec('noise.density_ug_per_rthz', _NOISE.noise_density / MICRO_G,
                  'White acceleration noise density (velocity random walk) [ug/sqrt(Hz)]',
                  CONFIGURE, 0.0, 10000.0, why=SENSOR),
    ParameterSpec('noise.bias_instability_ug', _NOISE.bias_instability / MICRO_G,
                  'Bias instability, flicker floor of the Allan deviation [ug]', CONFIGURE,
                  0.0, 100000.0, why=SENSOR),
    ParameterSpec('noise.adc_counts', _NOISE.adc_noise, 'ADC input noise [count rms]', CONFIGURE,
                  0.0, 10000.0, why=SENSOR),
    ParameterSpec('noise.imu_yaml', '',
                  'Kalibr imu.yaml whose noise the sensor emulates (docs/ins.md): its '
                  'accelerometer and gyroscope noise densities and random walks replace '
                  'noise.density_ug_per_rthz, noise.bias_instability_ug and gyro.arw, '
                  'bias_instability, rate_random_walk; the QFA loop, its ADC noise and the '
                  'unit stay. Read once, at start (a managed node: at each configure; a '
                  f'regular file of at most {kalibr_yaml.MAX_BYTES >> 10} KiB, ~ expanded); set '
                  'by the operator only, so no participant can make the node read a file',
                  OPERATOR, why=FILE_READ),
    ParameterSpec('unit.draw', True,
                  'Draw the sensor as one unit within the datasheet spreads (turn-on bias, '
                  'thermal curves, aging, K2, misalignment; qfa_ros.model.drawn_unit); false: the '
                  'nominal sensor (Liu, Li and Shen, default curves, no turn-on bias)', CONFIGURE,
                  why=SENSOR),
    ParameterSpec('unit.seed', -1,
                  'Seed of the drawn unit: the same seed, the same unit; -1: the unit of seed',
                  CONFIGURE, -1, 2 ** 31 - 1, why=SENSOR),
    _vector('model.bias_ug', (0.0, 0.0, 0.0),
            "IEEE 1293 bias per axis x, y, z, added to the unit's [ug]", CONFIGURE,
            -1.0e5, 1.0e5, why=SENSOR),
    _vector('model.k2_ug_per_g2', (0.0, 0.0, 0.0),
            "IEEE 1293 second-order coefficient per axis, added to the unit's [ug/g^2]", CONFIGURE,
            -1.0e4, 1.0e4, why=SENSOR),
    ParameterSpec('model.misalignment_mrad', [0.0] * 9,
                  "Mounting misalignment / cross-coupling M added to the unit's, row-major "
                  '3x3 (each loop senses ((I + M) f)_i) [mrad]', CONFIGURE, -100.0, 100.0,
                  length=9, why=SENSOR),
    _vector('drift.forward_ppm', (0.0, 0.0, 0.0),
            'Step drift of the forward gain (in-amp gain resistor) per axis [ppm]',
            low=-1.0e5, high=1.0e5),
    _vector('drift.feedback_ppm', (0.0, 0.0, 0.0),
            'Step drift of the feedback gain (V/I sense resistor) per axis [ppm]',
            low=-1.0e5, high=1.0e5),
    _vector('drift.aging_forward_ppm_per_year', (0.0, 0.0, 0.0),
            'Linear aging of the forward gain per axis [ppm/year of sensor time]',
            low=-1.0e5, high=1.0e5),
    _vector('drift.aging_feedback_ppm_per_year', (0.0, 0.0, 0.0),
            'Linear aging of the feedback gain per axis [ppm/year of sensor time]',
            low=-1.0e5, high=1.0e5),
    ParameterSpec('drift.time_acceleration', 1.0,
                  'Aging time-acceleration factor (3.15e7: a year per second)', RUNTIME,
                  0.0, 1.0e12),
    ParameterSpec('latitude_deg', 45.0,
                  'Geodetic latitude of the sensor (WGS-84) [deg]: normal gravity and Earth '
                  'rate follow (at a pole: the Earth rate all vertical; a drive keeps 0.1 deg '
                  'off it)', RUNTIME, -90.0, 90.0),
    ParameterSpec('longitude_deg', 0.0, 'Longitude of the sensor (WGS-84) [deg]', RUNTIME,
                  -180.0, 180.0),
    ParameterSpec('height_m', 0.0, 'Height of the sensor above the WGS-84 ellipsoid [m]',
                  RUNTIME, -12000.0, 100000.0),
    ParameterSpec('gyro.enabled', True,
                  'Gyro triad (IEEE 952 FOG model): angular_velocity of imu/data_raw; false: '
                  'angular_velocity_covariance[0] = -1', CONFIGURE, why=SENSOR),
    ParameterSpec('gyro.arw_deg_per_rthr', _GYRO.arw / DEG_PER_ROOT_HOUR,
                  'Gyro angle random walk [deg/sqrt(h)]', CONFIGURE, 0.0, 100.0, why=SENSOR),
    ParameterSpec('gyro.bias_instability_deg_per_hr', _GYRO.bias_instability / DEG_PER_HOUR,
                  'Gyro bias instability, flicker floor of the Allan deviation [deg/h]', CONFIGURE,
                  0.0, 1000.0, why=SENSOR),
    ParameterSpec('gyro.rate_random_walk_deg_per_hr_per_rthr',
                  _GYRO.rate_random_walk * 60.0 / DEG_PER_HOUR,
                  'Gyro rate random walk [deg/h/sqrt(h)]', CONFIGURE, 0.0, 1000.0, why=SENSOR),
    ParameterSpec('gyro.turn_on_bias_deg_per_hr', round(_GYRO.turn_on_bias / DEG_PER_HOUR, 9),
                  'Spread (1 sigma) of the gyro turn-on bias drawn per unit [deg/h]', CONFIGURE,
                  0.0, 10000.0, why=SENSOR),
    ParameterSpec('truth.enabled', True,
                  'Publish truth/odometry and truth/origin (input.mode static or trajectory) and '
                  'truth/imu_errors, the errors the model holds (docs/ins.md); '
                  '~/calibration_events is published either way', CONFIGURE, why=TRUTH),
    ParameterSpec('truth.rate_hz', 10.0,
                  'Rate of truth/odometry and truth/imu_errors [Hz], and how often applied '
                  'corrections are looked for', OPERATOR, 0.1, 100.0, why=CPU_RATE),
    ParameterSpec('input.mode', 'static',
                  'Input: static orientation, scripted profile, trajectory on the Earth, or '
                  'ground-truth topic', choices=INPUT_MODES),
    ParameterSpec('input.roll', 0.0, 'Static roll [rad] (also the topic fallback)', RUNTIME,
                  -math.pi, math.pi),
    ParameterSpec('input.pitch', 0.0, 'Static pitch [rad] (also the topic fallback)', RUNTIME,
                  -math.pi / 2, math.pi / 2),
    ParameterSpec('input.yaw', 0.0,
                  'Static heading [rad], REP-103 ENU yaw (0: x east, pi/2: x north); also '
                  'the initial heading of a trajectory', RUNTIME, -math.pi, math.pi),
    ParameterSpec('input.trajectory', 'drive',
                  'Trajectory of input.mode trajectory: a built-in motion script or file '
                  '(input.trajectory_file); it starts when selected', choices=INPUT_TRAJECTORIES),
    ParameterSpec('input.trajectory_file', '',
                  'CSV pose file of input.trajectory file: time_s, latitude_deg, '
                  'longitude_deg, height_m, roll_deg, pitch_deg, yaw_deg. Read once, at '
                  'start (a managed node: at each configure; a regular file of at most '
                  f'{motion_scripts.MAX_CSV_BYTES >> 20} MiB, ~ expanded); set by the operator '
                  'only, so no participant can make the node read a file', OPERATOR,
                  why=FILE_READ),
    ParameterSpec('input.profile', 'sine', 'Scripted profile of input.mode profile',
                  choices=INPUT_PROFILES),
    ParameterSpec('input.sine.frequency_hz', 5.0, 'Sine vibration frequency [Hz]', RUNTIME,
                  1.0e-3, 5000.0),
    _vector('input.sine.amplitude', (0.0, 0.0, 0.1 * STANDARD_GRAVITY),
            'Sine vibration amplitude per axis [m/s^2]', low=0.0, high=1000.0),
    _vector('input.sine.offset', (0.0, 0.0, STANDARD_GRAVITY),
            'Static specific force under the sine vibration per axis [m/s^2]',
            low=-1000.0, high=1000.0),
    ParameterSpec('input.tumble.dwell_s', 10.0, 'Dwell per tumble position [s]', RUNTIME,
                  1.0e-3, 1.0e6),
    ParameterSpec('input.steps.times_s', [0.0, 10.0],
                  'Start of each step level in sensor time [s], increasing', RUNTIME, 0.0,
                  1.0e9, max_length=MAX_STEPS),
    ParameterSpec('input.steps.levels', [0.0, 0.0, STANDARD_GRAVITY,
                                         STANDARD_GRAVITY, 0.0, 0.0],
                  'Step levels, x, y, z per entry of input.steps.times_s [m/s^2]', RUNTIME,
                  -1000.0, 1000.0, max_length=3 * MAX_STEPS),
    ParameterSpec('input.topic_type', 'imu',
                  'Ground-truth message: imu (sensor_msgs/Imu on input/imu, with its '
                  'angular_velocity unless covariance[0] = -1), accel '
                  '(geometry_msgs/AccelStamped on input/accel) or odometry (nav_msgs/Odometry '
                  'on input/odometry, e.g. Gazebo ground truth)', CONFIGURE,
                  choices=INPUT_TOPIC_TYPES, why=TOPIC_TYPE),
    ParameterSpec('input.timeout_s', 0.1,
                  'Ground-truth input older than this is stale: imu/data_raw pauses [s]',
                  RUNTIME, 1.0e-3, 3600.0),
    ParameterSpec('input.stamp_window_s', 1.0,
                  'A ground-truth message stamped further than this from the node clock, '
                  'ahead or behind, is refused and counted (diagnostics input) without '
                  'changing the input [s]. Read-only: a message stamped up to this far ahead '
                  'holds back the honest input stamped before it, so no participant may '
                  'widen it', OPERATOR, 1.0e-3, 3600.0, why=STALL),
    ParameterSpec('estimation.realtime', True,
                  'true: a schedule takes its sensor time at the node clock; false: as fast '
                  'as the CPU allows'),
    ParameterSpec('estimation.forward.points', _FORWARD.points,
                  'Forward sweep steps n (N_FPGA + i dN0, i = 0..n)' + ESTIMATION_BOUND,
                  RUNTIME, 2, FORWARD_MAX_POINTS),
    ParameterSpec('estimation.forward.step', _FORWARD.step,
                  'Forward sweep increment dN0 [count]' + FORWARD_SPAN_BOUND, RUNTIME, 1,
                  FORWARD_MAX_SPAN // 2),
    ParameterSpec('estimation.forward.settle_s', _FORWARD.settle_s,
                  'Discarded time per forward point [s]' + ESTIMATION_BOUND, RUNTIME,
                  0.0, FORWARD_MAX_SETTLE_S),
    ParameterSpec('estimation.forward.average_s', _FORWARD.average_s,
                  'Averaged time per forward point [s]' + ESTIMATION_BOUND, RUNTIME,
                  1.0e-3, FORWARD_MAX_AVERAGE_S),
    ParameterSpec('estimation.forward.order', _FORWARD.order, 'Forward sweep order',
                  choices=FORWARD_ORDERS),
    ParameterSpec('estimation.feedback.cycles', _FEEDBACK.cycles,
                  'I_ref on/off cycles (chopped: off-on-on-off quadruples)'
                  + ESTIMATION_BOUND, RUNTIME, 1, FEEDBACK_MAX_CYCLES),
    ParameterSpec('estimation.feedback.settle_s', _FEEDBACK.settle_s,
                  'Discarded time per I_ref segment [s]' + ESTIMATION_BOUND, RUNTIME,
                  0.0, FEEDBACK_MAX_SETTLE_S),
    ParameterSpec('estimation.feedback.average_s', _FEEDBACK.average_s,
                  'Averaged time per I_ref segment [s]' + ESTIMATION_BOUND, RUNTIME,
                  1.0e-3, FEEDBACK_MAX_AVERAGE_S),
    ParameterSpec('estimation.feedback.order', _FEEDBACK.order, 'I_ref switching order',
                  choices=FEEDBACK_ORDERS),
    ParameterSpec('estimation.feedback.motion_limit_ug', _FEEDBACK.motion_limit / MICRO_G,
                  'Scatter of 10 ms means beyond the noise that counts as a moving input '
                  '[ug]', RUNTIME, 1.0e-3, 1.0e6),
    ParameterSpec('estimation.feedback.temperature_correction',
                  _FEEDBACK.temperature_correction,
                  'Move the I_ref reference step to the present on-board temperature with the '
                  'I_ref temperature coefficient calibrate_temperature measured (refused '
                  'without one; false: the paper schedule)'),
    ParameterSpec('gyro_bias.duration_s', _GYRO_BIAS.duration_s,
                  'Averaged time of calibrate_gyros, the gyro bias at rest [s] (bounded: at '
                  'most 600 s of sensor time)', RUNTIME, 2.0, 600.0),
    ParameterSpec('gyro_bias.motion_limit_deg_per_hr',
                  round(_GYRO_BIAS.rate_limit / DEG_PER_HOUR, 9),
                  'A 1 s gyro mean departing from the run mean by more than this counts as a '
                  'moving input in calibrate_gyros [deg/h]', RUNTIME, 1.0e-3, 1.0e6),
    ParameterSpec('gyro_bias.motion_limit_ug', round(_GYRO_BIAS.accel_limit / MICRO_G, 9),
                  'A 1 s accelerometer mean departing from the run mean by more than this '
                  'counts as a moving input in calibrate_gyros [ug]', RUNTIME, 1.0e-3, 1.0e6),
    ParameterSpec('temperature_calibration.low_c', _CHAMBER.low_c,
                  'Lowest chamber plateau of calibrate_temperature [degC]', RUNTIME,
                  -60.0, 125.0),
    ParameterSpec('temperature_calibration.high_c', _CHAMBER.high_c,
                  'Highest chamber plateau of calibrate_temperature [degC]', RUNTIME,
                  -60.0, 125.0),
    ParameterSpec('temperature_calibration.period_s', _CHAMBER.period_s,
                  'Chamber program of calibrate_temperature (all plateaus, six-position '
                  'tumble) in sensor time [s], plus the soaks at the turning points and back '
                  'to the starting temperature (always run as fast as the CPU allows)'
                  + CHAMBER_BOUND,
                  RUNTIME, 60.0, CHAMBER_MAX_PERIOD_S),
    ParameterSpec('temperature_calibration.cycles', _CHAMBER.cycles,
                  'Chamber programs of calibrate_temperature' + CHAMBER_BOUND, RUNTIME,
                  1, CHAMBER_MAX_CYCLES),
    ParameterSpec('temperature_calibration.reference_steps', True,
                  'Measure the I_ref step at every chamber plateau of calibrate_temperature '
                  'and store its temperature coefficient (what '
                  'estimation.feedback.temperature_correction needs)'),
    ParameterSpec('temperature_calibration.m_bits', _CHAMBER.m_bits,
                  'Fraction bits M of the fixed-point CORDIC zero-bias compensator (Liu, Li and '
                  'Shen: 16; the scale factor uses 24); at least these: an axis whose fitted '
                  'terms cancel gets the bits they take beyond the 4 guard bits, up to 27',
                  RUNTIME, 8, 30),
    ParameterSpec('output_dir', '~/.ros/qfa_ros',
                  'Base directory of every trace and recording the node writes (~ expanded '
                  'once, at start); trace_dir and recorder.directory must stay inside it',
                  OPERATOR, why=FILES_WRITTEN),
    ParameterSpec('min_free_bytes', 1 << 30,
                  'Free space the node leaves on the file system of output_dir [bytes]: no '
                  'trace is written and the recorder stops (diagnostics ERROR) before the '
                  'free space falls under it', OPERATOR, 1 << 20, 2 ** 50, why=DISK),
    ParameterSpec('trace_dir', 'traces',
                  'Directory of the estimation traces (MCAP), created when needed: relative '
                  'to output_dir, or absolute inside it (symlinks and .. resolved; ~ not '
                  'expanded)', confined=True),
    ParameterSpec('state_file', '~/.ros/qfa_ros/calibration.json',
                  'Persisted calibration state (JSON); empty: keep it in memory only', OPERATOR,
                  why=FILES_WRITTEN),
    ParameterSpec('state.fresh', False,
                  'Start fresh: ignore state_file at start (not loaded: nominal words, no '
                  'compensation, no references); the next saved calibration replaces it',
                  OPERATOR, why=STATE_READ),
    ParameterSpec('recorder.enabled', False,
                  'Record the published imu/data_raw, imu/temperature, /diagnostics, '
                  '~/is_calibrated, ~/calibration_events and truth topics to MCAP'),
    ParameterSpec('recorder.directory', 'recordings',
                  'Directory of the flight recordings, created when needed: relative to '
                  'output_dir, or absolute inside it (symlinks and .. resolved; ~ not '
                  'expanded)', confined=True),
    ParameterSpec('recorder.max_bytes', 1 << 30,
                  'Start a new recording file before this size [bytes]', RUNTIME,
                  1 << 20, 1 << 34),
    ParameterSpec('recorder.max_duration_s', 600.0,
                  'Start a new recording file after this long [s]', RUNTIME, 1.0, 86400.0),
    ParameterSpec('recorder.keep_s', 86400.0,
                  'Recording time the flight recorder keeps [s]: the newest finished files '
                  'are kept while the time they cover adds up to less than this (the one that '
                  'reaches it too), older ones are deleted, the bags of earlier runs in '
                  'recorder.directory included; the file being written is never deleted. '
                  '0: no limit. 86400: the last day of recording, as a flight data recorder '
                  'keeps its last hours of operation (the disk it takes: docs/node.md, '
                  'Retention)',
                  OPERATOR, 0.0, 3.1536e7, why=RETENTION),
    ParameterSpec('recorder.keep_bytes', 10 << 30,
                  'Most bytes of finished recording files the flight recorder keeps [bytes]: '
                  'beyond it the oldest are deleted (the file being written comes on top, at '
                  'most recorder.max_bytes). 0: no limit. 10 GiB: more than a day at the '
                  'default rates (bench/results/recorder_disk_rate.md), so that '
                  'recorder.keep_s decides there and this one at higher rates; min_free_bytes '
                  'still stops the recorder when neither frees enough', OPERATOR, 0, 2 ** 50,
                  why=RETENTION),
)

SPECS = {spec.name: spec for spec in PARAMETERS}
CONFINED = tuple(spec.name for spec in PARAMETERS if spec.confined)
"""The directories a participant may set, each confined to ``output_dir``."""

RUNTIME_EFFECTS = {
    'frame': ('frame_id',),
    'ambient': ('temperature_c', 'thermal.ambient_profile', 'thermal.ramp_rate_c_per_s',
                'thermal.cycle_low_c', 'thermal.cycle_high_c', 'thermal.cycle_period_s',
                'thermal.room_amplitude_c', 'thermal.room_correlation_s'),
    'drift': ('drift.forward_ppm', 'drift.feedback_ppm', 'drift.aging_forward_ppm_per_year',
              'drift.aging_feedback_ppm_per_year', 'drift.time_acceleration'),
    'input': ('latitude_deg', 'longitude_deg', 'height_m', 'input.mode', 'input.roll',
              'input.pitch', 'input.yaw', 'input.trajectory', 'input.profile',
              'input.sine.frequency_hz', 'input.sine.amplitude', 'input.sine.offset',
              'input.tumble.dwell_s', 'input.steps.times_s', 'input.steps.levels'),
    'recorder': ('recorder.enabled', 'recorder.directory', 'recorder.max_bytes',
                 'recorder.max_duration_s'),
    'live': ('input.timeout_s', 'estimation.realtime',
             'estimation.forward.points', 'estimation.forward.step',
             'estimation.forward.settle_s', 'estimation.forward.average_s',
             'estimation.forward.order', 'estimation.feedback.cycles',
             'estimation.feedback.settle_s', 'estimation.feedback.average_s',
             'estimation.feedback.order', 'estimation.feedback.motion_limit_ug',
             'estimation.feedback.temperature_correction', 'gyro_bias.duration_s',
             'gyro_bias.motion_limit_deg_per_hr', 'gyro_bias.motion_limit_ug',
             'temperature_calibration.low_c', 'temperature_calibration.high_c',
             'temperature_calibration.period_s', 'temperature_calibration.cycles',
             'temperature_calibration.reference_steps', 'temperature_calibration.m_bits',
             'trace_dir'),
}
"""
What a runtime change of each writable parameter does to the running sensor.

``live`` parameters are read from the live values where they are used (a schedule's
settings when it is called, the input's timeout at every sample); every other effect
is a step the node runs when one of its parameters changes (its handler in
``QfaNode``). Every writable parameter is in exactly one entry and no read-only one
is (test_node_params.py), so a new writable parameter cannot be accepted and ignored.
"""
EFFECT_OF = {name: effect for effect, names in RUNTIME_EFFECTS.items() for name in names}
"""The runtime effect of each writable parameter (see :data:`RUNTIME_EFFECTS`)."""
_UNMAPPED = {spec.name for spec in PARAMETERS if not spec.read_only} ^ set(EFFECT_OF)
if _UNMAPPED:
    # A programming error, caught at import by every test: a writable parameter without
    # a runtime effect would be accepted and do nothing.
    raise RuntimeError(f'RUNTIME_EFFECTS must list every writable parameter exactly once: '
                       f'{sorted(_UNMAPPED)}')
THERMAL_RUNTIME_PARAMETERS = frozenset(RUNTIME_EFFECTS['ambient'])
"""Parameters that change the ambient of the running thermal model."""
