"""
Measure the loop's margins, bandwidth and step response on the simulated loop.

The design (:mod:`qfa_ros.model.design`) *solves* for ``|L| = 1`` at the crossover; this
module *measures* what the compiled kernel (:func:`qfa_ros.model.kernel.run_axis`, through
:class:`qfa_ros.model.axis.AxisLoop`: integer PID, exact ZOH pendulum, ADC and DA2
quantization, one step of computation delay, noise drawn in the loop) does, as a bench
would on the real sensor:

* **Loop breaking** (the classical injection measurement). A periodic logarithmic chirp
  ``r`` [m/s^2] enters as input acceleration, i.e. as the moment ``K0 r`` at the summing
  point in front of the pendulum, where the feedback moment ``f = -k_fb N_DA2[n-1]``
  arrives. With ``u = K0 r + f`` the moment leaving the summing point, going once round
  the loop gives ``f = -L u``, so ``L = -F/U``; both are estimated against the injection
  (``L = -S_rf / S_ru``, cross-spectra with ``scipy.signal.csd``, one boxcar segment per
  chirp period, so every bin is leakage-free and the loop's own noise averages out).
  The same run gives the closed-loop response ``T = S_ry / S_rr`` from input to output
  ``y = N_DA2 k_fb,nom / K0`` [m/s^2].
* **Step**: a periodic square wave of acceleration, averaged over its periods, gives
  the overshoot, the 10-90 % rise time and the 2 % settling time.

Uncertainties come from the spread of the per-period estimates (standard error of the
mean over periods) plus the interpolation between frequency bins.
"""

from dataclasses import dataclass
import math

import numpy as np

from qfa_ros.model.axis import AxisLoop
from qfa_ros.model.constants import STANDARD_GRAVITY
from qfa_ros.model.design import LinearLoop
from qfa_ros.model.hardware import counts_to_accel
from qfa_ros.model.noise import NoiseSource


@dataclass(frozen=True)
class LoopMeasurement:
    """
    Frequency response measured on the simulated loop.

    Attributes
    ----------
    freq_hz : float64[k]
        Frequency bins [Hz] (multiples of ``loop_rate / period``) inside the chirp band.
    loop_gain : complex128[k]
        Measured open-loop gain ``L`` (mean over the chirp periods).
    closed_loop : complex128[k]
        Measured closed-loop response output/input [(m/s^2)/(m/s^2)].
    loop_gain_se : float64[k]
        Standard error of ``L`` over the periods (absolute, complex magnitude).
    closed_loop_se : float64[k]
        Standard error of the closed-loop response over the periods.
    periods : int
        Chirp periods averaged.
    """

    freq_hz: np.ndarray
    loop_gain: np.ndarray
    closed_loop: np.ndarray
    loop_gain_se: np.ndarray
    closed_loop_se: np.ndarray
    periods: int

    def margins(self):
        """
        Return the figures read off the measured response, with their uncertainties.

        Returns
        -------
        LoopMargins
            Crossover (the last bin pair where ``|L|`` crosses 1, log-log
            interpolated), phase margin ``180 deg + arg L`` there, gain margin
            ``-20 log10 |L|`` at the first -180 deg crossing above it, and the
            closed-loop -3 dB bandwidth (first bin pair where ``|T|`` falls through
            ``1/sqrt(2)``).
        """
        f = self.freq_hz
        mag = np.abs(self.loop_gain)
        above = np.nonzero(np.diff(np.sign(mag - 1.0)))[0]
        if not len(above):
            raise ValueError('|L| does not cross 1 inside the chirp band')
        i = above[-1]
        w = _log_fraction(mag[i], mag[i + 1], 1.0)
        crossover = _log_interp(f[i], f[i + 1], w)
        phase = np.unwrap(np.angle(self.loop_gain[i:]))
        phase -= 2 * math.pi * round(phase[0] / (2 * math.pi))
        phase_at = phase[0] + w * (phase[1] - phase[0])
        phase_margin = 180.0 + math.degrees(phase_at)
        # Uncertainty: the standard error of arg L at the two bins (|dL|/|L|) and the
        # linear interpolation's error bound, a quarter of the phase step over the bin
        # pair times its curvature share (taken as the whole step: conservative).
        rel = self.loop_gain_se[i:i + 2] / mag[i:i + 2]
        phase_se = math.degrees(float(np.max(rel)))
        phase_interp = 0.25 * abs(math.degrees(phase[1] - phase[0]))
        crossover_se = float(np.max(rel)) * crossover / max(
            abs(math.log(mag[i + 1] / mag[i]) / math.log(f[i + 1] / f[i])), 1e-12)
        turns = np.nonzero(np.diff(np.sign(phase + math.pi)))[0]
        if len(turns):
            j = turns[0]
            u = (-math.pi - phase[j]) / (phase[j + 1] - phase[j])
            gain_at = math.exp(math.log(mag[i + j]) + u * (math.log(mag[i + j + 1])
                                                          - math.log(mag[i + j])))
            phase_crossover = _log_interp(f[i + j], f[i + j + 1], u)
            gain_margin = -20 * math.log10(gain_at)
            gain_margin_se = 20 / math.log(10) * float(
                np.max(self.loop_gain_se[i + j:i + j + 2] / mag[i + j:i + j + 2]))
        else:
            phase_crossover, gain_margin, gain_margin_se = math.inf, math.inf, 0.0
        closed = np.abs(self.closed_loop)
        drops = np.nonzero((closed[:-1] >= 1 / math.sqrt(2)) & (closed[1:] < 1 / math.sqrt(2)))[0]
        if len(drops):
            k = drops[0]
            bandwidth = _log_interp(f[k], f[k + 1],
                                    _log_fraction(closed[k], closed[k + 1], 1 / math.sqrt(2)))
            slope = abs(math.log(closed[k + 1] / closed[k]) / math.log(f[k + 1] / f[k]))
            bandwidth_se = float(np.max(self.closed_loop_se[k:k + 2] / closed[k:k + 2])) \
                * bandwidth / max(slope, 1e-12)
        else:
            bandwidth, bandwidth_se = math.inf, 0.0
        return LoopMargins(crossover, crossover_se, phase_margin, phase_se + phase_interp,
                           gain_margin, gain_margin_se, phase_crossover, bandwidth,
                           bandwidth_se, float(f[1] - f[0]))


@dataclass(frozen=True)
class LoopMargins:
    """
    Loop figures measured on the simulated loop, each with its uncertainty (1 sigma + bound).

    Attributes
    ----------
    crossover_hz, crossover_se_hz : float
        Gain crossover ``|L| = 1`` [Hz].
    phase_margin_deg, phase_margin_se_deg : float
        Phase margin [deg]; the uncertainty adds the interpolation bound.
    gain_margin_db, gain_margin_se_db : float
        Gain margin [dB] at the phase crossover (inf if none in the band).
    phase_crossover_hz : float
        Where ``arg L = -180 deg`` above the gain crossover [Hz].
    bandwidth_hz, bandwidth_se_hz : float
        Closed-loop -3 dB bandwidth [Hz].
    resolution_hz : float
        Bin spacing of the measurement [Hz].
    """

    crossover_hz: float
    crossover_se_hz: float
    phase_margin_deg: float
    phase_margin_se_deg: float
    gain_margin_db: float
    gain_margin_se_db: float
    phase_crossover_hz: float
    bandwidth_hz: float
    bandwidth_se_hz: float
    resolution_hz: float


@dataclass(frozen=True)
class StepMeasurement:
    """
    Step response measured on the simulated loop (mean over the square wave's edges).

    Attributes
    ----------
    time_s : float64[m]
        Time after the input step [s], at the loop rate.
    response : float64[m]
        Mean output over the rising edges, normalized to the step (0 before, 1 settled).
    response_se : float64[m]
        Its standard error over the edges.
    overshoot, overshoot_se : float
        Peak over the settled value, as a fraction of the step.
    rise_time_s : float
        10 % to 90 % rise time [s] (linear interpolation between loop steps).
    settling_time_s : float
        Time after which the response stays within ``settle_band`` of 1 [s].
    settle_band : float
        Band of the settling time (fraction of the step).
    edges : int
        Rising edges averaged.
    """

    time_s: np.ndarray
    response: np.ndarray
    response_se: np.ndarray
    overshoot: float
    overshoot_se: float
    rise_time_s: float
    settling_time_s: float
    settle_band: float
    edges: int


def _log_fraction(a, b, level):
    # Fraction of the way from a to b (log scale) at which ``level`` is reached.
    return math.log(level / a) / math.log(b / a)


def _log_interp(f0, f1, w):
    return math.exp(math.log(f0) + w * (math.log(f1) - math.log(f0)))


def _loop(config, rng, controller):
    if config.decimation < 1:
        raise ValueError('config.decimation must be >= 1')
    # One axis at the loop rate (decimation 1): the command of every loop step is seen.
    noise = NoiseSource(config.noise, 1, config.loop_rate_hz, config.loop_rate_hz,
                        np.random.default_rng(rng))
    loop = AxisLoop(config, noise, 0)
    if controller is not None:
        loop.controller = controller
    loop.update({})
    return loop


def _run(loop, accel):
    # Kernel over one per-step input [m/s^2]: unit scale, no offset, decimation 1.
    counts = np.zeros(len(accel))
    flags = np.zeros(len(accel), dtype=np.int8)
    loop.run(np.ascontiguousarray(accel, dtype=float), np.ones(1), np.zeros(1), 1,
             counts, flags)
    if flags.any():
        raise ValueError('the excitation saturated the loop (flags set); lower its amplitude')
    return counts


def measure_loop(config, rng=0, controller=None, amplitude=0.2 * STANDARD_GRAVITY,
                 band_hz=(10.0, None), period_steps=2 ** 14, periods=8, settle_periods=1):
    """
    Measure ``L`` and the closed-loop response of one simulated axis by loop breaking.

    Parameters
    ----------
    config : qfa_ros.model.triad_config.TriadConfig
        Loop rate, hardware, controller targets and noise (noise on: it averages out).
    rng : int or numpy.random.Generator
        Seed of the loop's noise.
    controller : qfa_ros.model.design.ControllerDesign or None
        Controller to run instead of the one designed from ``config``.
    amplitude : float
        Chirp amplitude [m/s^2].
    band_hz : (float, float or None)
        Chirp band [Hz]; the upper end defaults to 0.45 of the loop rate.
    period_steps : int
        Loop steps per chirp period (= the segment of the spectral estimate: bin
        spacing ``loop_rate / period_steps``).
    periods, settle_periods : int
        Periods averaged, and periods run first to let the loop settle.

    Returns
    -------
    LoopMeasurement
    """
    rate = config.loop_rate_hz
    low, high = band_hz
    high = 0.45 * rate if high is None else high
    if not 0 < low < high < rate / 2:
        raise ValueError(f'band_hz must satisfy 0 < low < high < {rate / 2:g}, got {band_hz!r}')
    if periods < 2 or settle_periods < 1 or period_steps < 64:
        raise ValueError('periods must be >= 2, settle_periods >= 1 and period_steps >= 64')
    if not amplitude > 0:
        raise ValueError(f'amplitude must be positive, got {amplitude!r}')
    # Imported here: scipy.signal (~1.3 CPU-s alone, ~0.35 on top of what the node loads
    # anyway) would otherwise be paid at every start of the node and of the command-line
    # tools, which import this module for the step response only.
    from scipy import signal

    loop = _loop(config, rng, controller)
    t = np.arange(period_steps) / rate
    # A logarithmic sweep over exactly one period, repeated: its spectrum lives on the
    # period's bins, so boxcar segments of one period see no leakage.
    sweep = amplitude * signal.chirp(t, low, t[-1], high, method='logarithmic')
    total = settle_periods + periods
    r = np.tile(sweep, total)
    counts = _run(loop, r)
    k_fb = loop.gains.feedback_gain
    k0 = config.hardware.pendulosity
    applied = np.concatenate(([0.0], counts[:-1]))  # one step of computation delay
    feedback = -k_fb * applied
    moment = k0 * r + feedback
    output = counts * counts_to_accel(config.hardware)
    return _breaking_estimate((r, feedback, moment, output), rate, settle_periods * period_steps,
                              periods, (low, high))


def _breaking_estimate(signals, rate, start, periods, band):
    """
    Estimate ``L`` and the closed-loop response from the signals of a loop-breaking run.

    Parameters
    ----------
    signals : tuple of numpy.ndarray
        Per loop step: the excitation ``r``, the feedback moment, the moment at the
        summing point ``u`` and the output [m/s^2].
    rate : float
        Loop rate [Hz].
    start : int
        Loop steps of the settling periods, not used.
    periods : int
        Chirp periods after ``start``, each one spectral segment.
    band : (float, float)
        Frequencies estimated [Hz].

    Returns
    -------
    LoopMeasurement
    """
    from scipy import signal  # already loaded by measure_loop

    r, feedback, moment, output = signals
    period_steps = (len(r) - start) // periods
    low, high = band

    def per_period(x):
        # Spectrum of each period (boxcar), rows = periods.
        return np.fft.rfft(x[start:].reshape(periods, period_steps), axis=1)

    spectra_r, spectra_f, spectra_u, spectra_y = (per_period(x)
                                                  for x in (r, feedback, moment, output))
    freq = np.fft.rfftfreq(period_steps, 1.0 / rate)
    inside = (freq >= low) & (freq <= high)
    # Per period: L_p = -F_p/U_p, T_p = Y_p/R_p (a period's ratio is the csd ratio of
    # one boxcar segment); the mean over periods is the csd estimate to first order.
    loop_p = -spectra_f[:, inside] / spectra_u[:, inside]
    closed_p = spectra_y[:, inside] / spectra_r[:, inside]
    # Pooled estimate: scipy's averaged cross-spectra over the same boxcar segments.
    seg = {'fs': rate, 'window': 'boxcar', 'nperseg': period_steps, 'noverlap': 0,
           'detrend': False, 'scaling': 'spectrum'}
    _, s_rf = signal.csd(r[start:], feedback[start:], **seg)
    _, s_ru = signal.csd(r[start:], moment[start:], **seg)
    _, s_ry = signal.csd(r[start:], output[start:], **seg)
    _, s_rr = signal.welch(r[start:], **seg)
    loop_gain = -s_rf[inside] / s_ru[inside]
    closed = s_ry[inside] / s_rr[inside]
    se = np.sqrt(periods / (periods - 1.0))  # sample std -> ddof 1

    def standard_error(values):
        return np.std(values, axis=0) * se / math.sqrt(periods)

    return LoopMeasurement(freq[inside], loop_gain, closed, standard_error(loop_p),
                           standard_error(closed_p), periods)


def measure_step(config, rng=0, controller=None, amplitude=0.2 * STANDARD_GRAVITY,
                 half_period_s=0.1, edges=8, settle_band=0.02):
    """
    Measure the step response of one simulated axis with a periodic square wave.

    The input alternates between 0 and ``amplitude`` [m/s^2] every ``half_period_s``;
    the output after each rising edge, minus the level before it, is averaged over
    ``edges`` edges (the first cycle settles the loop) and normalized by the settled
    level (the mean of the last 10 % of the half period).

    Returns
    -------
    StepMeasurement
    """
    if not amplitude > 0 or not half_period_s > 0 or edges < 2:
        raise ValueError('amplitude and half_period_s must be positive, edges >= 2')
    if not 0 < settle_band < 1:
        raise ValueError(f'settle_band must be in (0, 1), got {settle_band!r}')
    rate = config.loop_rate_hz
    half = int(round(half_period_s * rate))
    if half < 20:
        raise ValueError('half_period_s must span at least 20 loop steps')
    loop = _loop(config, rng, controller)
    cycle = np.concatenate((np.zeros(half), np.full(half, amplitude)))
    counts = _run(loop, np.tile(cycle, edges + 1))
    output = counts * counts_to_accel(config.hardware)
    rising = output.reshape(edges + 1, 2 * half)[1:]
    before = rising[:, half - half // 10:half].mean(axis=1, keepdims=True)
    after = rising[:, half:]
    settled = after[:, -half // 10:].mean(axis=1, keepdims=True)
    curves = (after - before) / (settled - before)
    # The command at loop step n acts from step n + 1, and step n reads the ADC before
    # the input of step n moves the pendulum: index 0 is the first step with the input.
    response = curves.mean(axis=0)
    response_se = curves.std(axis=0, ddof=1) / math.sqrt(edges)
    time = np.arange(half) / rate
    peaks = curves.max(axis=1) - 1.0
    overshoot, rise, settling = step_figures(response, settle_band, rate)
    overshoot_se = float(peaks.std(ddof=1) / math.sqrt(edges))
    return StepMeasurement(time, response, response_se, overshoot, overshoot_se, rise,
                           settling, settle_band, edges)


def design_step(config, controller, steps):
    """
    Return the linearized design's step response over ``steps`` loop steps.

    The closed-loop response of :meth:`qfa_ros.model.design.LinearLoop.closed_loop`
    sampled on ``4 steps`` bins is inverted (its impulse response, periodic over ``4
    steps`` loop steps, has died out by then) and integrated.
    """
    n = 4 * steps
    freq = np.fft.rfftfreq(n, 1.0 / config.loop_rate_hz)
    model = LinearLoop(config.hardware, controller, config.loop_rate_hz)
    # The integrator makes L infinite at DC, where the closed loop is exactly 1.
    response = np.ones(len(freq), dtype=complex)
    response[1:] = model.closed_loop(freq[1:])
    impulse = np.fft.irfft(response, n)
    return np.cumsum(impulse)[:steps]


CORRECTION_SETTLE_BAND = 1e-3
"""Band [fraction of the correction] within which a corrected output counts as settled.

0.1 %: 0.3 ug after a 300 ppm correction at 1 g, 3 ug (the bias instability) after
3000 ppm.
"""


@dataclass(frozen=True)
class SampleTransient:
    """
    The published samples' answer to a step of the feedback gain, relative to the step.

    A new feedback word (``N_VREF``, what a feedback-gain correction writes) scales the
    torque per count at once; the loop answers as it answers a step of its input, and
    each published sample is the mean of ``decimation`` loop outputs.

    Attributes
    ----------
    first_fraction : float
        Share of the step in the first sample with the new word.
    peak_fraction : float
        Largest sample over the step (the overshoot is ``peak_fraction - 1``).
    settled_samples : int
        Samples after the first from which every sample is within ``band`` of the step.
    band : float
        The settling band [fraction of the step].
    """

    first_fraction: float
    peak_fraction: float
    settled_samples: int
    band: float


def feedback_step_transient(config, controller, band=CORRECTION_SETTLE_BAND, samples=200):
    """
    Return the :class:`SampleTransient` of the published output after a feedback-gain step.

    The linearized design's step response (:func:`design_step`) over ``samples``
    published samples, averaged over each sample's ``config.decimation`` loop steps; the
    compiled loop follows it within its quantization (``test_node_ins``).
    """
    if not 0 < band < 1 or samples < 2:
        raise ValueError(f'band must be in (0, 1) and samples >= 2, got {band!r}, {samples!r}')
    per_sample = design_step(config, controller, samples * config.decimation).reshape(
        samples, config.decimation).mean(axis=1)
    outside = np.nonzero(np.abs(per_sample - 1.0) > band)[0]
    settled = int(outside[-1]) + 1 if len(outside) else 0
    return SampleTransient(float(per_sample[0]), float(per_sample.max()), settled, band)


def step_figures(response, settle_band, rate):
    """Return (overshoot, 10-90 % rise time [s], settling time [s]) of a unit step curve."""
    overshoot = float(response.max() - 1.0)

    def crossing(level):
        k = int(np.argmax(response >= level))
        if k == 0:
            return 0.0
        return (k - 1 + (level - response[k - 1]) / (response[k] - response[k - 1])) / rate

    outside = np.nonzero(np.abs(response - 1.0) > settle_band)[0]
    settling = (outside[-1] + 1) / rate if len(outside) else 0.0
    return overshoot, crossing(0.9) - crossing(0.1), settling
