"""
Ran et al.'s experiment (§IV) and the Monte Carlo comparison of estimation schedules.

The error sources (:class:`ErrorProfile`) and the paper's room (:class:`PaperRoom`) are
physics and live in :mod:`qfa_ros.model.error_profiles`; they are re-exported here.
"""

import copy
from dataclasses import dataclass, replace
import math

import numpy as np
from tqdm import tqdm

from qfa_ros.calibration.chamber import DIAGONAL, idle
from qfa_ros.calibration.estimation import (
    capture_reference,
    FeedbackSettings,
    ForwardSettings,
    self_calibrate,
)
from qfa_ros.calibration.schedule import run_schedule
from qfa_ros.calibration.state import CalibrationState
from qfa_ros.model import random_streams
from qfa_ros.model.constants import MICRO_G, PPM, STANDARD_GRAVITY
from qfa_ros.model.error_profiles import ErrorProfile, PaperRoom
from qfa_ros.model.triad import AXES, QfaTriad
from qfa_ros.model.triad_config import TriadConfig

OBSERVABLE_FORWARD = ('v_da1_ref', 'k_tz', 'k_amp', 'v_ad_ref')
OBSERVABLE_FEEDBACK = ('v_da2_ref', 'k_vi')


def split_drift(rng, total, components):
    """
    Split a channel drift ``total`` over its ``components`` with Dirichlet weights.

    Returns ``{component: relative drift}`` whose effects on the channel gain add up to
    ``total``: the sign of ``v_ad_ref`` is flipped because ``k_AD = 1 / V_AD_ref``.
    """
    weights = rng.dirichlet(np.ones(len(components)))
    return {c: (-1.0 if c == 'v_ad_ref' else 1.0) * w * total
            for c, w in zip(components, weights)}


@dataclass
class PaperTrial:
    """One trial of Ran et al. 2019, §IV-A (z axis, level sensor, 1 g); counts and micro-g."""

    forward_reference: float
    forward_drifted: float
    forward_estimate_ppm: float
    feedback_reference: float
    feedback_drifted: float
    feedback_estimate_ppm: float
    output_reference: float
    output_drifted: float
    output_compensated: float
    scale_error_drifted_ppm: float = math.nan
    scale_error_after_ppm: float = math.nan
    feedback_std_error_ppm: float = math.nan

    @property
    def drifted_error_ug(self):
        """N'_out(1) - N_out(0) [micro-g]."""
        return (self.output_drifted - self.output_reference) / MICRO_G

    @property
    def compensated_error_ug(self):
        """N_out(1) - N_out(0) [micro-g]."""
        return (self.output_compensated - self.output_reference) / MICRO_G


def measure_scale(triad, seconds=0.5, settle_s=0.05):
    """
    Measure the output scale of each axis with a known input, on a noiseless twin [1].

    A deep copy of the sensor (same words, drift, temperature and thermal state) with
    its acceleration noise off is driven with ``+-g / sqrt(3)`` on every axis;
    ``(N_+ - N_-) k_nom / (2 g / sqrt(3))`` is the scale the user gets (1 = nominal).
    The converter's ADC noise stays (it dithers the quantization). This is the one
    definition of truth of every report here; the sensor itself is not advanced.
    """
    twin = copy.deepcopy(triad)
    quiet = replace(twin.config.noise, noise_density=0.0, bias_instability=0.0)
    twin.set_noise(quiet, 0)
    n_settle = int(round(settle_s * twin.config.sample_rate_hz))
    n = int(round(seconds * twin.config.sample_rate_hz))
    levels = []
    for sign in (1, -1):
        force = np.tile(sign * STANDARD_GRAVITY * DIAGONAL, (n_settle + n, 1))
        out = twin.run(n_settle + n, force)
        levels.append(out.counts[n_settle:].mean(axis=0))
    return (levels[0] - levels[1]) * twin.scale / (2.0 * STANDARD_GRAVITY * DIAGONAL)


def paper_experiment(seed=0, trials=6, forward_ppm=-200.0, feedback_ppm=200.0,
                     profile=ErrorProfile(), room=PaperRoom(), static_s=10.0,
                     forward=ForwardSettings(), feedback=FeedbackSettings(), recorder=None,
                     progress=False, start_ns=0):
    """
    Run Ran et al. 2019, §IV-A steps 1-5 ``trials`` times; return the :class:`PaperTrial` list.

    Per trial, a fresh sensor of the same design (seeded per trial) in the paper's room
    (:class:`PaperRoom`: wander, warm-up): (1) capture the references after the
    warm-up; (2) static output N_out(0); (3) ``trial_gap_s`` later, ``forward_ppm`` on
    the in-amp gain and ``feedback_ppm`` on the V/I sense resistor (the paper changed
    resistors: ``k_VI = 1/R`` falls, ``|N_on - N_off|`` grows as in its Table 4);
    static output N'_out(1) without compensation; (4) self-estimation and
    compensation, static output N_out(1). The profile's temperature coefficients act
    on the body temperature the room and the warm-up give. Each trial also records
    the output scale (:func:`measure_scale`) at the reference, drifted and after
    compensation. A ``recorder`` (:class:`qfa_ros.bag.scenario_bag.ScenarioBag`)
    receives the first trial: its phases, static outputs and estimation traces, stamped
    from ``start_ns`` (the triads' stamp origin [ns], default 0).
    """
    results = []
    root = np.random.SeedSequence(seed)
    for number in tqdm(range(trials), desc='paper trials', disable=not progress):
        record = recorder if number == 0 else None
        triad = QfaTriad(TriadConfig(thermal=room.thermal_config()),
                         rng=random_streams.generator(root, 'paper.trial', number),
                         start_ns=start_ns)
        profile.apply(triad)
        state = CalibrationState()
        idle(triad, room.warm_up_s)
        triad.run_for(1.0)
        forward_ref, feedback_ref = run_schedule(
            triad, capture_reference(triad, state, forward, feedback))
        scale_reference = measure_scale(triad)
        reference = _static_phase(triad, static_s, 'reference', record)
        idle(triad, room.trial_gap_s)
        for axis in range(len(AXES)):
            triad.drift.set_step(axis, 'k_amp', forward_ppm * PPM)
            triad.drift.set_step(axis, 'k_vi', 1.0 / (1.0 + feedback_ppm * PPM) - 1.0)
        triad.run_for(0.5)
        scale_drifted = measure_scale(triad)
        drifted = _static_phase(triad, static_s, 'drifted', record)
        if record:
            record.write_phase('estimation', triad.stamp_ns(triad.sample_index))
        forward_est, feedback_est = run_schedule(
            triad, self_calibrate(triad, state, forward, feedback))
        scale_after = measure_scale(triad)
        compensated = _static_phase(triad, static_s, 'compensated', record)
        if record:
            record.write_trace('reference', 'reference', (forward_ref, feedback_ref))
            record.write_trace('self_calibrate', 'self_calibrate', (forward_est, feedback_est))
        results.append(PaperTrial(
            forward_reference=forward_ref.measured[2], forward_drifted=forward_est.measured[2],
            forward_estimate_ppm=forward_est.estimate_ppm[2],
            feedback_reference=feedback_ref.measured[2],
            feedback_drifted=feedback_est.measured[2],
            # Table 4 states the drift as the change of the on/off step.
            feedback_estimate_ppm=(feedback_est.measured[2] / feedback_est.reference[2] - 1)
            / PPM,
            output_reference=reference, output_drifted=drifted, output_compensated=compensated,
            scale_error_drifted_ppm=(scale_drifted[2] / scale_reference[2] - 1) / PPM,
            scale_error_after_ppm=(scale_after[2] / scale_reference[2] - 1) / PPM,
            feedback_std_error_ppm=float(np.hypot(feedback_est.std_error_ppm[2],
                                                  feedback_ref.std_error_ppm[2]))))
    return results


def _static_phase(triad, seconds, name, recorder):
    """Run a static measurement and return the z-axis mean [m/s^2]; record it if asked."""
    if recorder:
        recorder.write_phase(name, triad.stamp_ns(triad.sample_index))
    output = triad.run_for(seconds)
    if recorder:
        recorder.write_imu(output)
        once_a_second = slice(int(triad.config.sample_rate_hz) - 1, None,
                              int(triad.config.sample_rate_hz))
        recorder.write_temperature(output.stamps_ns[once_a_second],
                                   output.temperature[once_a_second])
    return output.accel[:, 2].mean()


def format_paper_tables(trials, forward_ppm=-200.0, feedback_ppm=200.0):
    """Return Ran et al. 2019, Tables 3-4 and the eq. 31 comparison as Markdown text."""
    lines = _gain_table('Table 3 - Eq-forward-gain (dN_out/dN_FPGA, z axis)',
                        ('k_pre-eq0', 'k_pre-eq1', 'dk_pre'), 4, forward_ppm,
                        [(t.forward_reference, t.forward_drifted, t.forward_estimate_ppm)
                         for t in trials])
    lines += [''] + _gain_table(
        'Table 4 - feedback gain (N_out-on - N_out-off [count], z axis)',
        ('k_VI0 k_DA0', 'k_VI1 k_DA1', 'dk_fb'), 2, feedback_ppm,
        [(t.feedback_reference, t.feedback_drifted, t.feedback_estimate_ppm) for t in trials])
    mean_f = np.mean([t.forward_estimate_ppm for t in trials])
    mean_b = np.mean([t.feedback_estimate_ppm for t in trials])
    drifted = np.mean([abs(t.drifted_error_ug) for t in trials])
    compensated = np.mean([abs(t.compensated_error_ug) for t in trials])
    restrained = 100 * (1 - compensated / drifted)
    lines += ['', 'Eq. 31 - static output error against N_out(0) (z axis, 1 g), mean of |.|',
              '', '| | error (ug) |', '|---|---|',
              f"| N'_out(1) - N_out(0), drifted | {drifted:.1f} |",
              f'| N_out(1) - N_out(0), compensated | {compensated:.1f} |',
              f'| residual error (eq. 31) | {100 * compensated / drifted:.2f} % |',
              f'| output error restrained | {restrained:.2f} % |',
              '',
              f'forward drift estimated {100 - _residual(mean_f, forward_ppm):.2f} % '
              f'(Ran et al. 2019: 90.26 %); feedback '
              f'{100 - _residual(mean_b, feedback_ppm):.2f} % (Ran et al. 2019: 90.92 %); '
              f'output error restrained {restrained:.2f} % (Ran et al. 2019: 87.56 %)']
    return '\n'.join(lines)


def _gain_table(title, names, decimals, injected_ppm, rows):
    """Return one table of Ran et al. 2019, Tables 3-4: reference, drifted, estimate, residual."""
    lines = [title, '', f'| trial | {names[0]} | {names[1]} | {names[2]} (ppm) | residual |',
             '|---|---|---|---|---|']
    rows = np.asarray(rows, dtype=float)
    labelled = [(str(i), row) for i, row in enumerate(rows, 1)] + [('mean', rows.mean(axis=0))]
    for label, (reference, drifted, estimate) in labelled:
        lines.append(f'| {label} | {reference:.{decimals}f} | {drifted:.{decimals}f} | '
                     f'{estimate:+.2f} | {_residual(estimate, injected_ppm):.2f} % |')
    return lines


def _residual(estimate, injected):
    return 100.0 * abs((estimate - injected) / injected)


# Monte Carlo ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Schedule:
    """
    A named pair of forward and feedback settings.

    ``capture_feedback`` (default: ``feedback``) is used for the reference capture,
    which happens once in the initial state and may average longer than an
    in-service estimation.
    """

    name: str
    forward: ForwardSettings
    feedback: FeedbackSettings
    capture_feedback: FeedbackSettings = None

    @property
    def reference_feedback(self):
        """Return the feedback settings of the reference capture."""
        return self.capture_feedback or self.feedback


PAPER_SCHEDULE = Schedule('paper', ForwardSettings(), FeedbackSettings())
IMPROVED_SCHEDULE = Schedule(
    'improved',
    ForwardSettings(points=10, step=1024, settle_s=0.005, average_s=0.245,
                    order='bidirectional'),
    FeedbackSettings(cycles=16, settle_s=0.02, average_s=0.28, order='chopped',
                     temperature_correction=True),
    FeedbackSettings(cycles=32, settle_s=0.02, average_s=0.28, order='chopped'))
