"""Plot estimation traces and scenario bags like the source papers' figures.

``qfa-report BAG [BAG ...] [--out DIR]`` reads MCAP files of this project (trace
files written by :func:`qfa_ros.bag.estimation_trace.write_estimation_trace`, scenario bags of
``qfa-sim``, or directories of them) and writes PNG figures:

``forward_gain.png`` (Ran et al. 2019, Fig. 11)
    Open-loop sweep ``N_out`` against ``dN_FPGA`` for the reference and every
    estimation run, with the fitted slopes, and the deviation from the reference
    line that makes a slope change of a few hundred ppm visible.
``feedback_gain.png`` (Ran et al. 2019, Fig. 12)
    Segment means with ``I_ref`` off and on, and the step ``N_on - N_off``
    relative to the reference.
``static_output.png`` (Ran et al. 2019, Fig. 13)
    The static ``imu/data_raw`` output through the scenario phases (reference,
    drifted, compensated, ...), each phase's mean and its error in µg.
``temperature_fit.png`` (Liu, Li and Shen, Fig. 3)
    Zero bias against ``V_temp`` with the fitted double exponential.
``temperature_compensation.png`` (Liu, Li and Shen, Fig. 4)
    Zero bias before and after the compensation.

A figure is written only when its data are present. Runs from several files
given together are combined: the captured reference is compared with every
estimation run.

One cohesive thing: every figure reads the same loaded bag contents and shares its
run selection, labels and colours, so they stay in one module.
"""

import dataclasses
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np

from qfa_ros.bag.reader import mcap_read_errors
from qfa_ros.bag.trace_writer import key_values_to_dict
from qfa_ros.model.constants import MICRO_G
from qfa_ros.model.safe_files import open_regular_file
from qfa_ros.model.triad import AXES

# Headless: figures are only ever written to files.
matplotlib.use('Agg')

__all__ = ['BagContents', 'ReportFigure', 'TraceRun', 'build_figures', 'load_bag',
           'report']

IMU_TYPE = 'sensor_msgs/msg/Imu'
TABLE_TYPE = 'std_msgs/msg/Float64MultiArray'
STATUS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'
STRING_TYPE = 'std_msgs/msg/String'
TRACE_ROOT = '/qfa/trace'
DPI = 110
REFERENCE_COLOR = 'tab:blue'
RUN_COLORS = ['tab:red', 'tab:green', 'tab:purple', 'tab:brown', 'tab:pink', 'tab:olive']
PHASE_COLORS = {'reference': 'tab:blue', 'drifted': 'tab:red', 'compensated': 'tab:green',
                'estimation': 'tab:gray', 'static': 'tab:blue', 'cycle': 'tab:orange',
                'verification': 'tab:green'}


# --- loading ------------------------------------------------------------------------------

@dataclasses.dataclass
class TraceRun:
    """
    One estimation run: its settings, result and tables.

    Attributes
    ----------
    name : str
        Run name: the ``<run>`` level of a scenario bag, else the settings' ``kind``.
    source : pathlib.Path
        File it came from.
    namespace : str
        Topic namespace of the run, e.g. ``/qfa/trace/reference``.
    settings, result : dict
        Flat ``KeyValue`` dicts (see :func:`qfa_ros.bag.trace_writer.key_values_to_dict`).
    tables : dict of str to dict of numpy arrays
        Relative table name (``'forward/points'``) to columns, plus ``time_ns`` (the
        log times).
    """

    name: str
    source: Path
    namespace: str
    settings: dict = dataclasses.field(default_factory=dict)
    result: dict = dataclasses.field(default_factory=dict)
    tables: dict = dataclasses.field(default_factory=dict)

    @property
    def start_ns(self):
        """Earliest log time in the run's tables [ns] (0 when it has none)."""
        return min((int(t['time_ns'][0]) for t in self.tables.values() if len(t['time_ns'])),
                   default=0)

    def value(self, suffix, default=None):
        """Return the result value whose key is ``suffix`` or ends with ``.suffix``."""
        if suffix in self.result:
            return self.result[suffix]
        return next((value for key, value in self.result.items()
                     if key.endswith('.' + suffix)), default)

    def table_with(self, *columns):
        """Return the first table having all ``columns`` (None if none has)."""
        return next((table for table in self.tables.values()
                     if all(column in table for column in columns)), None)

    @property
    def captured(self):
        """Whether the run measured references rather than estimating drift."""
        flags = [value for key, value in self.result.items() if key.endswith('captured')]
        if flags:
            return all(bool(flag) for flag in flags)
        return self.name == 'reference'


@dataclasses.dataclass
class BagContents:
    """
    What a report can use from one file.

    Attributes
    ----------
    path : pathlib.Path
    runs : list of TraceRun
    imu_time_ns : numpy int64 array
        Log times of ``imu/data_raw`` [ns].
    imu_accel : float64[n, 3]
        Linear acceleration [m/s^2].
    phases : list of (int, str)
        Scenario phase start times [ns] and names.
    """

    path: Path
    runs: list = dataclasses.field(default_factory=list)
    imu_time_ns: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(0, dtype=np.int64))
    imu_accel: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    phases: list = dataclasses.field(default_factory=list)


def _is_trace_topic(topic):
    return topic == TRACE_ROOT or topic.startswith(TRACE_ROOT + '/')


def load_bag(path):
    """
    Read the trace runs, IMU stream and scenario phases of one MCAP file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    BagContents

    Raises
    ------
    ValueError
        ``path`` is not a regular file or not a readable MCAP file; the message names it,
        never quotes it.
    """
    path = Path(path)
    statuses = {}
    tables = {}
    imu_times, imu_accel, phases = [], [], []
    with mcap_read_errors(path), open_regular_file(path) as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topic, msgtype = channel.topic, schema.name if schema else ''
            if msgtype == STATUS_TYPE and _is_trace_topic(topic) and decoded.status:
                statuses[topic] = key_values_to_dict(decoded.status[0].values)
            elif msgtype == TABLE_TYPE and _is_trace_topic(topic):
                labels = [dim.label for dim in decoded.layout.dim]
                rows = tables.setdefault(topic, (labels, [], []))
                rows[1].append(message.log_time)
                rows[2].append(list(decoded.data))
            elif msgtype == IMU_TYPE and not _is_trace_topic(topic):
                acceleration = decoded.linear_acceleration
                imu_times.append(message.log_time)
                imu_accel.append((acceleration.x, acceleration.y, acceleration.z))
            elif msgtype == STRING_TYPE and topic.endswith('scenario/phase'):
                phases.append((message.log_time, decoded.data))
    contents = BagContents(path, phases=sorted(phases))
    if imu_times:
        order = np.argsort(imu_times, kind='stable')
        contents.imu_time_ns = np.asarray(imu_times, dtype=np.int64)[order]
        contents.imu_accel = np.asarray(imu_accel, dtype=float)[order]
    namespaces = sorted({topic.rsplit('/', 1)[0] for topic in statuses
                         if topic.endswith(('/settings', '/result'))}, key=len, reverse=True)
    runs = {namespace: TraceRun(_run_name(namespace, statuses), path, namespace,
                                statuses.get(f'{namespace}/settings', {}),
                                statuses.get(f'{namespace}/result', {}))
            for namespace in namespaces}
    for topic, (labels, times, rows) in tables.items():
        # The longest namespace owns the table: /qfa/trace/reference/forward/points
        # belongs to /qfa/trace/reference even if /qfa/trace has a run too.
        namespace = next((n for n in namespaces if topic.startswith(n + '/')), None)
        if namespace is None:
            continue
        matrix = np.asarray(rows, dtype=float).reshape(len(rows), len(labels))
        columns = {label: matrix[:, i] for i, label in enumerate(labels)}
        columns['time_ns'] = np.asarray(times, dtype=np.int64)
        runs[namespace].tables[topic[len(namespace) + 1:]] = columns
    contents.runs = sorted(runs.values(), key=lambda run: run.start_ns)
    return contents


def _run_name(namespace, statuses):
    if namespace != TRACE_ROOT and namespace.startswith(TRACE_ROOT + '/'):
        return namespace[len(TRACE_ROOT) + 1:]
    settings = statuses.get(f'{namespace}/settings', {})
    return str(settings.get('kind', namespace.rsplit('/', 1)[-1]))


def _expand(paths):
    return [file for path in map(Path, paths)
            for file in (sorted(path.glob('*.mcap')) if path.is_dir() else [path])]


# --- figures ------------------------------------------------------------------------------

@dataclasses.dataclass
class ReportFigure:
    """
    A figure and the data plotted on it (for checks and for the summary).

    Attributes
    ----------
    name : str
        File stem, e.g. ``'forward_gain'``.
    figure : matplotlib.figure.Figure
    data : dict
        The plotted numbers, by line label.
    """

    name: str
    figure: object
    data: dict


def _labels(runs):
    """Return a legend label per run, with the file stem where names repeat."""
    names = [run.name for run in runs]
    return [f'{run.name} ({run.source.stem})' if names.count(run.name) > 1 else run.name
            for run in runs]


def _pick_runs(runs, columns):
    """Split runs with a table having ``columns`` into (reference, [(run, table)])."""
    usable = [(run, run.table_with(*columns)) for run in runs]
    usable = [(run, table) for run, table in usable if table is not None]
    references = [(run, table) for run, table in usable if run.captured]
    estimates = [(run, table) for run, table in usable if not run.captured]
    reference = references[-1] if references else None
    if estimates and references:
        # The reference an estimation compares with is the last one captured before it.
        earlier = [item for item in references if item[0].start_ns <= estimates[0][0].start_ns]
        reference = (earlier or references)[-1]
    return reference, estimates


def _kind_value(run, kind, field, axis):
    value = run.result.get(f'{kind}.{field}.{axis}', run.value(f'{field}.{axis}'))
    return float(value) if isinstance(value, (int, float)) else None


def _run_color(index, is_reference, reference):
    if is_reference:
        return REFERENCE_COLOR
    # Estimation runs count from 0 whether or not a reference precedes them.
    return RUN_COLORS[(index - (reference is not None)) % len(RUN_COLORS)]


def _label(plot, title=None, xlabel=None, ylabel=None, **legend):
    """Title, label, legend (``legend`` its keywords) and grid one panel."""
    plot.set(**{key: text for key, text in (('title', title), ('xlabel', xlabel),
                                             ('ylabel', ylabel)) if text is not None})
    plot.legend(**{'fontsize': 8, **legend})
    plot.grid(alpha=0.3)


def _finish(name, figure, data, title):
    """Title and lay out ``figure``; return it as the :class:`ReportFigure` ``name``."""
    figure.suptitle(title)
    figure.tight_layout()
    return ReportFigure(name, figure, data)


def forward_figure(runs):
    """Plot the forward sweeps (Ran et al. 2019, Fig. 11); return a ReportFigure or None."""
    reference, estimates = _pick_runs(runs, ('delta_n', 'mean_x'))
    plotted = ([reference] if reference else []) + estimates
    if not plotted:
        return None
    labels = _labels([run for run, _ in plotted])
    figure, axes = plt.subplots(2, len(AXES), figsize=(15, 8), sharex=True,
                                gridspec_kw={'height_ratios': [3, 2]})
    data = {}
    for column, axis in enumerate(AXES):
        top, bottom = axes[0, column], axes[1, column]
        reference_fit = None
        if reference:
            table = reference[1]
            reference_fit = np.polyfit(table['delta_n'], table[f'mean_{axis}'], 1)
        for index, ((run, table), label) in enumerate(zip(plotted, labels)):
            delta_n, n_out = table['delta_n'], table[f'mean_{axis}']
            order = np.argsort(delta_n, kind='stable')
            slope, intercept = np.polyfit(delta_n, n_out, 1)
            is_reference = reference is not None and run is reference[0]
            color = _run_color(index, is_reference, reference)
            legend = f'{label}: slope {slope:.6f}'
            estimate = None if is_reference else _kind_value(run, 'forward', 'estimate_ppm',
                                                             axis)
            if estimate is not None:
                error = _kind_value(run, 'forward', 'std_error_ppm', axis)
                legend += f', est. {estimate:+.1f}' + (f' ± {error:.2g}' if error else '') + \
                    ' ppm'
            top.plot(delta_n[order], n_out[order], 'o-', color=color, markersize=4,
                     label=legend)
            entry = {'delta_n': delta_n, 'n_out': n_out, 'slope': slope,
                     'intercept': intercept, 'estimate_ppm': estimate}
            if reference_fit is not None:
                deviation = n_out - np.polyval(reference_fit, delta_n)
                entry['deviation'] = deviation
                entry['slope_change_ppm'] = (slope / reference_fit[0] - 1.0) * 1e6
                bottom.plot(delta_n[order], deviation[order], 'o-', color=color, markersize=4,
                            label=f'{label}: slope {entry["slope_change_ppm"]:+.1f} ppm '
                                  'vs reference')
            data.setdefault(label, {})[axis] = entry
        _label(top, f'{axis} axis', None, 'N_out [count]', loc='upper left')
        _label(bottom, None, 'dN_FPGA [count]', 'N_out - reference line [count]')
        if reference_fit is None:
            bottom.set_visible(False)
    return _finish('forward_gain', figure, data, 'Forward gain: open-loop sweep N_out vs '
                   'dN_FPGA, reference vs drifted (Ran et al. 2019, Fig. 11)')


def feedback_figure(runs):
    """Plot the I_ref on/off segments (Ran et al. 2019, Fig. 12); return a ReportFigure or None."""
    reference, estimates = _pick_runs(runs, ('reference_on', 'mean_x'))
    plotted = ([reference] if reference else []) + estimates
    if not plotted:
        return None
    labels = _labels([run for run, _ in plotted])
    figure, axes = plt.subplots(2, len(AXES), figsize=(15, 8),
                                gridspec_kw={'height_ratios': [3, 2]})
    data = {}
    for column, axis in enumerate(AXES):
        top, bottom = axes[0, column], axes[1, column]
        steps = []
        for index, ((run, table), label) in enumerate(zip(plotted, labels)):
            on = table['reference_on'] > 0.5
            means, stds = table[f'mean_{axis}'], table.get(f'std_{axis}')
            is_reference = reference is not None and run is reference[0]
            color = _run_color(index, is_reference, reference)
            segment = np.arange(len(means)) if 'segment' not in table else table['segment']
            # A binary regressor's least-squares step is the difference of the group means.
            step = means[on].mean() - means[~on].mean() if on.any() and (~on).any() \
                else float('nan')
            # Relative to each run's own I_ref-off level, so that the runs share one scale
            # although their zero outputs differ.
            relative = means - (means[~on].mean() if (~on).any() else 0.0)
            top.step(segment, relative, where='mid', color=color,
                     linewidth=3.0 if is_reference else 1.2, alpha=0.5 if is_reference else 1)
            top.errorbar(segment[~on], relative[~on], yerr=None if stds is None else stds[~on],
                         fmt='o', color=color, mfc='white', label=f'{label}: I_ref off')
            top.errorbar(segment[on], relative[on], yerr=None if stds is None else stds[on],
                         fmt='s', color=color, label=f'{label}: I_ref on, step {step:.2f}')
            steps.append((label, step, color, run, is_reference))
            data.setdefault(label, {})[axis] = {'segment': segment, 'reference_on': on,
                                                'means': means, 'step': step}
        reference_step = next((s for _, s, _, _, is_ref in steps if is_ref), None)
        if reference_step is not None:
            for position, (label, step, color, run, is_ref) in enumerate(steps):
                change = (step / reference_step - 1.0) * 1e6
                bottom.bar(position, change, color=color)
                estimate = None if is_ref else _kind_value(run, 'feedback', 'estimate_ppm',
                                                           axis)
                text = f'{change:+.1f} ppm' + ('' if estimate is None
                                               else f'\n(est. dk_fb {estimate:+.1f} ppm)')
                bottom.annotate(text, (position, change), ha='center', fontsize=8,
                                va='bottom' if change >= 0 else 'top')
                data[label][axis]['step_change_ppm'] = change
                data[label][axis]['estimate_ppm'] = estimate
            bottom.set_xticks(range(len(steps)), [label for label, *_ in steps])
            bottom.axhline(0.0, color='black', linewidth=0.8)
            bottom.margins(y=0.35)
        else:
            bottom.set_visible(False)
        top.xaxis.get_major_locator().set_params(integer=True)
        _label(top, f'{axis} axis', 'segment', 'segment mean N_out - I_ref-off mean [count]',
               fontsize=7, loc='center left')
        bottom.set_ylabel('step N_on - N_off vs reference [ppm]')
        bottom.grid(alpha=0.3, axis='y')
    return _finish('feedback_gain', figure, data, 'Feedback gain: output with the reference '
                   'current I_ref off/on, reference vs drifted (Ran et al. 2019, Fig. 12)')


def static_output_figure(contents, axis='z'):
    """Plot the static IMU output through the scenario phases (Ran et al. 2019, Fig. 13)."""
    with_imu = [c for c in contents if len(c.imu_time_ns)]
    if not with_imu:
        return None
    bag = with_imu[0]
    column = AXES.index(axis)
    times, values = bag.imu_time_ns, bag.imu_accel[:, column]
    phases = bag.phases or [(int(times[0]), 'all')]
    bounds = [start for start, _ in phases[1:]] + [max(int(times[-1]) + 1, phases[-1][0])]
    segments = [(name, start, end, (times >= start) & (times < end))
                for (start, name), end in zip(phases, bounds)]
    baseline_name = 'reference' if any(name == 'reference' and inside.any()
                                       for name, _, _, inside in segments) else None
    baseline = next((values[inside].mean() for name, _, _, inside in segments
                     if inside.any() and (baseline_name is None or name == baseline_name)))
    origin = phases[0][0]
    figure, plot = plt.subplots(figsize=(12, 5.5))
    data = {'baseline_m_s2': float(baseline), 'phases': {}}
    for name, start, end, inside in segments:
        color = PHASE_COLORS.get(name, 'tab:gray')
        if not inside.any():
            plot.axvspan((start - origin) * 1e-9, (end - origin) * 1e-9, color=color,
                         alpha=0.12, label=f'{name} (no output)')
            continue
        seconds = (times[inside] - origin) * 1e-9
        error_ug = (values[inside] - baseline) / MICRO_G
        mean_ug = float(error_ug.mean())
        plot.plot(seconds, error_ug, color=color, linewidth=0.4, alpha=0.35, rasterized=True)
        plot.hlines(mean_ug, seconds[0], seconds[-1], color=color, linewidth=2.5,
                    label=f'{name}: mean {mean_ug:+.1f} µg '
                          f'({values[inside].mean():.7f} m/s²)')
        data['phases'][name] = {'mean_m_s2': float(values[inside].mean()),
                                'error_ug': mean_ug, 'samples': int(inside.sum())}
    _label(plot, f'Static output, {axis} axis: '
           f'{" / ".join(name for name, *_ in segments)} (Ran et al. 2019, Fig. 13)', 'time [s]',
           f'{axis} output - {baseline_name or "first phase"} mean [µg]', loc='best')
    figure.tight_layout()
    return ReportFigure('static_output', figure, data)


def _double_exponential(run, axis):
    names = ('alpha1', 'alpha2', 'beta1', 'beta2')
    coefficients = [run.value(f'fit.{axis}.{name}') for name in names]
    if all(isinstance(c, (int, float)) for c in coefficients):
        fit = dict(zip(names, map(float, coefficients)))
        # the linear baseline of a multi-position calibration (0 for Liu, Li and Shen's model)
        fit['offset'] = float(run.value(f'fit.{axis}.offset') or 0.0)
        fit['slope'] = float(run.value(f'fit.{axis}.slope') or 0.0)
        return fit
    return None


def _temperature_panels(runs, *stems):
    """
    Return the last temperature calibration's panels: ``(run, table, order, figure, panels)``.

    ``table`` is the binned curve (not the raw 1 s blocks of the cycle: no ``bias_``
    columns), ``order`` sorts it by V_temp, ``panels`` pairs a plot with each axis that
    has every ``STEM_axis`` column; None without such a run or axis.
    """
    found = [(run, run.table_with('v_temp', 'bias_x')) for run in runs]
    found = [(run, table) for run, table in found if table is not None]
    if not found:
        return None
    run, table = found[-1]
    present = [axis for axis in AXES if all(f'{stem}_{axis}' in table for stem in stems)]
    if not present:
        return None
    figure, axes = plt.subplots(1, len(present), figsize=(5 * len(present), 4.5),
                                squeeze=False)
    return run, table, np.argsort(table['v_temp']), figure, zip(axes[0], present)


def temperature_fit_figure(runs):
    """Plot zero bias vs V_temp with the double-exponential fit (Liu, Li and Shen, Fig. 3)."""
    panels = _temperature_panels(runs, 'bias')
    if panels is None:
        return None
    run, table, order, figure, panels = panels
    v_temp = table['v_temp'][order]
    data = {}
    for plot, axis in panels:
        bias_ug = table[f'bias_{axis}'][order] / MICRO_G
        plot.plot(v_temp, bias_ug, '.', color='tab:blue', label='binned zero bias')
        entry = {'v_temp': v_temp, 'bias_ug': bias_ug}
        fit = _double_exponential(run, axis)
        if fit is not None:
            grid = np.linspace(v_temp[0], v_temp[-1], 400)
            model = (fit['alpha1'] * np.exp(fit['beta1'] * grid)
                     + fit['alpha2'] * np.exp(fit['beta2'] * grid)
                     + fit['offset'] + fit['slope'] * grid)
            rmse = run.value(f'fit.{axis}.rmse')
            r_squared = run.value(f'fit.{axis}.r_squared')
            detail = '' if rmse is None else f'\nRMSE {rmse / MICRO_G:.2f} µg'
            detail += '' if r_squared is None else f', R² {r_squared:.5f}'
            plot.plot(grid, model / MICRO_G, '-', color='tab:red',
                      label='α1·exp(β1·V) + α2·exp(β2·V)' + detail)
            entry.update(fit=fit, fit_v=grid, fit_ug=model / MICRO_G)
        _label(plot, f'{axis} axis', 'V_temp [V]', 'zero bias [µg]')
        data[axis] = entry
    return _finish('temperature_fit', figure, data, 'Zero bias vs temperature-sensor voltage '
                   f'and double-exponential fit ({run.name}, Liu, Li and Shen, Fig. 3)')


def temperature_compensation_figure(runs):
    """Plot the zero bias before and after compensation (Liu, Li and Shen, Fig. 4)."""
    panels = _temperature_panels(runs, 'bias', 'compensated')
    if panels is None:
        return None
    run, table, order, figure, panels = panels
    v_temp = table['v_temp'][order]
    data = {}
    for plot, axis in panels:
        before = table[f'bias_{axis}'][order] / MICRO_G
        after = table[f'compensated_{axis}'][order] / MICRO_G
        p2p_before = run.value(f'p2p_before_ug.{axis}', float(np.ptp(before)))
        p2p_after = run.value(f'p2p_after_ug.{axis}', float(np.ptp(after)))
        plot.plot(v_temp, before - before.mean(), '.-', color='tab:red', markersize=3,
                  label=f'before (p2p {p2p_before:.1f} µg)')
        plot.plot(v_temp, after - after.mean(), '.-', color='tab:green', markersize=3,
                  label=f'after (p2p {p2p_after:.1f} µg)')
        _label(plot, f'{axis} axis', 'V_temp [V]', 'zero output - its mean [µg]')
        data[axis] = {'v_temp': v_temp, 'before_ug': before, 'after_ug': after,
                      'p2p_before_ug': p2p_before, 'p2p_after_ug': p2p_after}
    return _finish('temperature_compensation', figure, data, 'Zero drift over the temperature '
                   'cycle before and after the fixed-point double-exponential compensation '
                   f'({run.name}, Liu, Li and Shen, Fig. 4)')


def build_figures(paths):
    """
    Load ``paths`` (files or directories of ``.mcap``) and return every figure they allow.

    Returns
    -------
    list of ReportFigure
        Open matplotlib figures; close them (``plt.close(f.figure)``) when done.
    """
    contents = [load_bag(path) for path in _expand(paths)]
    runs = sorted((run for bag in contents for run in bag.runs), key=lambda run: run.start_ns)
    figures = [forward_figure(runs), feedback_figure(runs), static_output_figure(contents),
               temperature_fit_figure(runs), temperature_compensation_figure(runs)]
    return [figure for figure in figures if figure is not None]


def report(paths, out_dir):
    """
    Write the PNG figures for ``paths`` into ``out_dir``.

    Parameters
    ----------
    paths : str, os.PathLike or list of them
        MCAP files (trace files, scenario bags) or directories of them.
    out_dir : str or os.PathLike
        Created if missing, once there is a figure to write.

    Returns
    -------
    list of pathlib.Path
        The PNG files written, in figure order.
    """
    if isinstance(paths, (str, Path)):
        paths = [paths]
    out_dir = Path(out_dir)
    # Created once there is something to write: a refused input leaves nothing behind.
    figures = build_figures(paths)
    written = []
    try:
        if figures:
            out_dir.mkdir(parents=True, exist_ok=True)
        for item in figures:
            target = out_dir / f'{item.name}.png'
            item.figure.savefig(target, dpi=DPI)
            written.append(target)
    finally:
        for item in figures:
            plt.close(item.figure)
    return written
