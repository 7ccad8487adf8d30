"""Compare hand-written helpers with the well-kept libraries that could replace them.

Run: ``.venv/bin/python bench/library_alternatives.py [--repeat 200]`` (python-control is
imported only if installed: ``pip install control==0.10.2``).

* Rotations: :func:`qfa_ros.model.trajectory.euler_to_dcm`, ``dcm_to_quaternion`` and
  ``quaternion_to_dcm`` against ``scipy.spatial.transform.Rotation``: the largest error
  against an exact reference (``mpmath``-free: the reference matrices are built from
  quaternions, whose matrix is exact to rounding), including rotations within 1e-9 rad of
  a half turn, where a quaternion's ``w`` vanishes; and the time per call for one
  rotation (the node's odometry message) and for 10 000 (a trajectory chunk).
* Loop margins: :meth:`qfa_ros.model.design.LinearLoop.margins` (a 40 000-point grid)
  against ``control.stability_margins`` on the same discrete loop, and both against an
  analytic case (``L(z) = K / (z (z - 1))``: crossover, phase and gain margin in closed
  form, the bandwidth a root of a closed-form expression).
Prints Markdown tables.
"""

import argparse
import math
import subprocess
import sys
import time

import numpy as np
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from qfa_ros.model.design import COEF_FRAC_BITS, design_controller, LinearLoop
from qfa_ros.model.trajectory import dcm_to_quaternion, euler_to_dcm, quaternion_to_dcm
from qfa_ros.model.triad_config import TriadConfig

SPATIAL = 'scipy.spatial.transform'
NODE_IMPORTS = 'numpy, scipy.linalg, numba, rclpy'
"""What the node process has imported by the time it would import scipy.spatial."""


def per_call_us(function, repeat):
    """Return the median time of ``function()`` over ``repeat`` calls [us]."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return 1e6 * float(np.median(times))


def same_rotation_error(q, reference):
    """Return the largest distance between quaternions up to sign (q and -q are one)."""
    return float(np.max(np.minimum(np.linalg.norm(q - reference, axis=-1),
                                   np.linalg.norm(q + reference, axis=-1))))


def rotations(repeat, rng):
    """Print the rotation table."""
    count = 10_000
    reference = rng.normal(size=(count, 4))
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    # Rotations within 1e-9 rad of a half turn: w ~ 5e-10.
    near = rng.normal(size=(count, 3))
    near /= np.linalg.norm(near, axis=1, keepdims=True)
    half = np.column_stack([near * math.cos(5e-10), np.full(count, math.sin(5e-10))])
    angles = rng.uniform(-math.pi, math.pi, size=(count, 3))
    angles[:, 1] /= 2.0
    # Exact half turns: w = 0 (the copysign formula read the signs off vanishing differences).
    exact_half = np.column_stack([near, np.zeros(count)])
    rows = []
    for name, q in (('random', reference), ('near a half turn', half),
                    ('exact half turn', exact_half)):
        matrix = Rotation.from_quat(q).as_matrix()
        rows.append((f'DCM -> quaternion, {name}', same_rotation_error(
            dcm_to_quaternion(matrix), q), same_rotation_error(
            Rotation.from_matrix(matrix).as_quat(), q)))
    rows.append(('quaternion -> DCM, random',
                 float(np.max(np.abs(quaternion_to_dcm(reference)
                                     - Rotation.from_quat(reference).as_matrix()))), 0.0))
    euler = euler_to_dcm(angles[:, 0], angles[:, 1], angles[:, 2])
    scipy_euler = Rotation.from_euler('ZYX', angles[:, ::-1]).as_matrix()
    rows.append(('Euler -> DCM, random (difference between the two)',
                 float(np.max(np.abs(euler - scipy_euler))), 0.0))
    print(f'importing scipy.spatial.transform after numpy, scipy.linalg, numba and rclpy '
          f'(median of 5 fresh interpreters): {import_seconds(SPATIAL, NODE_IMPORTS, 5):.3f} s\n')
    print('| rotation | hand-written: largest error | scipy Rotation: largest error |')
    print('|---|---|---|')
    for name, own, library in rows:
        print(f'| {name} | {own:.2e} | {library:.2e} |')
    one_matrix, one_quaternion, one_angle = matrix[:1], reference[:1], angles[:1]
    timings = [
        ('DCM -> quaternion', lambda m: dcm_to_quaternion(m),
         lambda m: Rotation.from_matrix(m).as_quat(), one_matrix, matrix),
        ('quaternion -> DCM', lambda q: quaternion_to_dcm(q),
         lambda q: Rotation.from_quat(q).as_matrix(), one_quaternion, reference),
        ('Euler -> DCM', lambda a: euler_to_dcm(a[:, 0], a[:, 1], a[:, 2]),
         lambda a: Rotation.from_euler('ZYX', a[:, ::-1]).as_matrix(), one_angle, angles),
    ]
    print('\n| conversion | hand-written, 1 | scipy, 1 | hand-written, 10 000 | scipy, 10 000 |')
    print('|---|---|---|---|---|')
    for name, own, library, one, many in timings:
        print(f'| {name} | {per_call_us(lambda: own(one), repeat):.1f} us '
              f'| {per_call_us(lambda: library(one), repeat):.1f} us '
              f'| {per_call_us(lambda: own(many), repeat // 10 + 1):.0f} us '
              f'| {per_call_us(lambda: library(many), repeat // 10 + 1):.0f} us |')


def control_loop(control, loop):
    """Return the loop gain of ``loop`` as a python-control discrete transfer function."""
    ts = loop.loop_period
    q = 2.0 ** COEF_FRAC_BITS
    c = loop.controller
    plant = control.ss2tf(control.ss(loop.ad, loop.bd.reshape(2, 1), [[1.0, 0.0]], [[0.0]],
                                     ts)) * loop.gains.k_sense
    lead = control.tf([c.lead_b0 / q, c.lead_b1 / q], [1.0, -c.lead_a1 / q], ts)
    integrator = control.tf([1.0 + c.integrator_gain / q, -1.0], [1.0, -1.0], ts)
    delay = control.tf([1.0], [1.0, 0.0], ts)
    return loop.gains.feedback_gain * plant * (c.gain * lead * integrator) * delay


class AnalyticLoop:
    """``L(z) = K / (z (z - 1))`` at ``rate`` [Hz], through LinearLoop's grid search."""

    def __init__(self, gain, rate):
        self.gain, self.loop_period = gain, 1.0 / rate

    def loop_gain(self, freq_hz):
        z = np.exp(2j * np.pi * np.asarray(freq_hz) * self.loop_period)
        return self.gain / (z * (z - 1.0))

    def closed_loop(self, freq_hz):
        loop = self.loop_gain(freq_hz)
        return loop / (1.0 + loop)

    margins = LinearLoop.margins

    def exact(self):
        """Return (crossover Hz, phase margin deg, gain margin dB, bandwidth Hz)."""
        # |e^{jw} - 1| = 2 sin(w/2), arg L = -(3w/2 + pi/2): |L| = 1 at w = 2 asin(K/2),
        # arg L = -pi at w = pi/3; |T(e^{jw})|^2 = K^2 / |e^{2jw} - e^{jw} + K|^2 = 1/2.
        hz = 1.0 / (2 * math.pi * self.loop_period)
        w = 2.0 * math.asin(self.gain / 2.0)
        k = self.gain

        def excess(w):
            return 2 * k * k - abs(np.exp(2j * w) - np.exp(1j * w) + k) ** 2

        corner = brentq(excess, math.pi / 3, math.pi, xtol=1e-15)  # |T| > 0.71 below
        return (w * hz, 90.0 - 1.5 * math.degrees(w), -20.0 * math.log10(k), corner * hz)


def import_seconds(module, after='numpy, scipy.signal', repeat=1):
    """
    Return how long importing ``module`` takes in a fresh interpreter [s].

    ``after`` is imported first (what the caller already has loaded); the median of
    ``repeat`` interpreters.
    """
    script = (f'import time, {after}\nstart = time.perf_counter()\n'
              f'import {module}\nprint(time.perf_counter() - start)')
    times = [float(subprocess.run([sys.executable, '-c', script], capture_output=True,
                                  text=True, check=True).stdout) for _ in range(repeat)]
    return float(np.median(times))


def margins(repeat):
    """Print the margins table."""
    try:
        import control
    except ImportError:
        print('\npython-control not installed: margins not compared')
        return
    config = TriadConfig()
    controller = design_controller(config.hardware, config.loop_rate_hz, config.crossover_hz,
                                   config.integrator_ratio, config.lead_pole_ratio)
    loop = LinearLoop(config.hardware, controller, config.loop_rate_hz)
    analytic = AnalyticLoop(0.5, config.loop_rate_hz)
    print(f'\npython-control {control.__version__}\n')
    print('| loop, figure | exact | 40 000-point grid | python-control |')
    print('|---|---|---|---|')
    for name, system, exact in (
            ('K/(z(z-1)), K = 0.5', analytic, analytic.exact()),
            (f'designed loop (crossover designed to {config.crossover_hz:g} Hz)', loop,
             (config.crossover_hz, None, None, None))):
        grid = system.margins()
        if system is loop:
            tf = control_loop(control, loop)
        else:
            tf = control.tf([analytic.gain], [1.0, -1.0, 0.0], analytic.loop_period)
        gm, pm, _, _, wgc, _ = control.stability_margins(tf)
        try:
            bandwidth = control.bandwidth(control.feedback(tf, 1)) / (2 * math.pi)
            bandwidth = f'{bandwidth:.9g}'
        except Exception as error:
            # 0.10.2 evaluates a discrete system at s = jw, not at z = e^{jw Ts}.
            bandwidth = f'control.bandwidth fails: {type(error).__name__}'
        library = (f'{wgc / (2 * math.pi):.9g}', f'{pm:.9g}', f'{20 * math.log10(gm):.9g}',
                   bandwidth)
        for k, figure in enumerate(('crossover [Hz]', 'phase margin [deg]',
                                    'gain margin [dB]', '-3 dB bandwidth [Hz]')):
            reference = '' if exact[k] is None else f'{exact[k]:.9g}'
            print(f'| {name}, {figure} | {reference} | {grid[k]:.9g} | {library[k]} |')
    tf = control_loop(control, loop)
    grid_us = per_call_us(loop.margins, repeat // 10 + 1)
    library_us = per_call_us(lambda: control.stability_margins(tf), repeat // 10 + 1)
    build_us = per_call_us(lambda: control_loop(control, loop), repeat // 10 + 1)
    print(f'\n| time per call | grid (margins and bandwidth) | control.stability_margins '
          f'(+ building the transfer function) |\n|---|---|---|\n| designed loop '
          f'| {grid_us / 1e3:.1f} ms | {library_us / 1e3:.1f} ms (+ {build_us / 1e3:.1f} ms) |')
    print(f'\nimporting control (after numpy and scipy.signal; it imports matplotlib.pyplot): '
          f'{import_seconds("control"):.2f} s')


def main():
    """Measure and print both comparisons."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=200)
    args = parser.parse_args()
    rotations(args.repeat, np.random.default_rng(0))
    margins(args.repeat)


if __name__ == '__main__':
    main()
