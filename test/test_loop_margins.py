"""The design's margins and bandwidth (LinearLoop.margins) against a loop solved in closed form."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from qfa_ros.model.design import LinearLoop

RATE_HZ = 10000.0
GRID_STEP = 10 ** ((math.log10(0.5 * RATE_HZ * 0.999) + 1) / 39999) - 1
"""Relative spacing of the 40 000-point logarithmic grid from 0.1 Hz to Nyquist."""


class AnalyticLoop:
    """``L(z) = K / (z (z - 1))``: an integrator behind one step of delay."""

    margins = LinearLoop.margins

    def __init__(self, gain):
        self.gain, self.loop_period = gain, 1.0 / RATE_HZ

    def loop_gain(self, freq_hz):
        z = np.exp(2j * np.pi * np.asarray(freq_hz) * self.loop_period)
        return self.gain / (z * (z - 1.0))

    def closed_loop(self, freq_hz):
        loop = self.loop_gain(freq_hz)
        return loop / (1.0 + loop)


def exact_figures(k):
    """Return (crossover Hz, phase margin deg, gain margin dB, -3 dB bandwidth Hz)."""
    # |e^{jw} - 1| = 2 sin(w/2) and arg L = -(3w/2 + pi/2): |L| = 1 at w = 2 asin(K/2),
    # arg L = -pi at w = pi/3 where |L| = K; |T|^2 = K^2 / |e^{2jw} - e^{jw} + K|^2.
    hz = RATE_HZ / (2 * math.pi)
    w = 2.0 * math.asin(k / 2.0)

    def excess(w):
        return 2 * k * k - np.abs(np.exp(2j * w) - np.exp(1j * w) + k) ** 2

    # The first fall through 1/sqrt(2) (|T| = 1 at DC), bracketed on a fine grid.
    ws = np.linspace(1e-6, math.pi, 100001)
    i = np.nonzero(excess(ws) < 0)[0][0]
    corner = brentq(excess, ws[i - 1], ws[i], xtol=1e-15)
    return w * hz, 90.0 - 1.5 * math.degrees(w), -20.0 * math.log10(k), corner * hz


@pytest.mark.parametrize('k', [0.2, 0.5, 0.8])
def test_the_grid_margins_match_the_closed_form_within_one_grid_step(k):
    crossover, phase_margin, gain_margin, bandwidth = AnalyticLoop(k).margins()
    exact = exact_figures(k)
    assert crossover == pytest.approx(exact[0], rel=GRID_STEP)
    # The phase and the gain move by at most their slope over one grid step.
    assert phase_margin == pytest.approx(exact[1], abs=1.5 * math.degrees(
        2 * math.pi * exact[0] / RATE_HZ) * GRID_STEP)
    assert gain_margin == pytest.approx(exact[2], abs=20 * GRID_STEP)
    assert bandwidth == pytest.approx(exact[3], rel=GRID_STEP)
