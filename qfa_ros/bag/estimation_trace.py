"""Write estimation results as self-describing trace MCAP files (no ROS needed)."""

from pathlib import Path

import numpy as np

from qfa_ros.bag.trace_writer import TraceWriter
from qfa_ros.model.triad import AXES


def trace_path(directory, kind, time_ns):
    """Return the trace file name for a ``kind`` schedule ending at ``time_ns`` [ns]."""
    return Path(directory) / f'qfa_{kind}_{int(time_ns):019d}.mcap'


def write_estimation_trace(path, kind, results, *, source='qfa_ros', context=None):
    """
    Write one trace file for a schedule run and return its final path.

    Topics (all under ``/qfa/trace``): ``settings`` (the settings of every result plus
    ``context``), ``<result kind>/points`` (every raw point, logged at its sensor
    time), ``<result kind>/residuals`` (fit residuals per axis), ``<result kind>/blocks``
    (a temperature calibration's raw cycle: V_temp, temperature and zero output per
    averaging block), ``result`` (estimate,
    standard error, measured and reference gain, words before and after, summary).
    The file appears under its final name only once complete (``.part`` until then);
    an ``OSError`` leaves no file under that name.
    """
    with TraceWriter(path, source=source) as trace:
        write_results(trace, kind, results, context)
        return trace.finish()


def write_results(trace, kind, results, context=None):
    """Write the settings, points, residuals and result of ``results`` to ``trace``."""
    results = list(results)
    if not results:
        raise ValueError('results must not be empty')
    settings = {'kind': kind, **{r.kind: r.settings for r in results}, **(context or {})}
    trace.write_settings(settings, results[0].start_ns)
    for r in results:
        times = np.asarray(r.points['time_ns'], dtype=np.int64)
        columns = {k: v for k, v in r.points.items() if k != 'time_ns'}
        trace.write_table(f'{r.kind}/points', columns, times)
        residuals = np.asarray(r.residuals, dtype=float)
        trace.write_table(f'{r.kind}/residuals',
                          {axis: residuals[:, i] for i, axis in enumerate(AXES)}, times)
        blocks = getattr(r, 'blocks', None)
        if blocks:
            # The raw cycle behind the binned points (temperature calibration), so that
            # the fit can be redone from the trace alone.
            zero = np.asarray(blocks['zero'], dtype=float)
            # the fixture's input per block (multi-position calibration), if any
            force = np.asarray(blocks.get('force', np.zeros((0, 3))), dtype=float)
            trace.write_table(f'{r.kind}/blocks', {
                'v_temp': blocks['v_temp'], 'temperature': blocks['temperature'],
                **{f'zero_{axis}': zero[:, i] for i, axis in enumerate(AXES)},
                **{f'force_{axis}': force[:, i] for i, axis in enumerate(AXES) if len(force)}},
                np.asarray(blocks['time_ns'], dtype=np.int64))
    summary = '; '.join(r.summary() for r in results)
    trace.write_result({r.kind: r.to_mapping() for r in results}, results[-1].end_ns,
                       summary=summary)
