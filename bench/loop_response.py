"""Measure the loop's margins, bandwidth and step response on the simulated loop.

Run: ``.venv/bin/python bench/loop_response.py [--seed 7] [--periods 8]
[--figure docs/figures/loop_response.png]``.

Loop breaking with a periodic logarithmic chirp injected at the pendulum's summing point
(``L = -S_rf / S_ru``) and a square wave of acceleration, both on the compiled kernel with
the default noise (:mod:`qfa_ros.model.loop_response`), beside the linearized design
(:class:`qfa_ros.model.design.LinearLoop`). Prints a Markdown table; the figure shows the
Bode plot of ``L`` and of the closed loop (measured vs design) and the step response.
"""

import argparse

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from qfa_ros.model.design import LinearLoop  # noqa: E402
from qfa_ros.model.loop_response import (  # noqa: E402
    design_step,
    measure_loop,
    measure_step,
    step_figures,
)
from qfa_ros.model.triad import QfaTriad  # noqa: E402
from qfa_ros.model.triad_config import TriadConfig  # noqa: E402


def main():
    """Measure, print the table, draw the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--periods', type=int, default=8)
    parser.add_argument('--figure', default='docs/figures/loop_response.png')
    args = parser.parse_args()
    config = TriadConfig()
    controller = QfaTriad(config, rng=0).axes[0].controller
    model = LinearLoop(config.hardware, controller, config.loop_rate_hz)
    crossover, phase_margin, gain_margin, bandwidth = model.margins()
    loop = measure_loop(config, rng=args.seed, periods=args.periods)
    m = loop.margins()
    step = measure_step(config, rng=args.seed + 1)
    design = design_step(config, controller, len(step.time_s))
    overshoot, rise, settling = step_figures(design, step.settle_band, config.loop_rate_hz)
    print('| figure | measured on the simulated loop (± 1σ) | linearized design |')
    print('|---|---|---|')
    print(f'| gain crossover | {m.crossover_hz:.2f} ± {m.crossover_se_hz:.2f} Hz '
          f'| {crossover:.2f} Hz |')
    print(f'| phase margin | {m.phase_margin_deg:.2f} ± {m.phase_margin_se_deg:.2f}° '
          f'| {phase_margin:.2f}° |')
    print(f'| gain margin | {m.gain_margin_db:.2f} ± {m.gain_margin_se_db:.3f} dB '
          f'(at {m.phase_crossover_hz:.0f} Hz) | {gain_margin:.2f} dB |')
    print(f'| closed-loop −3 dB bandwidth | {m.bandwidth_hz:.1f} ± {m.bandwidth_se_hz:.1f} Hz '
          f'| {bandwidth:.1f} Hz |')
    print(f'| step overshoot | {step.overshoot * 100:.2f} ± {step.overshoot_se * 100:.2f} % '
          f'| {overshoot * 100:.2f} % |')
    print(f'| 10–90 % rise time | {step.rise_time_s * 1e3:.2f} ms | {rise * 1e3:.2f} ms |')
    print(f'| 2 % settling time | {step.settling_time_s * 1e3:.1f} ms '
          f'| {settling * 1e3:.1f} ms |')
    print(f'\nbins {m.resolution_hz:.3f} Hz, {loop.periods} chirp periods, '
          f'{step.edges} step edges, seed {args.seed}')

    fig, axes = plt.subplots(3, 1, figsize=(8, 10), dpi=110)
    f = loop.freq_hz
    dense = np.logspace(np.log10(f[0]), np.log10(f[-1]), 2000)
    for values, design_values, label in (
            (loop.loop_gain, model.loop_gain(dense), 'open loop L'),
            (loop.closed_loop, model.closed_loop(dense), 'closed loop')):
        axes[0].semilogx(f, 20 * np.log10(np.abs(values)), '.', ms=1.5,
                         label=f'{label}, measured')
        axes[0].semilogx(dense, 20 * np.log10(np.abs(design_values)), '-', lw=0.8,
                         label=f'{label}, design')
        axes[1].semilogx(f, np.degrees(np.unwrap(np.angle(values))), '.', ms=1.5)
        axes[1].semilogx(dense, np.degrees(np.unwrap(np.angle(design_values))), '-', lw=0.8)
    axes[0].axhline(0.0, color='grey', lw=0.5)
    axes[0].axhline(-3.0, color='grey', lw=0.5, ls=':')
    axes[0].axvline(m.crossover_hz, color='grey', lw=0.5)
    axes[0].set_ylabel('gain [dB]')
    axes[0].set_ylim(-40, 40)
    axes[0].legend(fontsize=7)
    axes[0].set_title(f'measured: crossover {m.crossover_hz:.1f} Hz, PM '
                      f'{m.phase_margin_deg:.2f}°, GM {m.gain_margin_db:.2f} dB, '
                      f'BW {m.bandwidth_hz:.0f} Hz', fontsize=9)
    axes[1].axhline(-180.0, color='grey', lw=0.5)
    axes[1].set_ylabel('phase [deg]')
    axes[1].set_xlabel('frequency [Hz]')
    axes[2].plot(step.time_s * 1e3, step.response, '.', ms=2, label='measured')
    axes[2].plot(step.time_s * 1e3, design, '-', lw=0.8, label='design')
    axes[2].axhspan(1 - step.settle_band, 1 + step.settle_band, color='grey', alpha=0.2)
    axes[2].set_xlim(0, 20)
    axes[2].set_xlabel('time after the step [ms]')
    axes[2].set_ylabel('output / step')
    axes[2].set_title(f'step: overshoot {step.overshoot * 100:.1f} %, rise '
                      f'{step.rise_time_s * 1e3:.2f} ms, 2 % settling '
                      f'{step.settling_time_s * 1e3:.1f} ms', fontsize=9)
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.figure)
    print(f'figure: {args.figure}')


if __name__ == '__main__':
    main()
