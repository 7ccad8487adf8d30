"""Compare hand-written helpers with the well-kept libraries that could replace them.

Run: ``.venv/bin/python bench/library_alternatives.py [--repeat 200] [--parts allan ...]``
(python-control is imported only if installed: ``pip install control==0.10.2``; allantools
is a test dependency).

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
* Allan deviation: :func:`qfa_ros.model.allan.allan_deviation` (compiled) against
  ``allantools.oadev`` on one axis of a 1-hour 1 kHz series (3.6 M samples): the octave
  taus of ``qfa-sim``'s summary and the 144-tau grid of ``qfa-report imu-yaml``
  (:func:`qfa_ros.model.noise_figures.tau_grid`, 360 s), the largest relative difference and
  the time per axis; and the time importing allantools adds.
* Binning by temperature: :func:`qfa_ros.calibration.tempfit.bin_by_temperature`
  (``numpy.bincount``) against ``scipy.stats.binned_statistic`` on a 2-cycle chamber
  program's 1 s samples, and the import ``scipy.stats`` adds.
* Quintic Hermite pieces: :func:`qfa_ros.model.trajectory.quintic_coefficients` against
  ``scipy.interpolate.BPoly.from_derivatives`` (then ``PPoly.from_bernstein_basis``) on the
  knots of :func:`qfa_ros.model.motion_scripts.vehicle_drive`: the largest difference of
  the values and derivatives, and the time to build the drive's pieces.
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


def best_seconds(function, repeat):
    """Return the shortest time of ``function()`` over ``repeat`` calls [s]."""
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def allan(rng):
    """Print the Allan deviation table."""
    import allantools

    from qfa_ros.model.allan import allan_deviation
    from qfa_ros.model.noise_figures import tau_grid

    rate = 1000.0
    samples = rng.normal(size=3_600_000) + 1e-3 * np.cumsum(rng.normal(size=3_600_000))
    allan_deviation(samples[:100], 1.0 / rate)  # the compiled function, loaded once
    print(f'\nallantools {allantools.__version__}; one axis of 3 600 000 samples at 1 kHz '
          '(white noise and a random walk), best of 3\n')
    print('| taus | count | largest relative difference | hand-written (numba) | '
          'allantools.oadev |')
    print('|---|---|---|---|---|')
    for name, taus in (('octave (qfa-sim summary)', 'octave'),
                       ('tau_grid(360 s) (qfa-report imu-yaml)', tau_grid(360.0))):
        own = allan_deviation(samples, 1.0 / rate, taus)
        library = allantools.oadev(samples, rate=rate, data_type='freq', taus=taus)
        assert np.allclose(own[0], library[0]), name
        difference = float(np.max(np.abs(own[1] / library[1] - 1.0)))
        own_s = best_seconds(lambda: allan_deviation(samples, 1.0 / rate, taus), 3)
        library_s = best_seconds(lambda: allantools.oadev(samples, rate=rate, data_type='freq',
                                                          taus=taus), 3)
        print(f'| {name} | {len(own[0])} | {difference:.1e} | {own_s:.3f} s | '
              f'{library_s:.3f} s |')
    print(f'\nimporting allantools after numpy and numba (median of 5 fresh interpreters): '
          f'{import_seconds("allantools", "numpy, numba", 5):.3f} s')


def binning(rng):
    """Print the binning table."""
    from scipy.stats import binned_statistic

    from qfa_ros.calibration.tempfit import bin_by_temperature

    v_temp = 0.75 + 0.4 * np.sin(np.linspace(0.0, 4.0 * math.pi, 14_400)) \
        + 1e-4 * rng.normal(size=14_400)
    output = 1e-3 * np.exp(2.0 * v_temp) + 1e-5 * rng.normal(size=v_temp.size)
    own = bin_by_temperature(v_temp, output, 100)
    counts = binned_statistic(v_temp, output, 'count', bins=100)[0]
    means = [binned_statistic(v_temp, values, 'mean', bins=100)[0]
             for values in (v_temp, output)]
    keep = counts > 0
    difference = max(float(np.max(np.abs(own[1] - means[1][keep]))),
                     float(np.max(np.abs(own[0] - means[0][keep]))))
    own_us = per_call_us(lambda: bin_by_temperature(v_temp, output, 100), 50)
    library_us = per_call_us(lambda: [binned_statistic(v_temp, values, 'mean', bins=100)
                                      for values in (v_temp, output)], 50)
    print('\n| 14 400 samples in 100 V_temp bins | largest difference of the means | time |')
    print('|---|---|---|')
    print(f'| bin_by_temperature (numpy.bincount) | | {own_us:.0f} us |')
    print(f'| scipy.stats.binned_statistic (V and output means) | {difference:.1e} | '
          f'{library_us:.0f} us |')
    print(f'\nimporting scipy.stats after numpy and numba (median of 5 fresh interpreters): '
          f'{import_seconds("scipy.stats", "numpy, numba", 5):.3f} s')


def hermite(rng):
    """Print the quintic Hermite table."""
    from scipy.interpolate import BPoly, PPoly

    from qfa_ros.model.motion_scripts import vehicle_drive
    from qfa_ros.model.trajectory import quintic_coefficients

    drive = vehicle_drive()
    times = drive.poly.x
    knots = [drive.poly(times, nu) for nu in (0, 1, 2)]
    own = PPoly(*quintic_coefficients(times, *knots))
    library = PPoly.from_bernstein_basis(BPoly.from_derivatives(times, np.stack(knots, axis=1)))
    t = rng.uniform(times[0], times[-1], 100_000)
    differences = [float(np.max(np.abs(own.derivative(nu)(t) - library.derivative(nu)(t))))
                   if nu else float(np.max(np.abs(own(t) - library(t)))) for nu in (0, 1, 2)]
    own_s = best_seconds(lambda: quintic_coefficients(times, *knots), 3)
    library_s = best_seconds(lambda: PPoly.from_bernstein_basis(
        BPoly.from_derivatives(times, np.stack(knots, axis=1))), 3)
    print(f'\n| {len(times)} knots of the drive, 6 channels | largest difference: value, rate, '
          'acceleration | time |')
    print('|---|---|---|')
    print(f'| quintic_coefficients | | {own_s * 1e3:.1f} ms |')
    print(f'| BPoly.from_derivatives + PPoly.from_bernstein_basis | '
          f'{differences[0]:.1e}, {differences[1]:.1e}, {differences[2]:.1e} | '
          f'{library_s * 1e3:.0f} ms |')


PARTS = ('rotations', 'margins', 'allan', 'binning', 'hermite')


def main():
    """Measure and print the comparisons."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=200)
    parser.add_argument('--parts', nargs='+', choices=PARTS, default=PARTS)
    args = parser.parse_args()
    if 'rotations' in args.parts:
        rotations(args.repeat, np.random.default_rng(0))
    if 'margins' in args.parts:
        margins(args.repeat)
    if 'allan' in args.parts:
        allan(np.random.default_rng(1))
    if 'binning' in args.parts:
        binning(np.random.default_rng(2))
    if 'hermite' in args.parts:
        hermite(np.random.default_rng(3))


if __name__ == '__main__':
    main()
