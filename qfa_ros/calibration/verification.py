"""
Verification of a temperature calibration: another chamber cycle, six orientations.

The acceptance measurement of a multi-position temperature calibration
(:mod:`qfa_ros.calibration.temperature`): a chamber cycle of another shape than the
calibration's plateaus, the dividing head tumbling in the reverse order, compensation
on; errors per position and axis binned by the on-board reading. Offline only: it
compares the output with the fixture's known input, as the lab's verification does.
"""

from dataclasses import dataclass

import numpy as np

from qfa_ros.calibration.schedule import samples_for
from qfa_ros.calibration.temperature import AMBIENT_FIELDS, fixture_profile, POSITIONS
from qfa_ros.model.hardware import STANDARD_GRAVITY


@dataclass
class VerificationResult:
    """
    Compensated output over a verification chamber cycle, per fixture position.

    Attributes
    ----------
    zero_drift_p2p : float64[6, 3]
        Per position (:data:`POSITIONS`) and axis: peak to peak over temperature bins of
        the mean (output - fixture input) [m/s^2].
    scale_residual : float64[3]
        Per axis: largest |scale-factor error| of the +-g pairs, binned by
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
    reading into ``bin_c`` bins. Runs offline (``triad.run``); ``progress`` is called
    with the sensor seconds done, if given.
    """
    previous = {name: getattr(triad.thermal.config, name) for name in AMBIENT_FIELDS}
    triad.thermal.set_ambient(ambient_profile='cycle', cycle_low_c=low_c, cycle_high_c=high_c,
                              cycle_period_s=period_s, cycle_shape=shape)
    n = samples_for(triad, block_s)
    keep = min(samples_for(triad, 0.25), n // 2)
    rows = []
    try:
        done = 0.0
        while done < period_s:
            for axis, sign in POSITIONS[::-1]:
                triad.fixture = fixture_profile(axis, sign)
                out = triad.run(n)
                rows.append((out.v_temp[keep:].mean(), axis, sign,
                             (out.accel[keep:] - out.truth[keep:]).mean(axis=0)))
                done += block_s
                if progress is not None:
                    progress(block_s)
    finally:
        triad.fixture = None
        triad.thermal.set_ambient(**previous)
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
