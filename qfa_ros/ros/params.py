"""
Parameters of the QFA node: declarations, validation and mapping onto the model.

One cohesive thing: the parameter table and what is derived from it (descriptors,
type conversion, validation, model settings, ``config/qfa.yaml`` and the docs table);
splitting it would scatter one table over several modules.
"""

from contextlib import contextmanager
import dataclasses
from dataclasses import dataclass
import functools
import math
import os
import sys
import textwrap

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from qfa_ros.calibration import kalibr_yaml
from qfa_ros.calibration.estimation import (
    FEEDBACK_ORDERS,
    FeedbackSettings,
    FORWARD_ORDERS,
    ForwardSettings,
)
from qfa_ros.calibration.gyro_bias import GyroBiasSettings
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model import trajectories
from qfa_ros.model.errors import error_profile, ERROR_PROFILES, PaperRoom, sensor_config
from qfa_ros.model.gyro import GyroConfig
from qfa_ros.model.imu_noise import emulated_config
from qfa_ros.model.noise import NoiseConfig
from qfa_ros.model.profiles import SineProfile, StepProfile, tumble_profile
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig
from qfa_ros.model.unit import draw_unit
from qfa_ros.model.units import DEG_PER_HOUR, DEG_PER_ROOT_HOUR, MICRO_G, STANDARD_GRAVITY
from qfa_ros.ros.bounds import (
    budget_problem,
    CHAMBER_BOUND,
    CHAMBER_MAX_CYCLES,
    CHAMBER_MAX_PERIOD_S,
    confined_directory,
    ESTIMATION_BOUND,
    FEEDBACK_MAX_AVERAGE_S,
    FEEDBACK_MAX_CYCLES,
    FEEDBACK_MAX_SETTLE_S,
    FORWARD_MAX_AVERAGE_S,
    FORWARD_MAX_POINTS,
    FORWARD_MAX_SETTLE_S,
    FORWARD_MAX_SPAN,
    FORWARD_SPAN_BOUND,
    forward_sweep_problem,
)

INPUT_MODES = ('static', 'profile', 'trajectory', 'topic')
INPUT_TRAJECTORIES = tuple(sorted(trajectories.SCRIPTS)) + ('file',)
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
"""Drift component behind ``drift.forward_ppm``: the in-amp gain resistor (seed 1 §IV)."""

FEEDBACK_COMPONENT = 'k_vi'
"""Drift component behind ``drift.feedback_ppm``: the V/I sense resistor (seed 1 §IV)."""

_NOISE = NoiseConfig()
_FORWARD = ForwardSettings()
_FEEDBACK = FeedbackSettings()
_THERMAL = ThermalConfig()
_CHAMBER = TemperatureSettings()
_GYRO = GyroConfig()
_ROOM = PaperRoom()
_GYRO_BIAS = GyroBiasSettings()


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
    :param length: Required length of an array (None: one to ``max_length`` elements).
    :param max_length: Most elements of an array without a required ``length``.
    """

    name: str
    default: object
    description: str
    read_only: bool = False
    low: float = None
    high: float = None
    choices: tuple = None
    length: int = None
    max_length: int = None


def _vector(name, default, description, read_only=False, low=-1.0e6, high=1.0e6):
    return ParameterSpec(name, [float(v) for v in default], description, read_only, low, high,
                         length=3)


PARAMETERS = (
    ParameterSpec('sample_rate_hz', 1000.0, 'Published sample rate [Hz]', True, 1.0, 10000.0),
    ParameterSpec('loop_rate_hz', 10000.0,
                  'Digital loop rate [Hz]; an integer multiple of sample_rate_hz', True,
                  1.0, 1.0e6),
    ParameterSpec('stream.lead_s', 0.15,
                  'How far ahead of the clock the sensor thread computes the model [s]; each '
                  'sample is still published at its own instant. A parameter change reaches '
                  'the samples stamped up to this much later; a stall shorter than this '
                  'delays no sample', True, 0.002, 1.0),
    ParameterSpec('stream.batch_s', 0.1,
                  'How often the sensor thread wakes to compute the model up to '
                  'stream.lead_s ahead [s] (shorter than stream.lead_s); also the longest '
                  'wait for a ground-truth input before a sample holds the last one', True,
                  0.001, 1.0),
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
    ParameterSpec('sensor.error_profile', 'paper',
                  "Error sources of the sensor (qfa_ros.model.errors, docs/ins.md): paper, the "
                  "sensor with its errors (the drawn unit, noise.*, gyro.*, the thermal curves "
                  "and seed 1's component temperature coefficients: DA1 reference +20, k_tz +7, "
                  'in-amp +6, I_ref +30, magnet/k_t +10 ppm/degC); ideal, every source off '
                  '(no unit draw, no noise, ideal gyros, no thermal curves or coefficients; '
                  'model.* and drift.* still add what they set)', True,
                  choices=ERROR_PROFILES),
    ParameterSpec('thermal.ambient_profile', 'room',
                  "Ambient temperature profile (room: the paper's laboratory, wandering "
                  'within thermal.room_amplitude_c of temperature_c)', choices=AMBIENT_PROFILES),
    ParameterSpec('thermal.ramp_rate_c_per_s', _THERMAL.ramp_rate_c_per_s,
                  'Ramp rate of the ramp profile [degC/s], clipped to the cycle limits',
                  False, -10.0, 10.0),
    ParameterSpec('thermal.cycle_low_c', _THERMAL.cycle_low_c,
                  'Low limit of the cycle and the ramp [degC]', False, -60.0, 125.0),
    ParameterSpec('thermal.cycle_high_c', _THERMAL.cycle_high_c,
                  'High limit of the cycle and the ramp [degC]', False, -60.0, 125.0),
    ParameterSpec('thermal.cycle_period_s', _THERMAL.cycle_period_s,
                  'Period of the trapezoid cycle profile [s]', False, 1.0, 1.0e7),
    ParameterSpec('thermal.room_amplitude_c', _ROOM.room_amplitude_c,
                  'Bound of the room profile wander around temperature_c [degC] (seed 1: the '
                  'room within 3 degC)', False, 0.0, 50.0),
    ParameterSpec('thermal.room_correlation_s', _ROOM.room_correlation_s,
                  'Correlation time of the room profile wander [s] (12 h: a room following '
                  'the day; chosen)', False, 1.0, 1.0e7),
    ParameterSpec('thermal.sensor_tau_s', _THERMAL.sensor_tau_s,
                  'Thermal time constant of the sensor body [s]', True, 1.0, 1.0e5),
    ParameterSpec('thermal.bias_model', _THERMAL.bias_model,
                  'Zero bias versus temperature: the double exponential of seed 2 eq. 1 or '
                  'none', True, choices=THERMAL_BIAS_MODELS),
    ParameterSpec('diagnostics_rate_hz', 1.0, 'Rate of /diagnostics [Hz]', True, 0.1, 10.0),
    ParameterSpec('noise.density_ug_per_rthz', _NOISE.noise_density / MICRO_G,
                  'White acceleration noise density (velocity random walk) [ug/sqrt(Hz)]',
                  True, 0.0, 10000.0),
    ParameterSpec('noise.bias_instability_ug', _NOISE.bias_instability / MICRO_G,
                  'Bias instability, flicker floor of the Allan deviation [ug]', True,
                  0.0, 100000.0),
    ParameterSpec('noise.adc_counts', _NOISE.adc_noise, 'ADC input noise [count rms]', True,
                  0.0, 10000.0),
    ParameterSpec('noise.imu_yaml', '',
                  'Kalibr imu.yaml whose noise the sensor emulates (docs/ins.md): its '
                  'accelerometer and gyroscope noise densities and random walks replace '
                  'noise.density_ug_per_rthz, noise.bias_instability_ug and gyro.arw, '
                  'bias_instability, rate_random_walk; the QFA loop, its ADC noise and the '
                  'unit stay. Read once, at start (a regular file of at most '
                  f'{kalibr_yaml.MAX_BYTES >> 10} KiB, ~ expanded); read-only, so no participant '
                  'can make the node read a file', True),
    ParameterSpec('unit.draw', True,
                  'Draw the sensor as one unit within the datasheet spreads (turn-on bias, '
                  'thermal curves, aging, K2, misalignment; qfa_ros.model.unit); false: the '
                  'nominal sensor (seed 2 default curves, no turn-on bias)', True),
    ParameterSpec('unit.seed', -1,
                  'Seed of the drawn unit: the same seed, the same unit; -1: the unit of seed',
                  True, -1, 2 ** 31 - 1),
    _vector('model.bias_ug', (0.0, 0.0, 0.0),
            "IEEE 1293 bias per axis x, y, z, added to the unit's [ug]", True,
            -1.0e5, 1.0e5),
    _vector('model.k2_ug_per_g2', (0.0, 0.0, 0.0),
            "IEEE 1293 second-order coefficient per axis, added to the unit's [ug/g^2]", True,
            -1.0e4, 1.0e4),
    ParameterSpec('model.misalignment_mrad', [0.0] * 9,
                  "Mounting misalignment / cross-coupling M added to the unit's, row-major "
                  '3x3 (each loop senses ((I + M) f)_i) [mrad]', True, -100.0, 100.0,
                  length=9),
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
                  'Aging time-acceleration factor (3.15e7: a year per second)', False,
                  0.0, 1.0e12),
    ParameterSpec('latitude_deg', 45.0,
                  'Geodetic latitude of the sensor (WGS-84) [deg]: normal gravity and Earth '
                  'rate follow (at a pole: the Earth rate all vertical; a drive keeps 0.1 deg '
                  'off it)', False, -90.0, 90.0),
    ParameterSpec('longitude_deg', 0.0, 'Longitude of the sensor (WGS-84) [deg]', False,
                  -180.0, 180.0),
    ParameterSpec('height_m', 0.0, 'Height of the sensor above the WGS-84 ellipsoid [m]',
                  False, -12000.0, 100000.0),
    ParameterSpec('gyro.enabled', True,
                  'Gyro triad (IEEE 952 FOG model): angular_velocity of imu/data_raw; false: '
                  'angular_velocity_covariance[0] = -1', True),
    ParameterSpec('gyro.arw_deg_per_rthr', _GYRO.arw / DEG_PER_ROOT_HOUR,
                  'Gyro angle random walk [deg/sqrt(h)]', True, 0.0, 100.0),
    ParameterSpec('gyro.bias_instability_deg_per_hr', _GYRO.bias_instability / DEG_PER_HOUR,
                  'Gyro bias instability, flicker floor of the Allan deviation [deg/h]', True,
                  0.0, 1000.0),
    ParameterSpec('gyro.rate_random_walk_deg_per_hr_per_rthr',
                  _GYRO.rate_random_walk * 60.0 / DEG_PER_HOUR,
                  'Gyro rate random walk [deg/h/sqrt(h)]', True, 0.0, 1000.0),
    ParameterSpec('gyro.turn_on_bias_deg_per_hr', round(_GYRO.turn_on_bias / DEG_PER_HOUR, 9),
                  'Spread (1 sigma) of the gyro turn-on bias drawn per unit [deg/h]', True,
                  0.0, 10000.0),
    ParameterSpec('truth.enabled', True,
                  'Publish truth/odometry and truth/origin (input.mode static or trajectory) and '
                  'truth/imu_errors, the errors the model holds (docs/ins.md); '
                  '~/calibration_events is published either way', True),
    ParameterSpec('truth.rate_hz', 10.0,
                  'Rate of truth/odometry and truth/imu_errors [Hz], and how often applied '
                  'corrections are looked for', True, 0.1, 100.0),
    ParameterSpec('input.mode', 'static',
                  'Input: static orientation, scripted profile, trajectory on the Earth, or '
                  'ground-truth topic', choices=INPUT_MODES),
    ParameterSpec('input.roll', 0.0, 'Static roll [rad] (also the topic fallback)', False,
                  -math.pi, math.pi),
    ParameterSpec('input.pitch', 0.0, 'Static pitch [rad] (also the topic fallback)', False,
                  -math.pi / 2, math.pi / 2),
    ParameterSpec('input.yaw', 0.0,
                  'Static heading [rad], REP-103 ENU yaw (0: x east, pi/2: x north); also '
                  'the initial heading of a trajectory', False, -math.pi, math.pi),
    ParameterSpec('input.trajectory', 'drive',
                  'Trajectory of input.mode trajectory: a built-in motion script or file '
                  '(input.trajectory_file); it starts when selected', choices=INPUT_TRAJECTORIES),
    ParameterSpec('input.trajectory_file', '',
                  'CSV pose file of input.trajectory file: time_s, latitude_deg, '
                  'longitude_deg, height_m, roll_deg, pitch_deg, yaw_deg. Read once, at '
                  f'start (a regular file of at most {trajectories.MAX_CSV_BYTES >> 20} MiB, '
                  '~ expanded); read-only, so no participant can make the node read a file',
                  True),
    ParameterSpec('input.profile', 'sine', 'Scripted profile of input.mode profile',
                  choices=INPUT_PROFILES),
    ParameterSpec('input.sine.frequency_hz', 5.0, 'Sine vibration frequency [Hz]', False,
                  1.0e-3, 5000.0),
    _vector('input.sine.amplitude', (0.0, 0.0, 0.1 * STANDARD_GRAVITY),
            'Sine vibration amplitude per axis [m/s^2]', low=0.0, high=1000.0),
    _vector('input.sine.offset', (0.0, 0.0, STANDARD_GRAVITY),
            'Static specific force under the sine vibration per axis [m/s^2]',
            low=-1000.0, high=1000.0),
    ParameterSpec('input.tumble.dwell_s', 10.0, 'Dwell per tumble position [s]', False,
                  1.0e-3, 1.0e6),
    ParameterSpec('input.steps.times_s', [0.0, 10.0],
                  'Start of each step level in sensor time [s], increasing', False, 0.0,
                  1.0e9, max_length=MAX_STEPS),
    ParameterSpec('input.steps.levels', [0.0, 0.0, STANDARD_GRAVITY,
                                         STANDARD_GRAVITY, 0.0, 0.0],
                  'Step levels, x, y, z per entry of input.steps.times_s [m/s^2]', False,
                  -1000.0, 1000.0, max_length=3 * MAX_STEPS),
    ParameterSpec('input.topic_type', 'imu',
                  'Ground-truth message: imu (sensor_msgs/Imu on input/imu, with its '
                  'angular_velocity unless covariance[0] = -1), accel '
                  '(geometry_msgs/AccelStamped on input/accel) or odometry (nav_msgs/Odometry '
                  'on input/odometry, e.g. Gazebo ground truth)', True,
                  choices=INPUT_TOPIC_TYPES),
    ParameterSpec('input.timeout_s', 0.1,
                  'Ground-truth input older than this is stale: imu/data_raw pauses [s]',
                  False, 1.0e-3, 3600.0),
    ParameterSpec('input.stamp_window_s', 1.0,
                  'A ground-truth message stamped further than this from the node clock, '
                  'ahead or behind, is refused and counted (diagnostics input) without '
                  'changing the input [s]. Read-only: a message stamped up to this far ahead '
                  'holds back the honest input stamped before it, so no participant may '
                  'widen it', True, 1.0e-3, 3600.0),
    ParameterSpec('estimation.realtime', True,
                  'true: a schedule takes its sensor time at the node clock; false: as fast '
                  'as the CPU allows'),
    ParameterSpec('estimation.forward.points', _FORWARD.points,
                  'Forward sweep steps n (N_FPGA + i dN0, i = 0..n)' + ESTIMATION_BOUND,
                  False, 2, FORWARD_MAX_POINTS),
    ParameterSpec('estimation.forward.step', _FORWARD.step,
                  'Forward sweep increment dN0 [count]' + FORWARD_SPAN_BOUND, False, 1,
                  FORWARD_MAX_SPAN // 2),
    ParameterSpec('estimation.forward.settle_s', _FORWARD.settle_s,
                  'Discarded time per forward point [s]' + ESTIMATION_BOUND, False,
                  0.0, FORWARD_MAX_SETTLE_S),
    ParameterSpec('estimation.forward.average_s', _FORWARD.average_s,
                  'Averaged time per forward point [s]' + ESTIMATION_BOUND, False,
                  1.0e-3, FORWARD_MAX_AVERAGE_S),
    ParameterSpec('estimation.forward.order', _FORWARD.order, 'Forward sweep order',
                  choices=FORWARD_ORDERS),
    ParameterSpec('estimation.feedback.cycles', _FEEDBACK.cycles,
                  'I_ref on/off cycles (chopped: off-on-on-off quadruples)'
                  + ESTIMATION_BOUND, False, 1, FEEDBACK_MAX_CYCLES),
    ParameterSpec('estimation.feedback.settle_s', _FEEDBACK.settle_s,
                  'Discarded time per I_ref segment [s]' + ESTIMATION_BOUND, False,
                  0.0, FEEDBACK_MAX_SETTLE_S),
    ParameterSpec('estimation.feedback.average_s', _FEEDBACK.average_s,
                  'Averaged time per I_ref segment [s]' + ESTIMATION_BOUND, False,
                  1.0e-3, FEEDBACK_MAX_AVERAGE_S),
    ParameterSpec('estimation.feedback.order', _FEEDBACK.order, 'I_ref switching order',
                  choices=FEEDBACK_ORDERS),
    ParameterSpec('estimation.feedback.motion_limit_ug', _FEEDBACK.motion_limit / MICRO_G,
                  'Scatter of 10 ms means beyond the noise that counts as a moving input '
                  '[ug]', False, 1.0e-3, 1.0e6),
    ParameterSpec('estimation.feedback.temperature_correction',
                  _FEEDBACK.temperature_correction,
                  'Move the I_ref reference step to the present on-board temperature with the '
                  'I_ref temperature coefficient calibrate_temperature measured (refused '
                  'without one; false: the paper schedule)'),
    ParameterSpec('gyro_bias.duration_s', _GYRO_BIAS.duration_s,
                  'Averaged time of calibrate_gyros, the gyro bias at rest [s] (bounded: at '
                  'most 600 s of sensor time)', False, 2.0, 600.0),
    ParameterSpec('gyro_bias.motion_limit_deg_per_hr',
                  round(_GYRO_BIAS.rate_limit / DEG_PER_HOUR, 9),
                  'A 1 s gyro mean departing from the run mean by more than this counts as a '
                  'moving input in calibrate_gyros [deg/h]', False, 1.0e-3, 1.0e6),
    ParameterSpec('gyro_bias.motion_limit_ug', round(_GYRO_BIAS.accel_limit / MICRO_G, 9),
                  'A 1 s accelerometer mean departing from the run mean by more than this '
                  'counts as a moving input in calibrate_gyros [ug]', False, 1.0e-3, 1.0e6),
    ParameterSpec('temperature_calibration.low_c', _CHAMBER.low_c,
                  'Lowest chamber plateau of calibrate_temperature [degC]', False,
                  -60.0, 125.0),
    ParameterSpec('temperature_calibration.high_c', _CHAMBER.high_c,
                  'Highest chamber plateau of calibrate_temperature [degC]', False,
                  -60.0, 125.0),
    ParameterSpec('temperature_calibration.period_s', _CHAMBER.period_s,
                  'Chamber program of calibrate_temperature (all plateaus, six-position '
                  'tumble) in sensor time [s], plus the soaks at the extremes and back to the '
                  'starting temperature (always run as fast as the CPU allows)' + CHAMBER_BOUND,
                  False, 60.0, CHAMBER_MAX_PERIOD_S),
    ParameterSpec('temperature_calibration.cycles', _CHAMBER.cycles,
                  'Chamber programs of calibrate_temperature' + CHAMBER_BOUND, False,
                  1, CHAMBER_MAX_CYCLES),
    ParameterSpec('temperature_calibration.reference_steps', True,
                  'Measure the I_ref step at every chamber plateau of calibrate_temperature '
                  'and store its temperature coefficient (what '
                  'estimation.feedback.temperature_correction needs)'),
    ParameterSpec('temperature_calibration.m_bits', _CHAMBER.m_bits,
                  'Fraction bits M of the fixed-point CORDIC zero-bias compensator (seed 2: '
                  '16; the scale factor uses 24); at least these: an axis whose fitted terms '
                  'cancel gets the bits they take beyond the 4 guard bits, up to 27', False,
                  8, 30),
    ParameterSpec('output_dir', '~/.ros/qfa_ros',
                  'Base directory of every trace and recording the node writes (~ expanded '
                  'once, at start); trace_dir and recorder.directory must stay inside it',
                  True),
    ParameterSpec('min_free_bytes', 1 << 30,
                  'Free space the node leaves on the file system of output_dir [bytes]: no '
                  'trace is written and the recorder stops (diagnostics ERROR) before the '
                  'free space falls under it', True, 1 << 20, 2 ** 50),
    ParameterSpec('trace_dir', 'traces',
                  'Directory of the estimation traces (MCAP), created when needed: relative '
                  'to output_dir, or absolute inside it (symlinks and .. resolved; ~ not '
                  'expanded)'),
    ParameterSpec('state_file', '~/.ros/qfa_ros/calibration.json',
                  'Persisted calibration state (JSON); empty: keep it in memory only', True),
    ParameterSpec('state.fresh', False,
                  'Start fresh: ignore state_file at start (not loaded: nominal words, no '
                  'compensation, no references); the next saved calibration replaces it',
                  True),
    ParameterSpec('recorder.enabled', False,
                  'Record imu/data_raw, imu/temperature and /diagnostics to MCAP'),
    ParameterSpec('recorder.directory', 'recordings',
                  'Directory of the flight recordings, created when needed: relative to '
                  'output_dir, or absolute inside it (symlinks and .. resolved; ~ not '
                  'expanded)'),
    ParameterSpec('recorder.max_bytes', 1 << 30,
                  'Start a new recording file before this size [bytes]', False,
                  1 << 20, 1 << 34),
    ParameterSpec('recorder.max_duration_s', 600.0,
                  'Start a new recording file after this long [s]', False, 1.0, 86400.0),
)

SPECS = {spec.name: spec for spec in PARAMETERS}

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

    :param parameter: An :class:`rclpy.parameter.Parameter`.
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
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'{name} must be a number'
    if isinstance(default, float) and not math.isfinite(value):
        return f'{name} must be finite, got {shown(value)}'
    if isinstance(default, int) and not isinstance(value, int):
        return f'{name} must be an integer'
    if spec.low is not None and not spec.low <= value <= spec.high:
        return f'{name} must be in [{spec.low:g}, {spec.high:g}], got {shown(value)}'
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
        if isinstance(element, bool) or not isinstance(element, (int, float)):
            return f'{name}[{index}] must be a number'
        if not math.isfinite(element):
            return f'{name}[{index}] must be finite, got {shown(element)}'
        if spec.low is not None and not spec.low <= element <= spec.high:
            return (f'{name}[{index}] must be in [{spec.low:g}, {spec.high:g}], '
                    f'got {shown(element)}')
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
            'room_amplitude_c': values['thermal.room_amplitude_c'],
            'room_correlation_s': values['thermal.room_correlation_s']}


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
                                   m_bits=values['temperature_calibration.m_bits'],
                                   reference_steps=values[
                                       'temperature_calibration.reference_steps'])


def unit_of(values):
    """Return the drawn :class:`~qfa_ros.model.unit.Unit` of ``unit.*``, or None.

    None also for ``sensor.error_profile: ideal`` (an ideal sensor is no drawn unit).
    """
    if not values['unit.draw'] or values['sensor.error_profile'] == 'ideal':
        return None
    seed = values['unit.seed']
    return draw_unit(values['seed'] if seed < 0 else seed)


def make_triad(values, profile=None, imu_noise=None):
    """
    Return the :class:`QfaTriad` of the parameter ``values``: the unit, its aging, errors.

    ``imu_noise`` is what :func:`load_imu_noise` read at start (None: the ``noise.*`` and
    ``gyro.*`` noise).

    The error sources of ``sensor.error_profile`` (:mod:`qfa_ros.model.errors`) act
    through the thermal model's body temperature, with the drawn unit's own component
    coefficients (its I_ref and forward-chain temperature coefficients).
    """
    unit = unit_of(values)
    triad = QfaTriad(triad_config(values, unit, imu_noise), rng=values['seed'],
                     profile=profile)
    errors = error_profile(values['sensor.error_profile'])
    if unit is not None:
        unit.install_aging(triad)
        unit.install_error_profile(triad, errors)
    else:
        errors.apply(triad)
    return triad


def triad_config(values, unit=False, imu_noise=None):
    """
    Return the :class:`TriadConfig` of the parameter ``values`` (ValueError names them).

    ``unit`` is the drawn unit (or None) when the caller has it already; by default it
    is drawn from ``unit.*``. ``imu_noise`` (an
    :class:`~qfa_ros.model.imu_noise.ImuNoiseFigures`, what ``noise.imu_yaml`` held)
    replaces the configured noise processes (:func:`~qfa_ros.model.imu_noise.emulated_config`).
    """
    config = _triad_config(values, unit)
    if imu_noise is None:
        return config
    with _named('noise.imu_yaml'):
        return emulated_config(config, imu_noise)


def _triad_config(values, unit):
    thermal = thermal_config(values)
    with _named('noise'):
        noise = NoiseConfig(noise_density=values['noise.density_ug_per_rthz'] * MICRO_G,
                            bias_instability=values['noise.bias_instability_ug'] * MICRO_G,
                            adc_noise=values['noise.adc_counts'])
    mrad = values['model.misalignment_mrad']
    misalignment = tuple(tuple(v * 1e-3 for v in mrad[3 * k:3 * k + 3]) for k in range(3))
    gyro = None
    if values['gyro.enabled']:
        with _named('gyro'):
            gyro = _GYRO.with_errors(
                arw=values['gyro.arw_deg_per_rthr'] * DEG_PER_ROOT_HOUR,
                bias_instability=values['gyro.bias_instability_deg_per_hr'] * DEG_PER_HOUR,
                rate_random_walk=values['gyro.rate_random_walk_deg_per_hr_per_rthr']
                * DEG_PER_HOUR / 60.0,
                turn_on_bias=values['gyro.turn_on_bias_deg_per_hr'] * DEG_PER_HOUR)
    with _named('sample_rate_hz / loop_rate_hz / model'):
        config = TriadConfig.from_datasheet(
            bias_ug=tuple(values['model.bias_ug']),
            k2_ug_per_g2=tuple(values['model.k2_ug_per_g2']),
            loop_rate_hz=values['loop_rate_hz'], sample_rate_hz=values['sample_rate_hz'],
            noise=noise, thermal=thermal, gyro=gyro, misalignment=misalignment)
    if values['sensor.error_profile'] == 'ideal':
        # Every source of the sensor off; the operator's model.* terms stay (injected).
        return dataclasses.replace(sensor_config('ideal', config), bias=config.bias,
                                   k2=config.k2, misalignment=config.misalignment)
    if unit is False:
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
            temperature_correction=values['estimation.feedback.temperature_correction'])


def gyro_bias_settings(values):
    """Return the :class:`GyroBiasSettings` of ``gyro_bias.*``, the location and heading."""
    with _named('gyro_bias'):
        return GyroBiasSettings(
            duration_s=values['gyro_bias.duration_s'], latitude_deg=values['latitude_deg'],
            yaw=values['input.yaw'],
            rate_limit=values['gyro_bias.motion_limit_deg_per_hr'] * DEG_PER_HOUR,
            accel_limit=values['gyro_bias.motion_limit_ug'] * MICRO_G)


def static_profile(values):
    """Return the body at rest at the location, ``input.roll`` / ``pitch`` / ``yaw``."""
    with _named('latitude_deg / longitude_deg / height_m'):
        return trajectories.static(values['latitude_deg'], values['longitude_deg'],
                                   values['height_m'], values['input.roll'],
                                   values['input.pitch'], values['input.yaw'])


def load_imu_noise(values):
    """
    Return the :class:`~qfa_ros.model.imu_noise.ImuNoiseFigures` of ``noise.imu_yaml``.

    None when the parameter is empty. Read once, at start, with the bounds of
    :func:`~qfa_ros.calibration.kalibr_yaml.load_imu_yaml`.

    :raises ValueError: The file cannot be used; the message names the parameter and
        never quotes the file.
    """
    path = values['noise.imu_yaml']
    if not path:
        return None
    with _named('noise.imu_yaml'):
        return kalibr_yaml.load_imu_yaml(os.path.expanduser(path))


def load_trajectory_file(values):
    """
    Return the :class:`~qfa_ros.model.trajectory.Trajectory` of ``input.trajectory_file``.

    None when the parameter is empty. Read once, at start, with the bounds of
    :func:`~qfa_ros.model.trajectories.load_csv`.

    :raises ValueError: The file cannot be used; the message names the parameter and
        never quotes the file.
    """
    path = values['input.trajectory_file']
    if not path:
        return None
    with _named('input.trajectory_file'):
        return trajectories.load_csv(os.path.expanduser(path))


def trajectory_input(values, start_s=0.0, trajectory_file=None):
    """
    Return the trajectory of ``input.trajectory``, starting at sensor time ``start_s``.

    ``trajectory_file`` is what :func:`load_trajectory_file` read at start.
    """
    kind = values['input.trajectory']
    with _named(f'input.trajectory {kind}'):
        if kind == 'file':
            if trajectory_file is None:
                raise ValueError('no trajectory file was read at start: input.trajectory_file '
                                 'is read-only, set it when the node starts')
            motion = trajectory_file
        else:
            motion = _script_trajectory(kind, values['latitude_deg'], values['longitude_deg'],
                                        values['height_m'], values['input.yaw'])
    return motion.shifted(start_s)


@functools.lru_cache(maxsize=4)
def _script_trajectory(kind, latitude_deg, longitude_deg, height_m, yaw):
    """
    Return a built-in motion script, cached.

    The drive takes 0.5 s to build, and every parameter check rebuilds the input.
    """
    return trajectories.SCRIPTS[kind](latitude_deg=latitude_deg, longitude_deg=longitude_deg,
                                      height_m=height_m, yaw=yaw)


def input_profile(values, start_s=0.0, trajectory_file=None):
    """Return the input of the ``static``, ``profile`` and ``trajectory`` modes.

    A trajectory starts at sensor time ``start_s`` (when it is selected);
    ``trajectory_file`` is what :func:`load_trajectory_file` read at start.
    """
    if values['input.mode'] == 'trajectory':
        return trajectory_input(values, start_s, trajectory_file)
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
        problem = forward_sweep_problem(forward_settings(values), config.hardware,
                                        values['drift.forward_ppm'])
        if problem:
            return problem
        feedback_settings(values)
        temperature_settings(values)
        input_profile(values, trajectory_file=trajectory_file)
        if not values['output_dir']:
            return 'output_dir must not be empty'
        for name in ('trace_dir', 'recorder.directory'):
            confined_directory(values, name)
    except (ValueError, OSError) as error:
        # OSError: a symlink loop or an unreadable component while resolving a directory.
        return str(error)
    return budget_problem(values['loop_rate_hz'], forward_settings(values),
                          feedback_settings(values), temperature_settings(values))


def _yaml_value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, list):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    return repr(value)


def config_yaml(node_name='/**'):
    """
    Return ``config/qfa.yaml``: every parameter with its default and description.

    Keyed ``/**`` (every node given the file), so that it applies to the node under any
    name and namespace (``ros2 launch qfa_ros qfa.launch.py namespace:=imu1``).
    """
    lines = ['# Every parameter of qfa_ros/node.py with its default (see docs/node.md).',
             '# Generated by `python -m qfa_ros.ros.params yaml`. Keyed /** so that it',
             '# applies under any node name and namespace. Doubles keep their decimal point',
             '# (the node also accepts 1000 for 1000.0; most ROS 2 nodes do not). The QoS of',
             '# the stream: qos_overrides./imu/data_raw.publisher.{history,depth,reliability}',
             '# and the same for /imu/temperature (docs/node.md).',
             f'{_yaml_value(node_name)}:', '  ros__parameters:']
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
            kind = f'double[{spec.length}]' if spec.length else f'double[≤{spec.max_length}]'
        limits = ''
        if spec.low is not None:
            limits = f'{spec.low} … {spec.high}' if isinstance(spec.default, int) \
                else f'{spec.low:g} … {spec.high:g}'
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
