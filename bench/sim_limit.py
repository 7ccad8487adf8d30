"""Whole-process ``qfa-sim static`` against the limit of the loop with its noise, side by side.

Run (quiet machine, the figures in docs/performance.md)::

    .venv/bin/python bench/sim_limit.py --duration 3600 --repeat 5

Each repetition runs, interleaved so that a busy machine affects all alike:

* ``qfa-sim static --duration D`` as a fresh process (start-up, JIT cache load, thermal
  model, the three axes on the available cores, the summary with its Allan deviation):
  wall time, CPU time and peak RSS (``os.wait4``);
* the limit: a bare numba loop doing the kernel's arithmetic with the project's
  parameters (ADC rounding, Q32/Q20 lead and integrator, exact-ZOH pendulum, torquer
  delay, 10:1 averaging) and the full noise model (white and ADC noise per step, four
  Gauss-Markov drives per 0.1 s block, as the model) drawn inside the loop from a
  ``numpy.random.Generator`` passed into ``@njit``; the same loop without noise; and the
  project's kernel (``AxisLoop.run``: one axis, its normals drawn by numpy) over the same
  steps. These run in this process on one core; their CPU time is reported beside the
  wall time.

With ``--tree LABEL=DIR`` (repeatable) it only times the whole process of each source
tree in turn (e.g. an export of an earlier commit beside this one), start-up included.

Prints a Markdown table of medians: seconds, axis-steps per second, real-time multiple,
and the ratio of the whole process to the two-core limit (three axes of D seconds at
the limit rate spread over the cores: ``3 D f_loop / (cores * rate)``).
"""

import argparse
import os
import statistics
import subprocess
import sys
import time

from numba import njit
import numpy as np

from qfa_ros.model.constants import STANDARD_GRAVITY


@njit(cache=True, nogil=True)
def limit_loop(rng, n_samples, draw, decimation, level, white_std, adc_std, phi, drive,
               state, gm_block, ad, bd, k0, k_sense, k_fb, gain, a1, b0, b1, ki, limit, out):
    """Bare closed loop with the full noise model drawn from ``rng`` if ``draw``."""
    theta = 0.0
    omega = 0.0
    x_prev = 0
    y_prev = 0
    integrator = np.int64(0)
    applied = np.int64(0)
    for j in range(n_samples):
        held = level
        for k in range(phi.shape[0]):
            if j % gm_block == 0:
                state[k] = phi[k] * state[k] + drive[k] * rng.standard_normal()
            held += state[k]
        total = 0.0
        for _ in range(decimation):
            accel = held
            volts = k_sense * theta
            if draw:
                accel += white_std * rng.standard_normal()
                volts += adc_std * rng.standard_normal()
            code = np.int64(np.floor(volts + 0.5))
            x = (gain * code + (1 << 23)) >> 24
            y = (a1 * y_prev + b0 * x + b1 * x_prev + (1 << 19)) >> 20
            integrator = min(max(integrator + ki * y, -limit), limit)
            command = (y + ((integrator + (1 << 19)) >> 20) + (1 << 7)) >> 8
            x_prev = x
            y_prev = y
            moment = k0 * accel - k_fb * applied
            theta_next = ad[0] * theta + ad[1] * omega + bd[0] * moment
            omega = ad[2] * theta + ad[3] * omega + bd[1] * moment
            theta = theta_next
            applied = command
            total += command
        out[j] = total / decimation


def limit_arguments(noise_on):
    """Return the project's parameters for :func:`limit_loop` (axis z, level, 1 g)."""
    from qfa_ros.model import kernel
    from qfa_ros.model.noise import NoiseConfig
    from qfa_ros.model.triad import QfaTriad
    from qfa_ros.model.triad_config import TriadConfig

    config = TriadConfig(noise=NoiseConfig() if noise_on else NoiseConfig.off())
    triad = QfaTriad(config, rng=0)
    loop, noise = triad.axes[2], triad.noise
    pf, pi = loop.params_f, loop.params_i
    limit = (int(pi[kernel.Q_DA2_FULL_SCALE]) << 8) << 20
    return (config.decimation, STANDARD_GRAVITY, noise.white_std, noise.adc_std, noise.phi.copy(),
            noise.drive_std.copy(), noise.bias_state[2].copy(), noise.gm_block,
            pf[kernel.P_AD00:kernel.P_AD11 + 1].copy(), pf[kernel.P_BD0:kernel.P_BD1 + 1].copy(),
            pf[kernel.P_PENDULOSITY], pf[kernel.P_K_SENSE], pf[kernel.P_K_FB],
            int(pi[kernel.Q_GAIN]), int(pi[kernel.Q_A1]), int(pi[kernel.Q_B0]),
            int(pi[kernel.Q_B1]), int(pi[kernel.Q_KI]), limit)


def timed(function):
    """Return (wall s, thread CPU s) of ``function()``."""
    wall, cpu = time.perf_counter(), time.thread_time()
    function()
    return time.perf_counter() - wall, time.thread_time() - cpu


def run_limit(n_samples, noise_on):
    """Time :func:`limit_loop` over ``n_samples`` samples (one axis)."""
    args = limit_arguments(noise_on)
    out = np.empty(n_samples)
    rng = np.random.default_rng(1)
    limit_loop(rng, 10, noise_on, *args, out[:10])  # compile or load outside the timing
    return timed(lambda: limit_loop(rng, n_samples, noise_on, *args, out))


def run_kernel(n_samples):
    """Time the project's kernel with its noise over ``n_samples`` (one axis)."""
    from qfa_ros.model.triad import QfaTriad
    from qfa_ros.model.triad_config import TriadConfig

    triad = QfaTriad(TriadConfig(), rng=0)
    loop = triad.axes[2]
    sensed, scale, offset = np.array([STANDARD_GRAVITY]), np.ones(1), np.zeros(1)
    out = np.empty(n_samples)
    flags = np.empty(n_samples, dtype=np.int8)

    def call():
        loop.run(sensed, scale, offset, triad.decimation, out, flags)

    return timed(call)


def run_process(duration, tree=None):
    """
    Run ``qfa-sim static`` in a fresh process; return (wall s, CPU s, peak RSS MB).

    ``tree``: run the ``qfa_ros`` of this source tree (first on ``PYTHONPATH``) instead of
    the installed one.
    """
    command = [sys.executable, '-m', 'qfa_ros.cli.sim', 'static', '--duration', str(duration)]
    env = None
    if tree is not None:
        # As in a user's shell: the sources' bytecode is cached (by the first, untimed run).
        env = {**os.environ, 'PYTHONPATH': str(tree)}
        env.pop('PYTHONDONTWRITEBYTECODE', None)
    start = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                               env=env, cwd=tree)
    output = process.stdout.read()
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0 or b'ADEV' not in output:
        raise RuntimeError(f'qfa-sim failed ({process.returncode}): {output!r}')
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def compare_trees(trees, duration, repeat):
    """
    Print whole-process and start-up times of ``qfa-sim static`` per source tree.

    ``trees``: ``[(label, directory)]``; every repetition runs each tree once, in turn.
    """
    rows = {label: {'process': [], 'start-up': []} for label, _ in trees}
    for _, tree in trees:
        run_process(1.0, tree)  # the JIT cache and the file cache of each tree
    for _ in range(repeat):
        for label, tree in trees:
            rows[label]['process'].append(run_process(duration, tree))
            rows[label]['start-up'].append(run_process(1.0, tree))
    print(f'{repeat} interleaved repetitions per tree, {duration:g} s of sensor time; '
          f'medians (wall s / CPU s).\n')
    print(f'| tree | `qfa-sim static --duration {duration:g}`, whole process | '
          '`--duration 1` (start-up, summary) |')
    print('|---|---|---|')
    for label, row in rows.items():
        cells = []
        for name in ('process', 'start-up'):
            wall = statistics.median(r[0] for r in row[name])
            cpu = statistics.median(r[1] for r in row[name])
            cells.append(f'{wall:.2f} / {cpu:.2f}')
        print(f'| {label} | {cells[0]} | {cells[1]} |')


def main():
    """Run the comparison and print a Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--duration', type=float, default=3600.0,
                        help='sensor seconds of the qfa-sim run and of the loops [s]')
    parser.add_argument('--repeat', type=int, default=5)
    parser.add_argument('--tree', action='append', default=[],
                        help='LABEL=DIR: compare the whole process of these source trees '
                        'instead (no limit loops)')
    args = parser.parse_args()
    if args.tree:
        compare_trees([tuple(spec.split('=', 1)) for spec in args.tree], args.duration,
                      args.repeat)
        return
    from qfa_ros.model.parallel import available_cores
    from qfa_ros.model.triad_config import TriadConfig

    config = TriadConfig()
    n_samples = int(round(args.duration * config.sample_rate_hz))
    steps = n_samples * config.decimation
    cores = available_cores()
    run_process(1.0)  # warm the JIT cache and the file cache
    rows = {'process': [], 'start-up': [], 'limit': [], 'limit, noise off': [], 'kernel': []}
    for _ in range(args.repeat):
        rows['process'].append(run_process(args.duration))
        rows['start-up'].append(run_process(1.0))
        rows['limit'].append(run_limit(n_samples, True))
        rows['limit, noise off'].append(run_limit(n_samples, False))
        rows['kernel'].append(run_kernel(n_samples))

    def median(name, column):
        return statistics.median(row[column] for row in rows[name])

    limit_rate = steps / median('limit', 1)
    two_core_limit = 3 * steps / (min(cores, 3) * limit_rate)
    process_wall = median('process', 0)
    print(f'{args.repeat} interleaved repetitions, {args.duration:g} s of sensor time, '
          f'{cores} cores available; medians.\n')
    print('| run | wall s | CPU s | axis-steps/s (CPU) | real time (wall) | note |')
    print('|---|---|---|---|---|---|')
    print(f'| `qfa-sim static --duration {args.duration:g}`, whole process | '
          f'{process_wall:.2f} | {median("process", 1):.2f} | '
          f'{3 * steps / median("process", 1) / 1e6:.1f} M | '
          f'{args.duration / process_wall:.0f}x | peak RSS {median("process", 2):.0f} MB |')
    print(f'| `qfa-sim static --duration 1` (start-up, summary) | {median("start-up", 0):.2f} | '
          f'{median("start-up", 1):.2f} | | | peak RSS {median("start-up", 2):.0f} MB |')
    for name, label in (('limit', 'limit loop, full noise from a Generator, 1 axis'),
                        ('limit, noise off', 'limit loop without noise, 1 axis'),
                        ('kernel', '`AxisLoop.run`, its noise, 1 axis')):
        wall, cpu = median(name, 0), median(name, 1)
        print(f'| {label} | {wall:.2f} | {cpu:.2f} | {steps / cpu / 1e6:.1f} M | '
              f'{args.duration / wall:.0f}x per axis | |')
    limit_cpu = 3 * median('limit', 1)
    print(f'\nTwo-core limit for three axes (CPU rate of the noisy limit loop): '
          f'{two_core_limit:.2f} s; whole-process wall / two-core limit = '
          f'{process_wall / two_core_limit:.2f}. CPU time (robust on a busy machine): '
          f'whole process / three axes at the limit = {median("process", 1) / limit_cpu:.2f}, '
          f'without the start-up = '
          f'{(median("process", 1) - median("start-up", 1)) / limit_cpu:.2f}; '
          f'kernel / limit = {median("kernel", 1) / median("limit", 1):.2f}; '
          f'whole-process CPU / wall = {median("process", 1) / process_wall:.2f} cores.')


if __name__ == '__main__':
    main()
