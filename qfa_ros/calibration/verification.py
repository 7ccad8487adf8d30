"""
Verification of a temperature calibration: another chamber cycle, six orientations.

The acceptance measurement of a multi-position temperature calibration
(:mod:`qfa_ros.calibration.temperature`): a chamber cycle of another shape than the
calibration's plateaus, the dividing head tumbling in the reverse order, compensation
on; errors per position and axis binned by the on-board reading. Offline only: it
compares the output with the fixture's known input, as the lab's verification does.
"""

from dataclasses import dataclass
import math

import numpy as np

from qfa_ros.calibration.chamber import idle
from qfa_ros.calibration.schedule import samples_for
from qfa_ros.calibration.temperature import chamber_program, fixture_profile, POSITIONS
from qfa_ros.model.checks import is_finite
from qfa_ros.model.constants import STANDARD_GRAVITY
from qfa_ros.model.input_profiles import StaticProfile

MAX_BINS = 1e6
"""Most temperature bins :func:`verify_cycle` takes (``(high_c - low_c) / bin_c``)."""


@dataclass
class VerificationResult:
    r"""
    Compensated output over a verification chamber cycle, per fixture position.

    Attributes
    ----------
    zero_drift_p2p : float64[6, 3]
        Per position (:data:`POSITIONS`) and axis: peak to peak over temperature bins of
        the mean (output - fixture input) [m/s^2].
    scale_residual : float64[3]
        Per axis: largest \|scale-factor error| of the +-g pairs, binned by
        temperature [1].
    bins_c : float64[k]
        Centres of the temperature bins (on-board reading) [degC].
    """

    zero_drift_p2p: np.ndarray
    scale_residual: np.ndarray
    bins_c: np.ndarray


def verify_cycle(triad, low_c=-40.0, high_c=70.0, period_s=2400.0, shape='sine',
                 block_s=2.0, bin_c=10.0, progress=None):
    """
    Run a chamber cycle with the head tumbling and measure the compensated errors.

    The cycle is a ``shape`` profile (default a sine, not the calibration's plateaus)
    between ``low_c`` and ``high_c``; the head tumbles through the six positions in
    the reverse order with ``block_s`` dwell. Errors are binned by the on-board
    reading into ``bin_c`` bins [degC]. Runs offline (``triad.run``); ``progress`` is
    called with the sensor seconds done, if given. ``period_s`` and ``block_s`` [s] and
    ``bin_c`` must be finite and > 0, and ``(high_c - low_c) / bin_c`` at most
    :data:`MAX_BINS` (ValueError naming the parameter).
    """
    for name, value in (('low_c', low_c), ('high_c', high_c)):
        if not is_finite(value, bool_ok=False):
            raise ValueError(f'{name} must be a finite number, got {value!r}')
    for name, value in (('period_s', period_s), ('block_s', block_s), ('bin_c', bin_c)):
        if not is_finite(value, bool_ok=False) or value <= 0:
            raise ValueError(f'{name} must be a finite number > 0, got {value!r}')
    if (high_c - low_c) / bin_c > MAX_BINS:
        raise ValueError(f'bin_c must be at least (high_c - low_c) / {MAX_BINS:g}, got {bin_c!r}')
    n = samples_for(triad, block_s)
    # A block runs at least one sample: the cycle counts at least its sensor time.
    step_s = max(block_s, 1.0 / triad.config.sample_rate_hz)
    keep = min(samples_for(triad, 0.25), n // 2)
    rows = []
    with chamber_program(triad, ambient_profile='cycle', cycle_low_c=low_c,
                         cycle_high_c=high_c, cycle_period_s=period_s, cycle_shape=shape):
        done = 0.0
        while done < period_s:
            for axis, sign in POSITIONS[::-1]:
                triad.fixture = fixture_profile(axis, sign)
                out = triad.run(n)
                rows.append((out.v_temp[keep:].mean(), axis, sign,
                             (out.accel[keep:] - out.truth[keep:]).mean(axis=0)))
                done += step_s
                if progress is not None:
                    progress(step_s)
    reading = triad.thermal.reading_c(np.array([r[0] for r in rows]))
    edges = np.arange(low_c, high_c + bin_c, bin_c)
    which = np.digitize(reading, edges)
    error = np.array([r[3] for r in rows])
    position = np.array([POSITIONS.index((r[1], r[2])) for r in rows])
    used = [b for b in np.unique(which) if np.sum(which == b) >= 6 * 3]
    p2p = np.zeros((len(POSITIONS), 3))
    for k in range(len(POSITIONS)):
        means = np.array([error[(which == b) & (position == k)].mean(axis=0) for b in used])
        p2p[k] = np.ptp(means, axis=0)
    scale = np.zeros(3)
    g = STANDARD_GRAVITY
    for i in range(3):
        up, down = POSITIONS.index((i, 1)), POSITIONS.index((i, -1))
        for b in used:
            e_up = error[(which == b) & (position == up), i].mean()
            e_down = error[(which == b) & (position == down), i].mean()
            scale[i] = max(scale[i], abs(e_up - e_down) / (2 * g))
    centres = np.array([0.5 * (edges[max(b - 1, 0)] + edges[min(b, len(edges) - 1)])
                        for b in used])
    return VerificationResult(p2p, scale, centres)


ATTITUDES = (('level', 0.0, 0.0), ('inverted', math.pi, 0.0),
             ('roll +90', 0.5 * math.pi, 0.0), ('roll -90', -0.5 * math.pi, 0.0),
             ('pitch +90', 0.0, 0.5 * math.pi), ('pitch -90', 0.0, -0.5 * math.pi),
             ('arbitrary 1', 0.61, -0.43), ('arbitrary 2', -2.27, 0.97))
"""Verification attitudes ``(name, roll, pitch)`` [rad]: level, inverted, rolled and pitched
+-90 degrees (each axis's +-g pair) and two arbitrary ones (every axis a share of g)."""

SCALE_PAIRS = (('pitch -90', 'pitch +90'), ('roll +90', 'roll -90'), ('level', 'inverted'))
"""Per axis the two attitudes of :data:`ATTITUDES` that put it at +g and -g."""


@dataclass
class AttitudeVerification:
    """
    Compensated errors in fixed attitudes at constant chamber temperatures.

    Attributes
    ----------
    names : list of str
        Attitude names (:data:`ATTITUDES` order).
    temperatures_c : float64[t]
        Chamber temperatures [degC].
    error : float64[t, a, 3]
        Mean output minus the input per temperature, attitude and axis [m/s^2].
    zero_drift_p2p : float64[a, 3]
        Peak to peak of ``error`` over the temperatures [m/s^2].
    scale_error : float64[t, 3]
        Per temperature and axis the scale-factor error of the axis's +-g pair
        (:data:`SCALE_PAIRS`) [1].
    """

    names: list
    temperatures_c: np.ndarray
    error: np.ndarray
    zero_drift_p2p: np.ndarray
    scale_error: np.ndarray

    @property
    def scale_p2p(self):
        """Peak to peak of the scale-factor error over the temperatures per axis [1]."""
        return np.ptp(self.scale_error, axis=0)

    @property
    def scale_max(self):
        r"""Largest \|scale-factor error| over the temperatures per axis [1]."""
        return np.abs(self.scale_error).max(axis=0)


def verify_attitudes(triad, temperatures_c=(-27.0, 8.0, 41.0, 64.0), attitudes=ATTITUDES,
                     soak_s=None, average_s=1.5, settle_s=0.5):
    """
    Hold the chamber at each temperature and measure the compensated output per attitude.

    Per temperature: constant ambient, a soak of ``soak_s`` (default eight body time
    constants, environment time only), then per attitude ``settle_s`` discarded and
    ``average_s`` averaged; the error is the mean output minus the known input. Offline
    (``triad.run``), compensation as it is; the ambient is restored afterwards.
    """
    soak_s = 8.0 * triad.thermal.config.sensor_tau_s if soak_s is None else soak_s
    error = np.zeros((len(temperatures_c), len(attitudes), 3))
    with chamber_program(triad):
        for t, chamber_c in enumerate(temperatures_c):
            triad.thermal.set_ambient(ambient_profile='constant', ambient_c=float(chamber_c))
            idle(triad, soak_s)
            for a, (_, roll, pitch) in enumerate(attitudes):
                triad.fixture = StaticProfile.orientation(roll, pitch)
                triad.run(samples_for(triad, settle_s))
                out = triad.run(samples_for(triad, average_s))
                error[t, a] = (out.accel - out.truth).mean(axis=0)
    names = [name for name, *_ in attitudes]
    scale = np.full((len(temperatures_c), 3), np.nan)
    for axis, (up, down) in enumerate(SCALE_PAIRS):
        if up in names and down in names:
            i, j = names.index(up), names.index(down)
            scale[:, axis] = (error[:, i, axis] - error[:, j, axis]) / (2.0 * STANDARD_GRAVITY)
    return AttitudeVerification(names, np.asarray(temperatures_c, float), error,
                                np.ptp(error, axis=0), scale)
