"""
The model and schedule settings of a set of parameter values, and the files named at start.

Each builder takes the values by name (every parameter of
:data:`~qfa_ros.ros.parameter_table.PARAMETERS`) and raises a ``ValueError`` that names the
parameters it comes from.
"""

from contextlib import contextmanager
import dataclasses
import functools
import os

from qfa_ros.calibration import kalibr_yaml
from qfa_ros.calibration.estimation import FeedbackSettings, ForwardSettings
from qfa_ros.calibration.gyro_bias import GyroBiasSettings
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model import motion_scripts
from qfa_ros.model.constants import DEG_PER_HOUR, DEG_PER_ROOT_HOUR, MICRO_G
from qfa_ros.model.drawn_unit import draw_unit
from qfa_ros.model.error_profiles import error_profile, sensor_config
from qfa_ros.model.gyro import GyroConfig
from qfa_ros.model.input_profiles import SineProfile, StepProfile, tumble_profile
from qfa_ros.model.noise import NoiseConfig
from qfa_ros.model.noise_figures import emulated_config
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig

_GYRO = GyroConfig()


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
    """Return the drawn :class:`~qfa_ros.model.drawn_unit.Unit` of ``unit.*``, or None.

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

    The error sources of ``sensor.error_profile`` (:mod:`qfa_ros.model.error_profiles`) act
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
    :class:`~qfa_ros.model.noise_figures.ImuNoiseFigures`, what ``noise.imu_yaml`` held)
    replaces the configured noise processes (:func:`~qfa_ros.model.noise_figures.emulated_config`).
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
        return motion_scripts.static(values['latitude_deg'], values['longitude_deg'],
                                   values['height_m'], values['input.roll'],
                                   values['input.pitch'], values['input.yaw'])


def load_imu_noise(values):
    """
    Return the :class:`~qfa_ros.model.noise_figures.ImuNoiseFigures` of ``noise.imu_yaml``.

    None when the parameter is empty. Read once, at start, with the bounds of
    :func:`~qfa_ros.calibration.kalibr_yaml.load_imu_yaml`.

    Raises
    ------
    ValueError
        The file cannot be used; the message names the parameter and never quotes the file.
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
    :func:`~qfa_ros.model.motion_scripts.load_csv`.

    Raises
    ------
    ValueError
        The file cannot be used; the message names the parameter and never quotes the file.
    """
    path = values['input.trajectory_file']
    if not path:
        return None
    with _named('input.trajectory_file'):
        return motion_scripts.load_csv(os.path.expanduser(path))


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
    return motion_scripts.SCRIPTS[kind](latitude_deg=latitude_deg, longitude_deg=longitude_deg,
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
