"""Summaries and figures of a fleet study's results table."""

import numpy as np

from qfa_ros.model.triad import AXES


def _columns(table, stem):
    """Return the per-axis columns ``stem_x, stem_y, stem_z`` stacked as one array."""
    return np.concatenate([np.asarray(table.column(f'{stem}_{axis}')) for axis in AXES])


def summary_rows(table):
    """
    Return ``(quantity, mean |.|, p95 |.|, max |.|)`` rows over every unit, calibration, axis.

    Scale-factor and bias errors before and after self-calibration, and each schedule's
    estimate against its chain's drift alone with the share within two reported standard
    errors. Each label says what it compares: only the scale-factor error, measured with
    a known input, scores the calibration; the estimates also carry temperature effects
    the chain-drift columns leave out (:data:`ESTIMATE_LABELS`).
    """
    rows = []
    for label, stem in (('scale-factor error before (known input) [ppm]', 'sf_before_ppm'),
                        ('scale-factor error after (known input): the accuracy [ppm]',
                         'sf_after_ppm'),
                        ('bias error before [ug]', 'bias_before_ug'),
                        ('bias error after (gain calibration leaves the bias) [ug]',
                         'bias_after_ug')):
        values = np.abs(_columns(table, stem))
        rows.append((label, values.mean(), np.percentile(values, 95), values.max()))
    for kind in ('forward', 'feedback'):
        error = _columns(table, f'{kind}_estimate_ppm') - _columns(table, f'{kind}_truth_ppm')
        values = np.abs(error)
        difference, within_label = ESTIMATE_LABELS[kind]
        rows.append((difference, values.mean(), np.percentile(values, 95), values.max()))
        within = values <= 2 * _columns(table, f'{kind}_std_ppm')
        rows.append((within_label, 100 * within.mean(), np.nan, np.nan))
    return rows


ESTIMATE_LABELS = {
    'forward': (
        'forward estimate - forward-chain drift [ppm] (truth sampled once, before the '
        'schedule)',
        "forward estimate within 2 SE of that drift [%] (low: the SE is noise only, not "
        "the chain's +33 ppm/degC temperature terms)"),
    'feedback': (
        'feedback estimate - k_VI k_DA drift alone [ppm] (not an error: the estimate also '
        "holds the I_ref step's and, corrected, the scale's temperature change since the "
        'reference)',
        'feedback estimate within 2 SE of that drift [%] (low by design, same reason)'),
}
"""Labels of the estimate rows: what each compares, and why it is not the accuracy."""


def residual_metrics(table):
    r"""
    Return the residual scale-factor error after self-calibration over every row and axis.

    Keys ``error before mean ppm`` (mean \|error| before), ``residual mean ppm``, its
    standard error ``residual mean se ppm``, ``residual p95 ppm``, ``residual max ppm``
    (all of \|error| after) and ``sensor time s`` (mean schedule duration).
    """
    after = np.abs(_columns(table, 'sf_after_ppm'))
    before = np.abs(_columns(table, 'sf_before_ppm'))
    return {'error before mean ppm': float(before.mean()),
            'residual mean ppm': float(after.mean()),
            'residual mean se ppm': float(after.std(ddof=1) / np.sqrt(after.size)),
            'residual p95 ppm': float(np.percentile(after, 95)),
            'residual max ppm': float(after.max()),
            'sensor time s': float(np.mean(np.asarray(table.column('schedule_s'))))}


ZERO_DRIFT_LIMIT_UG = 30.0
"""Acceptance of the temperature calibration: zero-drift p2p per attitude and axis [ug]."""
SCALE_LIMIT_PPM = 20.0
"""Acceptance of the temperature calibration: scale-factor error per axis [ppm]."""


def self_calibration_claim(table):
    r"""Return mean, p95, p99 and max of \|residual| after self-calibration [ppm] (all axes)."""
    after = np.abs(_columns(table, 'sf_after_ppm'))
    return {'mean': float(after.mean()), 'p95': float(np.percentile(after, 95)),
            'p99': float(np.percentile(after, 99)), 'max': float(after.max()),
            'count': int(after.size)}


def temperature_rows(table):
    r"""
    Return the temperature study's distribution rows per quantity and axis.

    Each row: ``(quantity, axis, median, p95, max, yield %)``: the worst attitude's
    zero-drift p2p [ug] (yield: <= :data:`ZERO_DRIFT_LIMIT_UG`), the scale factor's p2p
    and largest \|error| over the temperatures [ppm] (yield: <= :data:`SCALE_LIMIT_PPM`).
    """
    rows = []
    for label, stem, limit in (('zero-drift p2p, worst attitude [ug]', 'zd_max_ug',
                                ZERO_DRIFT_LIMIT_UG),
                               ('scale-factor p2p [ppm]', 'sf_p2p_ppm', SCALE_LIMIT_PPM),
                               ('scale-factor max |error| [ppm]', 'sf_max_ppm',
                                SCALE_LIMIT_PPM)):
        for axis in AXES:
            values = np.asarray(table.column(f'{stem}_{axis}'))
            rows.append((label, axis, float(np.median(values)),
                         float(np.percentile(values, 95)), float(values.max()),
                         100.0 * float(np.mean(values <= limit))))
    return rows


def temperature_failures(table):
    """Return the rows (dicts) of units outside the acceptance on any axis."""
    return [row for row in table.to_pylist()
            if any(row[f'zd_max_ug_{a}'] > ZERO_DRIFT_LIMIT_UG
                   or row[f'sf_p2p_ppm_{a}'] > SCALE_LIMIT_PPM
                   or row[f'sf_max_ppm_{a}'] > SCALE_LIMIT_PPM for a in AXES)]


def format_temperature_summary(table):
    """Return a temperature study's summary as Markdown."""
    units = table.num_rows
    failures = temperature_failures(table)
    cpu = np.asarray(table.column('cpu_s'))
    lines = [f'{units} units; CPU per unit mean {cpu.mean():.1f} s, max {cpu.max():.1f} s; '
             f'units within every limit (all axes, attitudes, both scale-factor figures): '
             f'{units - len(failures)} of {units} ({100.0 * (1 - len(failures) / units):.1f} %)',
             '', '| quantity | axis | median | p95 | max | yield [%] |',
             '|---|---|---|---|---|---|']
    for label, axis, median, p95, worst, share in temperature_rows(table):
        lines.append(f'| {label} | {axis} | {median:.1f} | {p95:.1f} | {worst:.1f} | '
                     f'{share:.1f} |')
    lag = np.abs(np.asarray(table.column('probe_lag_s'))
                 - np.asarray(table.column('probe_tau_s')))
    lines += ['', f'probe-lag estimate - truth: median {np.median(lag):.3f} s, max '
              f'{lag.max():.3f} s']
    if failures:
        lines += ['', 'Units outside the limits (unit.seed, probe lag true/estimated, worst '
                  'zero drift ug / SF p2p / SF max ppm per axis):']
        for row in failures:
            cells = ', '.join(f'{a} {row[f"zd_max_ug_{a}"]:.1f}/{row[f"sf_p2p_ppm_{a}"]:.1f}/'
                              f'{row[f"sf_max_ppm_{a}"]:.1f}' for a in AXES)
            lines.append(f'- unit {row["unit"]} (seed {row["unit_seed"]}), lag '
                         f'{row["probe_tau_s"]:.2f}/{row["probe_lag_s"]:.2f} s: {cells}')
    return '\n'.join(lines)


def format_summary(table):
    """Return the summary as a Markdown table."""
    if 'zd_max_ug_x' in table.column_names:
        return format_temperature_summary(table)
    units = len(set(np.asarray(table.column('unit')).tolist()))
    calibrations = int(np.asarray(table.column('calibration')).max())
    lines = [f'{units} units x {calibrations} calibrations x {len(AXES)} axes',
             '', '| quantity | mean | p95 | max |', '|---|---|---|---|']
    for label, mean, p95, worst in summary_rows(table):
        cells = [f'{v:.2f}' if np.isfinite(v) else '' for v in (mean, p95, worst)]
        lines.append(f'| {label} | ' + ' | '.join(cells) + ' |')
    claim = self_calibration_claim(table)
    lines += ['', f'|residual scale-factor error| after self-calibration over '
              f'{claim["count"]} unit-axes: mean {claim["mean"]:.2f}, p95 {claim["p95"]:.2f}, '
              f'p99 {claim["p99"]:.2f}, max {claim["max"]:.2f} ppm']
    return '\n'.join(lines)


def draw_figures(table, out_dir, name='study'):
    """Write histogram, residual-versus-time and estimate-versus-truth PNGs; return paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    if 'zd_max_ug_x' in table.column_names:
        figure, panels = plt.subplots(1, 2, figsize=(9, 4))
        for panel, stem, limit, label in (
                (panels[0], 'zd_max_ug', ZERO_DRIFT_LIMIT_UG, 'zero-drift p2p, worst attitude '
                 '[ug]'), (panels[1], 'sf_p2p_ppm', SCALE_LIMIT_PPM, 'scale-factor p2p [ppm]')):
            # Common bins up to twice the limit; a unit beyond it counts in the last bin
            # (one outlier would otherwise squeeze every other unit into one bar).
            top = 2.0 * limit
            bins = np.linspace(0.0, top, 41)
            beyond = 0
            for axis in AXES:
                values = np.asarray(table.column(f'{stem}_{axis}'), dtype=float)
                beyond += int(np.sum(values > top))
                panel.hist(np.minimum(values, top), bins=bins, alpha=0.5, label=axis)
            panel.axvline(limit, color='k', linestyle='--', label='limit')
            if beyond:
                panel.annotate(f'{beyond} axis value(s) beyond {top:g}\nin the last bin',
                               xy=(0.97, 0.45), xycoords='axes fraction', ha='right')
            panel.set(xlabel=label, ylabel='units')
            panel.legend()
        figure.suptitle(f'{name}: temperature calibration, eight attitudes')
        written.append(_save(figure, out_dir / 'fleet_temperature_histogram.png', plt))
        return written
    before, after = _columns(table, 'sf_before_ppm'), _columns(table, 'sf_after_ppm')
    figure, axes = plt.subplots(figsize=(7, 4))
    bins = np.linspace(-max(np.abs(before).max(), 1), max(np.abs(before).max(), 1), 60)
    axes.hist(before, bins=bins, alpha=0.6, label='before self-calibration')
    axes.hist(after, bins=bins, alpha=0.6, label='after self-calibration')
    axes.set(xlabel='scale-factor error [ppm]', ylabel='unit-axis-calibrations',
             title=f'{name}: residual scale-factor error')
    axes.legend()
    written.append(_save(figure, out_dir / 'fleet_residual_histogram.png', plt))

    calibration = np.asarray(table.column('calibration'))
    days = np.asarray(table.column('time_days'))
    figure, axes = plt.subplots(figsize=(7, 4))
    for stem, label in (('sf_before_ppm', 'before'), ('sf_after_ppm', 'after')):
        values = np.abs(np.column_stack([np.asarray(table.column(f'{stem}_{a}'))
                                         for a in AXES]))
        steps = np.unique(calibration)
        t = [days[calibration == k][0] for k in steps]
        median = [np.median(values[calibration == k]) for k in steps]
        p95 = [np.percentile(values[calibration == k], 95) for k in steps]
        line, = axes.plot(t, median, marker='o', label=f'{label}: median')
        axes.plot(t, p95, linestyle='--', color=line.get_color(), label=f'{label}: p95')
    axes.set(xlabel='time since reference capture [days]', ylabel='|scale-factor error| [ppm]',
             title=f'{name}: residual versus time')
    axes.legend()
    written.append(_save(figure, out_dir / 'fleet_residual_vs_time.png', plt))

    figure, panels = plt.subplots(1, 2, figsize=(9, 4))
    for panel, kind in zip(panels, ('forward', 'feedback')):
        truth = _columns(table, f'{kind}_truth_ppm')
        estimate = _columns(table, f'{kind}_estimate_ppm')
        panel.plot(truth, estimate, '.', markersize=2)
        low, high = min(truth.min(), estimate.min()), max(truth.max(), estimate.max())
        panel.plot([low, high], [low, high], 'k-', linewidth=0.8)
        panel.set(xlabel='true drift [ppm]', ylabel='estimated drift [ppm]',
                  title=f'{kind} gain')
    figure.suptitle(f'{name}: estimated versus true')
    written.append(_save(figure, out_dir / 'fleet_estimate_vs_truth.png', plt))
    return written


def _save(figure, path, plt):
    try:
        figure.tight_layout()
        figure.savefig(path, dpi=110)
    finally:
        plt.close(figure)
    return path
