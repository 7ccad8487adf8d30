"""
Benchmark the temperature compensation chain (Liu, Li and Shen) and print Markdown tables.

Run from the repository root::

    .venv/bin/python bench/temperature_comp.py > bench/results/temperature_comp.md

Sections: CORDIC accuracy vs M; double exponential vs 3rd/4th-order polynomials on a
simulated temperature cycle of the default thermal model; peak-to-peak zero drift
before/after the fixed-point compensation; fit time; per-sample compensation cost; the
six-position calibration of five drawn units verified in six orientations on another
cycle (``--units N``; ``--short``: one unit, every thermal time scaled by 1/5, to prove
the script works in a few minutes).
"""

import argparse
import dataclasses
import math
from pathlib import Path
import platform
import sys
import time

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from qfa_ros.calibration.cordic import CordicExp  # noqa: E402
from qfa_ros.calibration.schedule import run_schedule  # noqa: E402
from qfa_ros.calibration.state import CalibrationState  # noqa: E402
from qfa_ros.calibration.temperature import (  # noqa: E402
    temperature_schedule,
    TemperatureSettings,
)
from qfa_ros.calibration.tempfit import (  # noqa: E402
    bin_by_temperature,
    fit_double_exponential,
    fit_double_exponential_reference,
)
from qfa_ros.calibration.thermal_compensation import calibrate_zero_bias  # noqa: E402
from qfa_ros.calibration.verification import verify_cycle  # noqa: E402
from qfa_ros.model.constants import MICRO_G  # noqa: E402
from qfa_ros.model.drawn_unit import draw_unit  # noqa: E402
from qfa_ros.model.thermal import ThermalConfig, ThermalModel  # noqa: E402
from qfa_ros.model.triad_config import TriadConfig  # noqa: E402

SEED = 20240611
THERMAL_DT = 0.1
AVERAGE = 10
"""Thermal samples per 1-s output average."""
CYCLES = 2
WHITE_NOISE_1S = 5.0 * MICRO_G
"""Zero-output white noise of a 1-s average (5 ug/sqrt(Hz) QA-2000-class figure)."""


def _best_time(function, repeats=5):
    best = math.inf
    for _ in range(repeats):
        started = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - started)
    return best


def _cordic_inputs(cordic, rng):
    total = cordic.z_max_q - cordic.z_min_q + 1
    if total <= 1 << 23:
        return np.arange(cordic.z_min_q, cordic.z_max_q + 1, dtype=np.int64), 'all'
    boundaries = np.round(np.arange(-2 ** cordic.n_bits / math.log(2) - 1,
                                    2 ** cordic.n_bits / math.log(2) + 1)
                          * math.log(2) * cordic.scale).astype(np.int64)
    words = np.concatenate([rng.integers(cordic.z_min_q, cordic.z_max_q + 1, 1 << 22),
                            (boundaries[:, None] + np.arange(-3, 4)).ravel(),
                            [cordic.z_min_q, cordic.z_max_q, 0, 1, -1]])
    words = words[(words >= cordic.z_min_q) & (words <= cordic.z_max_q)]
    return words, f'{words.size:,} sampled + edges'


def cordic_table(rng):
    lines = ['## CORDIC e^z: max relative error over the whole input range [-2^N, 2^N)', '',
             'Relative error of `mantissa * 2^(Q - W)` against `exp(z_q / 2^M)` (exact input '
             'word). `guard 0` is the datapath of Liu, Li and Shen (every constant quantized to '
             'M bits); `guard 4` the default.', '',
             '| M | N | inputs | guard 0 (Liu, Li and Shen) | guard 4 (default) '
             '| ns/sample (guard 4) |',
             '|---|---|---|---|---|---|']
    for n_bits in (6, 4):
        for m_bits in (12, 14, 16, 20, 24):
            errors = []
            for guard_bits in (0, 4):
                cordic = CordicExp(m_bits=m_bits, n_bits=n_bits, guard_bits=guard_bits)
                words, label = _cordic_inputs(cordic, rng)
                mantissa, q = cordic.exp_parts_array(words)
                value = np.ldexp(mantissa.astype(float), (q - cordic.work_bits).astype(np.int32))
                errors.append(np.max(np.abs(value / np.exp(words / cordic.scale) - 1.0)))
            sample = words[:1 << 20]
            elapsed = _best_time(lambda: cordic.exp_parts_array(sample), 3)  # noqa: B023
            lines.append(f'| {m_bits} | {n_bits} | {label} | {errors[0] * 100:.2e} % | '
                         f'{errors[1] * 100:.2e} % | {elapsed / sample.size * 1e9:.1f} |')
    return lines


SCENARIOS = [
    ('default (double-exp truth)', {}),
    ('+ 30 s temperature-probe lag', {'probe_tau_s': 30.0}),
    ('+ 10 ug heating/cooling hysteresis', {'hysteresis_m_s2': (10 * MICRO_G,) * 3}),
    ('cubic truth (S-shaped, 16 ug/degC max)', {
        'bias_model': 'polynomial',
        'bias_poly': ((0.0, 1e-4, 5e-7, -1.5e-8),) * 3}),
]


def simulate_cycle(overrides, rng):
    """Return 1-s averages of V_temp and of the zero output (bias + white noise), per axis."""
    config = ThermalConfig(**overrides)
    model = ThermalModel(config, rng)
    samples = int(round(CYCLES * config.cycle_period_s / THERMAL_DT))
    chunks = []
    done = 0
    while done < samples:
        n = min(20000, samples - done)
        chunks.append(model.run(n, THERMAL_DT))
        done += n
    v_temp = np.concatenate([c.v_temp for c in chunks]).reshape(-1, AVERAGE).mean(axis=1)
    bias = np.concatenate([c.bias for c in chunks]).reshape(-1, AVERAGE, 3).mean(axis=1)
    noise = WHITE_NOISE_1S * rng.standard_normal(bias.shape)
    return v_temp, bias + noise


def _moving_p2p(series, width=60):
    means = series[: series.size // width * width].reshape(-1, width).mean(axis=1)
    return float(np.ptp(means))


def fit_and_drift_tables(rng):
    config = ThermalConfig()
    fit_lines = [
        '## Fit on a simulated temperature cycle of the default thermal model', '',
        f'{CYCLES} trapezoid cycles -40..+70 degC, period {config.cycle_period_s:.0f} s, '
        f'body time constant {config.sensor_tau_s:.0f} s, TMP36-like sensor '
        f'({config.tsensor_noise_v * 1e3:.1f} mV rms, {config.adc_bits}-bit ADC on '
        f'{config.adc_vref_v} V); thermal model at dt = {THERMAL_DT} s, output averaged to '
        f'1 s with {WHITE_NOISE_1S / MICRO_G:.0f} ug white noise per 1-s sample; '
        'fits on 100 V_temp bins (calibrate_zero_bias). RMSE in ug.', '',
        '| scenario | axis | double-exp RMSE | R^2 | poly3 RMSE | R^2 | poly4 RMSE | R^2 | '
        'iterations | cancellation bits |',
        '|---|---|---|---|---|---|---|---|---|---|']
    drift_lines = [
        '## Peak-to-peak zero drift before/after compensation', '',
        'p2p over the 100 V_temp bin means (the measure of Liu, Li and Shen) and over 60-s '
        'means of the time series (includes white noise and every effect that is not a '
        'function of V_temp). Compensation = fixed-point double exponential, M = 16; '
        'poly4 = float 4th-order polynomial for comparison. Values in ug.', '',
        '| scenario | axis | p2p before | after (bins) | reduction | poly4 after (bins) | '
        'before (60 s) | after (60 s) | reduction (60 s) |',
        '|---|---|---|---|---|---|---|---|---|']
    timing = {}
    for name, overrides in SCENARIOS:
        v_temp, outputs = simulate_cycle(overrides, rng)
        for axis, label in enumerate('xyz'):
            output = outputs[:, axis]
            calibration = calibrate_zero_bias(v_temp, output, m_bits=16)
            fit, poly3, poly4 = calibration.fit, calibration.poly3, calibration.poly4
            fit_lines.append(
                f'| {name} | {label} | {fit.rmse / MICRO_G:.3f} | {fit.r_squared:.6f} | '
                f'{poly3.rmse / MICRO_G:.3f} | {poly3.r_squared:.6f} | '
                f'{poly4.rmse / MICRO_G:.3f} | {poly4.r_squared:.6f} | {fit.iterations} | '
                f'{calibration.cancellation_bits:.1f} |')
            compensated = output - calibration.compensator().evaluate_fixed(v_temp, clip=True)
            before_60, after_60 = _moving_p2p(output), _moving_p2p(compensated)
            drift_lines.append(
                f'| {name} | {label} | {calibration.p2p_before / MICRO_G:.1f} | '
                f'{calibration.p2p_after / MICRO_G:.2f} | x{calibration.reduction:.0f} | '
                f'{calibration.p2p_after_poly4 / MICRO_G:.2f} | {before_60 / MICRO_G:.1f} | '
                f'{after_60 / MICRO_G:.2f} | x{before_60 / after_60:.0f} |')
            if not timing:
                timing['data'] = (v_temp, output)
    return fit_lines, drift_lines, timing['data']


def fit_time_table(v_temp, output):
    v_bins, y_bins, _ = bin_by_temperature(v_temp, output, 100)
    lines = ['## Fit time (best of 5)', '',
             '| data | alternating iteration [ms] | iterations | scipy least_squares (LM) '
             '[ms] | nfev | RMSE ratio alt/ref - 1 |', '|---|---|---|---|---|---|']
    for label, (v, y) in (('100 V_temp bins', (v_bins, y_bins)),
                          (f'{v_temp.size} raw 1-s samples', (v_temp, output))):
        alternating = fit_double_exponential(v, y)
        reference = fit_double_exponential_reference(v, y)
        t_alt = _best_time(lambda: fit_double_exponential(v, y))  # noqa: B023
        t_ref = _best_time(lambda: fit_double_exponential_reference(v, y))  # noqa: B023
        lines.append(f'| {label} | {t_alt * 1e3:.2f} | {alternating.iterations} | '
                     f'{t_ref * 1e3:.2f} | {reference.iterations} | '
                     f'{alternating.rmse / reference.rmse - 1:.1e} |')
    return lines


def cost_table(v_temp, output, rng):
    calibration = calibrate_zero_bias(v_temp, output, m_bits=16)
    compensator = calibration.compensator()
    low, high = compensator.v_range
    voltages = rng.uniform(low, high, 1_000_000)
    words = compensator.quantize_v(voltages)
    compensator.evaluate_fixed_q(words[:10])
    fixed = _best_time(lambda: compensator.evaluate_fixed_q(words), 3)
    fixed_float = _best_time(lambda: compensator.evaluate_fixed(voltages), 3)
    reference = _best_time(lambda: compensator.evaluate_reference(voltages), 3)
    scalar_words = words[:2000]
    scalar = _best_time(lambda: [compensator.evaluate_fixed_scalar(w) for w in scalar_words], 3)
    error = np.abs(compensator.evaluate_fixed(voltages) - compensator.evaluate_reference(voltages))
    rom = compensator.rom()
    return ['## Per-sample compensation cost (1e6 samples, best of 3)', '',
            f'Compensator M = {rom["m_bits"]}, N = {rom["n_bits"]} (chosen from the fit), '
            f'guard bits {rom["guard_bits"]}, output LSB 2^-{rom["output_frac_bits"]} = '
            f'{compensator.output_lsb / MICRO_G:.4f} ug, V range {low:.3f}..{high:.3f} V; '
            f'max |fixed - float| = {error.max() / MICRO_G:.4f} ug over the range.', '',
            '| path | ns/sample |', '|---|---|',
            f'| fixed point, int64 words in/out (`evaluate_fixed_q`) | '
            f'{fixed / words.size * 1e9:.1f} |',
            f'| fixed point incl. V quantization and rescale (`evaluate_fixed`) | '
            f'{fixed_float / words.size * 1e9:.1f} |',
            f'| float reference (`evaluate_reference`) | {reference / words.size * 1e9:.1f} |',
            f'| scalar Python-int path (`evaluate_fixed_scalar`) | '
            f'{scalar / scalar_words.size * 1e9:.0f} |']


NOTES = [
    '## Reading the tables', '',
    '- CORDIC: with `guard 0` (the datapath of Liu, Li and Shen) the error of the `2^M/ln2` '
    "constant is multiplied by |z|, so Liu, Li and Shen's 0.019 % at M = 16 holds only for "
    'small |z| (N <= 4 region); the default 4 guard bits keep the whole [-2^6, 2^6) range within '
    '0.02 % at M = 16 and 2e-6 at M = 24. The mantissa/exponent output keeps the relative '
    'error bounded for very negative z (Q down to -93).',
    '- Default scenario: the ground truth is itself a double exponential in V_temp, so the '
    'bin residual is limited by the white noise left in each bin (about 5 ug / sqrt(samples '
    'per bin)), not by the model or the M = 16 fixed-point path (< 0.05 ug).',
    '- Probe lag: bins still flatten (heating and cooling average out in a bin) but the '
    'time series shows the lag as a heating/cooling split; hysteresis does the same '
    'without any lag. Neither is a function of V_temp, so no V_temp-only model removes '
    "it: these set the practical >= 10x..30x limit, like Liu, Li and Shen's tenfold result.",
    '- Cubic (S-shaped) truth: a sum of two exponentials has at most one extremum and one '
    'inflection, their spacing tied to the betas; this curve is outside that family, the '
    'best fit is the degenerate limit (beta1 ~ beta2, opposite alphas of ~150), '
    '`cancellation_bits` flags it and the 16-bit compensator output is then worthless; '
    'poly3/poly4 fit it to the noise.',
]


REDUCED_LOOP = {'loop_rate_hz': 2000.0, 'sample_rate_hz': 100.0, 'crossover_hz': 100.0}
"""Reduced-cost loop: the steady-state output depends on the feedback gain only, and this
loop settles to 1 ug in 0.2 s after a tumble step (the 10 kHz default: 0.05 s)."""


def units_table(units, short):
    """Calibrate ``units`` drawn units in six positions; verify in six on a sine cycle."""
    scale = 0.2 if short else 1.0
    tau = 300.0 * scale
    calibration_s, verification_s = 3600.0 * scale * 1.2, 4800.0 * scale * 1.2
    lines = ['## Six-position calibration of drawn units, verified in six orientations', '',
             f'Units drawn by seed (qfa_ros.model.drawn_unit); body time constant {tau:g} s; '
             f'calibration: chamber plateaus -40..+70 degC every 10 degC, {calibration_s:g} s '
             'program + extreme soaks + soak back, head tumbling +x +y +z -z -y -x with 2 s '
             f'dwell; verification: sine chamber cycle of {verification_s:g} s, the head '
             'tumbling in the reverse order; 10 degC bins of the on-board reading. Loop at '
             '2 kHz / 100 Hz output (reduced cost; same thermal errors). Acceptance: '
             'zero drift <= 30 ug and scale-factor residual <= 20 ppm in every position, '
             'every axis.', '',
             '| unit | turn-on bias x/y/z ug | bias p2p before x/y/z ug | worst zero-drift '
             'p2p after x/y/z ug | SF p2p before x/y/z ppm | SF residual after x/y/z ppm | '
             'soak back s |', '|---|---|---|---|---|---|---|']
    for seed in tqdm(range(units), desc='units', disable=None, file=sys.stderr):
        unit = draw_unit(seed)
        unit = dataclasses.replace(unit, probe_tau_s=unit.probe_tau_s * scale)
        config = TriadConfig(thermal=ThermalConfig(ambient_profile='constant',
                                                   sensor_tau_s=tau), **REDUCED_LOOP)
        triad = unit.triad(config, rng=seed)
        result = run_schedule(triad, temperature_schedule(
            triad, CalibrationState(), TemperatureSettings(period_s=calibration_s,
                                                           block_s=2.0, bins=40)))
        verification = verify_cycle(triad, period_s=verification_s, block_s=2.0)
        comp = result.compensation

        def triple(values, digits=1):
            return '/'.join(f'{v:.{digits}f}' for v in values)

        lines.append(
            f'| {seed} | {triple(np.array(unit.turn_on_bias) / MICRO_G, 0)} | '
            f'{triple([c.p2p_before / MICRO_G for c in comp.bias], 0)} | '
            f'{triple(verification.zero_drift_p2p.max(axis=0) / MICRO_G)} | '
            f'{triple([c.p2p_before * 1e6 for c in comp.scale], 0)} | '
            f'{triple(verification.scale_residual * 1e6)} | {result.soak_s:.0f} |')
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--units', type=int, default=5, help='drawn units (default 5)')
    parser.add_argument('--short', action='store_true',
                        help='only the drawn-unit section, one unit, time scaled by 1/5')
    args = parser.parse_args(argv)
    if args.short:
        print('\n'.join(units_table(1, True)))
        return
    rng = np.random.default_rng(SEED)
    lines = ['# Temperature compensation benchmark (Liu, Li and Shen)', '',
             f'Python {platform.python_version()}, numpy {np.__version__}, '
             f'{platform.machine()}; seed {SEED}.', '']
    lines += cordic_table(rng) + ['']
    fit_lines, drift_lines, (v_temp, output) = fit_and_drift_tables(rng)
    lines += fit_lines + [''] + drift_lines + ['']
    lines += fit_time_table(v_temp, output) + ['']
    lines += cost_table(v_temp, output, rng) + [''] + NOTES + ['']
    lines += units_table(args.units, False)
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
