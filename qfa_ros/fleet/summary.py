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
    """
    Return the residual scale-factor error after self-calibration over every row and axis.

    Keys ``error before mean ppm`` (mean |error| before), ``residual mean ppm``, its
    standard error ``residual mean se ppm``, ``residual p95 ppm``, ``residual max ppm``
    (all of |error| after) and ``sensor time s`` (mean schedule duration).
    """
    after = np.abs(_columns(table, 'sf_after_ppm'))
    before = np.abs(_columns(table, 'sf_before_ppm'))
    return {'error before mean ppm': float(before.mean()),
            'residual mean ppm': float(after.mean()),
            'residual mean se ppm': float(after.std(ddof=1) / np.sqrt(after.size)),
            'residual p95 ppm': float(np.percentile(after, 95)),
            'residual max ppm': float(after.max()),
            'sensor time s': float(np.mean(np.asarray(table.column('schedule_s'))))}


def format_summary(table):
    """Return the summary as a Markdown table."""
    units = len(set(np.asarray(table.column('unit')).tolist()))
    calibrations = int(np.asarray(table.column('calibration')).max())
    lines = [f'{units} units x {calibrations} calibrations x {len(AXES)} axes',
             '', '| quantity | mean | p95 | max |', '|---|---|---|---|']
    for label, mean, p95, worst in summary_rows(table):
        cells = [f'{v:.2f}' if np.isfinite(v) else '' for v in (mean, p95, worst)]
        lines.append(f'| {label} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def draw_figures(table, out_dir, name='study'):
    """Write histogram, residual-versus-time and estimate-versus-truth PNGs; return paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    before, after = _columns(table, 'sf_before_ppm'), _columns(table, 'sf_after_ppm')
    figure, axes = plt.subplots(figsize=(7, 4))
    bins = np.linspace(-max(np.abs(before).max(), 1), max(np.abs(before).max(), 1), 60)
    axes.hist(before, bins=bins, alpha=0.6, label='before self-calibration')
    axes.hist(after, bins=bins, alpha=0.6, label='after self-calibration')
    axes.set_xlabel('scale-factor error [ppm]')
    axes.set_ylabel('unit-axis-calibrations')
    axes.set_title(f'{name}: residual scale-factor error')
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
    axes.set_xlabel('time since reference capture [days]')
    axes.set_ylabel('|scale-factor error| [ppm]')
    axes.set_title(f'{name}: residual versus time')
    axes.legend()
    written.append(_save(figure, out_dir / 'fleet_residual_vs_time.png', plt))

    figure, panels = plt.subplots(1, 2, figsize=(9, 4))
    for panel, kind in zip(panels, ('forward', 'feedback')):
        truth = _columns(table, f'{kind}_truth_ppm')
        estimate = _columns(table, f'{kind}_estimate_ppm')
        panel.plot(truth, estimate, '.', markersize=2)
        low, high = min(truth.min(), estimate.min()), max(truth.max(), estimate.max())
        panel.plot([low, high], [low, high], 'k-', linewidth=0.8)
        panel.set_xlabel('true drift [ppm]')
        panel.set_ylabel('estimated drift [ppm]')
        panel.set_title(f'{kind} gain')
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
