"""
One unit of a temperature-calibration study: drawn, calibrated in the chamber, verified.

The unit is :func:`~qfa_ros.model.drawn_unit.draw_unit` of a seed derived from the study's
(``SeedSequence([seed, index])``; reported as ``unit_seed``, the node's ``unit.seed``),
with the study's error profile and its own component coefficients, on the study's sensor
(``sensor.*``: body time constant, loop and output rates). It runs the temperature
calibration with the I_ref steps at every plateau (what ``~/calibrate_temperature`` runs,
:func:`~qfa_ros.calibration.temperature.temperature_calibration`) and is verified in the
eight attitudes of :data:`~qfa_ros.calibration.verification.ATTITUDES` at constant
chamber temperatures off the calibration's 10 degC grid
(:func:`~qfa_ros.calibration.verification.verify_attitudes`). Scoring uses the model's
truth (the known input), never given to the calibration.
"""

import time

import numpy as np

from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.calibration.temperature import temperature_calibration
from qfa_ros.calibration.verification import ATTITUDES, verify_attitudes
from qfa_ros.model import random_streams
from qfa_ros.model.constants import MICRO_G, PPM
from qfa_ros.model.drawn_unit import draw_unit
from qfa_ros.model.error_profiles import error_profile
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES
from qfa_ros.model.triad_config import TriadConfig

SOAK_TIME_CONSTANTS = 10.0
"""Soak before each verification temperature, in body time constants."""


def attitude_key(name):
    """Return the column stem of an attitude name (``roll +90`` -> ``roll_p90``)."""
    return name.replace(' +', '_p').replace(' -', '_m').replace(' ', '_')


def unit_seed(study, index):
    """Return the ``draw_unit`` seed of unit ``index`` of ``study``."""
    return int(np.random.SeedSequence([study.seed, index]).generate_state(1)[0])


def simulate_temperature_unit(study, index):
    """
    Calibrate and verify unit ``index`` of a temperature ``study``; return one row.

    Columns: ``unit, calibration`` (1), ``unit_seed``, ``probe_tau_s`` (the unit's true
    probe lag) and ``probe_lag_s`` (the calibration's estimate) [s], ``cpu_s`` (process
    time of this unit: the one column that is not reproducible), and per axis ``a``:
    ``zd_<attitude>_ug_a`` (zero-drift p2p over the verification temperatures per
    attitude), ``zd_max_ug_a`` (the worst attitude), ``sf_p2p_ppm_a`` and
    ``sf_max_ppm_a`` (p2p and largest |error| of the axis's +-g scale factor over the
    temperatures).
    """
    started = time.process_time()
    seed = unit_seed(study, index)
    unit = draw_unit(seed)
    sensor = {'sensor_tau_s': 300.0, **study.sensor}
    rates = {k: v for k, v in sensor.items() if k != 'sensor_tau_s'}
    config = TriadConfig(gyro=None, thermal=ThermalConfig(
        ambient_profile='constant', ambient_c=study.environment.room_c,
        initial_sensor_c=study.environment.room_c, sensor_tau_s=sensor['sensor_tau_s']),
        **rates)
    triad = unit.triad(config, rng=random_streams.generator(
        np.random.SeedSequence([study.seed, index]), 'unit.model'))
    unit.install_error_profile(triad, error_profile(study.environment.error_profile))
    settings = study.temperature_settings()
    state = CalibrationState()
    result = run_schedule(triad, temperature_calibration(triad, state, settings))[0]
    verification = verify_attitudes(
        triad, soak_s=SOAK_TIME_CONSTANTS * sensor['sensor_tau_s'],
        **study.verification)
    row = {'unit': index, 'calibration': 1, 'unit_seed': seed,
           'probe_tau_s': float(unit.probe_tau_s), 'probe_lag_s': float(result.probe_lag_s)}
    for (name, *_), p2p in zip(ATTITUDES, verification.zero_drift_p2p):
        for axis, value in zip(AXES, p2p):
            row[f'zd_{attitude_key(name)}_ug_{axis}'] = float(value / MICRO_G)
    for i, axis in enumerate(AXES):
        row[f'zd_max_ug_{axis}'] = float(verification.zero_drift_p2p[:, i].max() / MICRO_G)
        row[f'sf_p2p_ppm_{axis}'] = float(verification.scale_p2p[i] / PPM)
        row[f'sf_max_ppm_{axis}'] = float(verification.scale_max[i] / PPM)
    row['cpu_s'] = time.process_time() - started
    return [row]
