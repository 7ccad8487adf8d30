"""
One unit of a self-calibration fleet study: drawn from its seed, aged, recalibrated, scored.

The unit is a default triad with the thermal model in a room (seasonal mean, wander with
a 12 h correlation, self-heating, :class:`~qfa_ros.model.error_profiles.PaperRoom`),
Ran et al.'s component temperature coefficients, and per-unit linear aging rates drawn from
the study's spreads. As a lab would, the I_ref temperature coefficient is measured once
in the chamber (when the schedule corrects for temperature), then the reference is
captured in the room; at every calibration the aging so far acts, the room has its
season, and the schedule runs through :func:`~qfa_ros.calibration.schedule.run_schedule`
exactly as in the node. The months between calibrations pass for the thermal model only
(:func:`~qfa_ros.calibration.chamber.idle`).

Scoring uses the model's truth, never given to the estimator: the scale-factor error is
the output scale measured with a known input on a noiseless twin
(:func:`~qfa_ros.calibration.experiments.measure_scale`, the one truth of every report)
relative to the reference capture [ppm]; the bias error is the mean static output minus
the known specific force [ug]; the forward and feedback truths are the observable channel
drifts the schedules estimate.
"""

from dataclasses import replace
from functools import partial
import math

import numpy as np

from qfa_ros.calibration.chamber import ChamberBench, idle
from qfa_ros.calibration.estimation import capture_reference, self_calibrate
from qfa_ros.calibration.experiments import (
    measure_scale,
    OBSERVABLE_FEEDBACK,
    OBSERVABLE_FORWARD,
    split_drift,
)
from qfa_ros.calibration.reference_tc import reference_tc_schedule
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.fleet.temperature_unit import simulate_temperature_unit
from qfa_ros.model import random_streams
from qfa_ros.model.constants import MICRO_G, PPM
from qfa_ros.model.drawn_unit import draw_component_tcs, install_component_tcs
from qfa_ros.model.error_profiles import error_profile, PaperRoom
from qfa_ros.model.thermal import ThermalConfig
from qfa_ros.model.triad import AXES, QfaTriad
from qfa_ros.model.triad_config import TriadConfig

DAYS_PER_YEAR = 365.25
SECONDS_PER_DAY = 86400.0
BIAS_WINDOW_S = 0.5
"""Static window that scores the bias before and after each calibration [s]."""

IDLE_STEP_S = 600.0
"""Thermal step while months pass between calibrations [s] (the room correlates over 12 h)."""

TORQUER_COMPONENT = 'l_coil'


def _profile(environment):
    profile = error_profile(environment.error_profile)
    if environment.magnet_tc_ppm is not None:
        profile = replace(profile, magnet_tc_ppm=environment.magnet_tc_ppm)
    # The study ages k_t itself; the profile keeps only its temperature coefficients.
    return replace(profile, torquer_drift_ppm=0.0)


def _static_error_ug(triad):
    out = triad.run_for(BIAS_WINDOW_S)
    return (out.accel.mean(axis=0) - out.truth.mean(axis=0)) / MICRO_G


def simulate_unit(study, index):
    """
    Simulate unit ``index`` of ``study``; return one row (a dict) per calibration.

    Parameters
    ----------
    study : qfa_ros.fleet.study.Study
        The validated study.
    index : int
        Unit index; its randomness comes from ``SeedSequence([study.seed, index])`` only,
        so a unit's rows do not depend on which worker ran it or in which batch.

    Returns
    -------
    list of dict
        Columns ``unit, calibration, time_days, body_c`` (body temperature [degC]) and
        per axis ``a`` in x, y, z:
        ``sf_before_ppm_a, sf_after_ppm_a, bias_before_ug_a, bias_after_ug_a,
        forward_estimate_ppm_a, forward_std_ppm_a, feedback_estimate_ppm_a,
        feedback_std_ppm_a, forward_truth_ppm_a, feedback_truth_ppm_a``, plus
        ``schedule_s`` (sensor time of the self-calibration).
    """
    root = np.random.SeedSequence([study.seed, index])
    rng = random_streams.generator(root, 'unit.draws')
    environment = study.environment
    room = PaperRoom()
    season_c = partial(_season_c, environment, rng.uniform(0.0, 2.0 * math.pi))
    triad = _unit_triad(environment, root, season_c, room)
    schedule = study.schedule_settings()
    aging = study.aging
    rates = [{
        **split_drift(rng, aging.draw(rng, aging.forward_ppm_per_year), OBSERVABLE_FORWARD),
        **split_drift(rng, aging.draw(rng, aging.feedback_ppm_per_year), OBSERVABLE_FEEDBACK),
        TORQUER_COMPONENT: aging.draw(rng, aging.torquer_ppm_per_year)} for _ in AXES]

    state = CalibrationState()
    reference = _capture_reference(triad, state, schedule, season_c, room)
    rows = []
    for calibration in range(1, study.calibrations + 1):
        days = calibration * study.calibration_interval_days
        triad.thermal.set_ambient(ambient_profile='room',
                                  ambient_c=season_c(days) + room.self_heating_c)
        idle(triad, study.calibration_interval_days * SECONDS_PER_DAY, IDLE_STEP_S)
        for axis, axis_rates in enumerate(rates):
            for component, rate in axis_rates.items():
                triad.drift.set_step(axis, component, rate * days / DAYS_PER_YEAR * PPM)
        row = {'unit': index, 'calibration': calibration, 'time_days': days}
        rows.append(_calibrate_and_score(triad, state, schedule, reference, row))
    return rows


def _season_c(environment, phase, days):
    """Return the room's seasonal mean [degC] ``days`` into the study (``phase`` [rad])."""
    return environment.room_c + environment.seasonal_amplitude_c * math.sin(
        2.0 * math.pi * days / DAYS_PER_YEAR + phase)


def _unit_triad(environment, root, season_c, room):
    """Return the unit's triad in the room, with its component temperature coefficients."""
    # No gyro triad: a study scores the accelerometers, and the gyros' random stream is
    # a named child apart from theirs (QfaTriad), so leaving them out changes no
    # accelerometer sample and saves a quarter of the unit's cost.
    config = TriadConfig(gyro=None, thermal=ThermalConfig(
        ambient_profile='room', ambient_c=season_c(0.0) + room.self_heating_c,
        room_amplitude_c=environment.wander_c, room_correlation_s=room.room_correlation_s,
        initial_sensor_c=season_c(0.0)))
    triad = QfaTriad(config, rng=random_streams.generator(root, 'unit.model'))
    if environment.component_tcs == 'drawn':
        # The unit's own coefficients, from a stream keyed apart from the others.
        i_ref, forward = draw_component_tcs(
            random_streams.seed_sequence(root, 'unit.component_tcs'))
        install_component_tcs(triad, _profile(environment), i_ref, forward)
    else:
        _profile(environment).apply(triad)
    return triad


def _capture_reference(triad, state, schedule, season_c, room):
    """
    Capture the unit's reference in the room, as a lab would.

    Returns
    -------
    tuple
        The output scale (:func:`measure_scale`), each axis's gains and controller gain
        k(D(z)) at the capture: what the calibrations are scored against.
    """
    if schedule.feedback.temperature_correction:
        # Production: the I_ref temperature coefficient, measured once in the chamber.
        run_schedule(triad, reference_tc_schedule(triad, ChamberBench(triad), state))
    triad.thermal.set_ambient(ambient_profile='room',
                              ambient_c=season_c(0.0) + room.self_heating_c)
    idle(triad, room.warm_up_s)
    triad.run_for(0.2)
    run_schedule(triad, capture_reference(triad, state, schedule.forward,
                                          schedule.reference_feedback))
    # The open-loop readout dN_out/dN_FPGA includes k(D(z)) (Ran et al. 2019, eq. 19-22), so the
    # forward truth is the chain times the controller gain, relative to the reference.
    return (measure_scale(triad), [loop.gains for loop in triad.axes],
            [loop.controller.gain for loop in triad.axes])


def _calibrate_and_score(triad, state, schedule, reference, row):
    """
    Self-calibrate the aged unit once and score it against ``reference``.

    Parameters
    ----------
    triad, state, schedule
        The unit, its calibration state and the study's schedule settings.
    reference : tuple
        What :func:`_capture_reference` returned.
    row : dict
        The row's unit, calibration and time columns, completed and returned.

    Returns
    -------
    dict
        The row of :func:`simulate_unit`.
    """
    scale_reference, reference_gains, reference_controller_gain = reference
    triad.run_for(0.2)
    drifted = [loop.gains for loop in triad.axes]
    controller_gain = [loop.controller.gain for loop in triad.axes]
    bias_before = _static_error_ug(triad)
    scale_before = measure_scale(triad) / scale_reference - 1
    forward, feedback = run_schedule(
        triad, self_calibrate(triad, state, schedule.forward, schedule.feedback))
    scale_after = measure_scale(triad) / scale_reference - 1
    bias_after = _static_error_ug(triad)
    row.update({'body_c': float(triad.thermal.sensor_c),
                'schedule_s': forward.duration_s + feedback.duration_s})
    for axis, name in enumerate(AXES):
        ref, now = reference_gains[axis], drifted[axis]
        row[f'sf_before_ppm_{name}'] = float(scale_before[axis]) / PPM
        row[f'sf_after_ppm_{name}'] = float(scale_after[axis]) / PPM
        row[f'bias_before_ug_{name}'] = float(bias_before[axis])
        row[f'bias_after_ug_{name}'] = float(bias_after[axis])
        row[f'forward_truth_ppm_{name}'] = (
            now.open_loop_counts_per_fpga * controller_gain[axis]
            / (ref.open_loop_counts_per_fpga * reference_controller_gain[axis]) - 1) / PPM
        row[f'feedback_truth_ppm_{name}'] = (now.k_da2_vi / ref.k_da2_vi - 1) / PPM
        row[f'forward_estimate_ppm_{name}'] = float(forward.estimate_ppm[axis])
        row[f'forward_std_ppm_{name}'] = float(forward.std_error_ppm[axis])
        row[f'feedback_estimate_ppm_{name}'] = float(feedback.estimate_ppm[axis])
        row[f'feedback_std_ppm_{name}'] = float(feedback.std_error_ppm[axis])
    return row


def simulate_batch(study, start, stop):
    """Return the rows of units ``start`` to ``stop - 1`` in unit order."""
    simulate = simulate_temperature_unit if study.kind == 'temperature' else simulate_unit
    return [row for index in range(start, stop) for row in simulate(study, index)]
