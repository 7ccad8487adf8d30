"""The soak's report (``--out``, Markdown) and figure, written from its CSV files alone."""

import json
import os

from crash_helpers import LOSS_BOUND_S
import numpy as np
from soak_csv import column, MIB, NS_PER_S, read_csv

from qfa_ros.ros.pacing import RECORD_PERIOD_S

PAUSE_MARGIN_NS = 500_000_000
"""A gap this close to a schedule call's window counts as the schedule's pause [ns]."""
STARVED_PERIODS = 4
"""A subscriber that reads the sample after a gap this many periods after it was sent was
behind: the four sent after it were waiting in its history of 5 too."""
COUNTERS = ('withheld', 'skipped', 'dropped', 'late')
"""The node's ``/diagnostics`` counters summed over its runs."""


def fit(t_h, y):
    """Return ``(slope per hour, its standard error, intercept)`` of a least-squares line."""
    ok = np.isfinite(t_h) & np.isfinite(y)
    t_h, y = t_h[ok], y[ok]
    if len(t_h) < 3 or np.ptp(t_h) <= 0:
        return np.nan, np.nan, np.nan
    (slope, intercept), cov = np.polyfit(t_h, y, 1, cov=True)
    return slope, float(np.sqrt(cov[0, 0])), intercept


def pause_windows(events):
    """Return the ``(start, end)`` windows of the schedule calls [ns], with the margin."""
    return [(int(e['sent_ns']) - PAUSE_MARGIN_NS, int(e['answered_ns']) + PAUSE_MARGIN_NS)
            for e in events if e['kind'] == 'schedule' and e['answered_ns']]


def classify_gaps(gaps, windows):
    """Split the gaps into those inside one of ``windows`` and the others."""
    inside, outside = [], []
    for gap in gaps:
        before, after = int(gap['before_stamp_ns']), int(gap['after_stamp_ns'])
        paused = any(before >= start and after <= end for start, end in windows)
        (inside if paused else outside).append(gap)
    return inside, outside


def run_totals(node_rows):
    """Return the node's counters summed over its runs (each run's last row)."""
    last = {}
    for row in node_rows:
        last[row['run']] = row
    return {name: int(np.nansum([float(row[name] or 'nan') for row in last.values()]))
            for name in COUNTERS}


def recorded_holes(files, recorded_gaps, period):
    """
    Return the holes in the recorded IMU stamps.

    Those inside each file read (``soak_recorded_gaps.csv``) and those between two
    consecutive files of a bag that were both read (``soak_files.csv``).
    """
    holes = [dict(g) for g in recorded_gaps]
    by_bag = {}
    for f in files:
        if f['first_stamp_ns'] and f['file'].endswith('.mcap'):
            index = int(f['file'].split('.mcap')[0].rsplit('_', 1)[1])
            by_bag.setdefault(f['bag'], {})[index] = f
    for bag in by_bag.values():
        for index in sorted(bag):
            following = bag.get(index + 1)
            if following is None:
                continue
            before = int(bag[index]['last_stamp_ns'])
            after = int(following['first_stamp_ns'])
            if (after - before) // period > 1:
                holes.append({'before_stamp_ns': before, 'after_stamp_ns': after,
                              'missing': (after - before) // period - 1})
    return holes


def write_report(paths):
    """Write the Markdown report and the figure from the soak's CSV files."""
    run = json.loads(paths.run.read_text())
    node_rows = read_csv(paths.node)
    stream_rows = read_csv(paths.stream)
    gaps = read_csv(paths.gaps)
    events = read_csv(paths.events)
    files = read_csv(paths.files)
    restarts = read_csv(paths.restarts)
    period = round(NS_PER_S / run.get('rate_hz', 1000.0))
    t0 = run['started_ns']
    t_h = (column(node_rows, 'wall_ns') - t0) / 3.6e12
    headline = {}  # what the sections found that the figures block states
    lines = header(run, node_rows, t_h)
    lines += stream_section(stream_rows, gaps, events, node_rows,
                            recorded_holes(files, read_csv(paths.recorded_gaps), period),
                            period, t0, headline)
    lines += restart_section(run, restarts, events, gaps, headline)
    lines += resource_section(run, node_rows, t_h, headline)
    lines += disk_section(run, node_rows, t_h, files, restarts, headline)
    lines += readback_section(files, read_csv(paths.bags), stream_rows)
    lines += calls_section(events, node_rows)
    lines += ['', f'![RSS, descriptors, threads and stamp offset against time]'
                  f'({paths.figure.name})', '']
    lines += days_figures(paths, run, node_rows, t_h, headline)
    paths.out.write_text('\n'.join(lines) + '\n')
    figure(paths, run, node_rows, stream_rows, events)


def header(run, node_rows, t_h):
    """Return the title, the command, the machine, the load and the conditions."""
    python = run.get('python', 'python')
    lines = [f'# Soak: the live node for {t_h[-1] if len(t_h) else 0:.2f} h', '',
             'Command (from the work tree):', '', '```sh',
             f'PYTHONPATH=$PWD {python} {run["bench"].split(" ", 1)[1]}', '```', '',
             f'Node (its own process group, domain {run["domain"]}): `python '
             f'{run["node_command"]}`', '',
             f'Code {run["commit"]}; started {run["started"]}; {run["machine"]}; ended: '
             f'{run.get("end_reason", "no end recorded (the bench died)")}, node exit '
             f'status {run.get("node_exit_status", "unknown")}.', '']
    if run.get('tracemalloc'):
        lines += ['**tracemalloc was on** (bench/soak_hook): the slopes below include '
                  'its own bookkeeping; not a measurement of the node.', '']
    if run.get('allocator'):
        lines += ['glibc allocator settings in the environment of the node: '
                  + ', '.join(f'`{k}={v}`' for k, v in run['allocator'].items()) + '.', '']
    load = column(node_rows, 'load1')
    if len(load):
        lines += [f'Load (1-min average, `os.getloadavg`, every row of `soak.csv`): median '
                  f'{np.median(load):.2f}, min {load.min():.2f}, max {load.max():.2f} on '
                  f'{os.cpu_count()} CPUs.', '']
    retention = run.get('retention', {})
    keep = [f'`{retention["keep_s"]}` {run["keep_s"]:g} s'] if run.get('keep_s') else []
    if run.get('keep_bytes'):
        keep.append(f'`{retention["keep_bytes"]}` {run["keep_bytes"] / MIB:.1f} MiB')
    kills = (f"a kill -9 of the node's process group and a restart every "
             f'{run["kill_every_s"]:g} s (±{100 * run["kill_jitter"]:g} %)'
             if run.get('kill_every_s') else 'no kill')
    lines += [f'Recorder split every {run["split_s"]:g} s or '
              f'{run["max_bytes"] / MIB:.1f} MiB (`recorder.max_bytes`), retention '
              f'{", ".join(keep) if keep else "off"}; a parameter change every '
              f'{run["param_every_s"]:g} s (rotating: {", ".join(run["rotation"])}), '
              f'`~/self_calibrate` every {run["calibrate_every_s"]:g} s in fast mode '
              f'(`estimation.realtime: false`) after one `~/capture_reference`; {kills}; '
              f'samples of the node every {run["sample_every_s"]:g} s; fits after a warm-up '
              f'of {run["warmup_s"] / 60:g} min of each run.', '']
    return lines


def stream_section(stream_rows, gaps, events, node_rows, recorded_gaps, period, t0,
                   headline):
    """Return the stream's lines: samples received and lost, the grid, the offset."""
    if not stream_rows:
        return ['## Stream', '', 'No subscriber rows.', '']
    last = stream_rows[-1]
    received, lost = int(last['received']), int(last['lost'])
    pauses = pause_windows(events)
    # A kill's window: from the last sample received of the killed node to the first of the
    # next (the subscriber's ``restart`` gap); every other gap is judged as without kills.
    in_kills = [g for g in gaps if g.get('kind') == 'restart']
    inside, outside = classify_gaps([g for g in gaps if g.get('kind') != 'restart'], pauses)
    # A keep-last-5 reader that took the sample after a hole this long after the node sent
    # it (DDS source timestamp) had the four after it waiting too: it was itself behind.
    behind = [g for g in outside
              if int(g['received_ns']) - int(g.get('published_ns') or g['after_stamp_ns'])
              >= STARVED_PERIODS * period]
    total = run_totals(node_rows)
    span = received + lost

    def missing(rows):
        return f'{sum(int(g["missing"]) for g in rows):,}'

    lines = ['## Stream (SensorDataQoS subscriber, best effort, keep last 5, own process)', '',
             '| | samples |', '|---|---|',
             f'| on the grid from the first to the last received | {span:,} |',
             f'| received | {received:,} |',
             f'| missing overall | {lost:,} ({lost / max(span, 1):.2e}) |',
             f"| missing from a kill to the restarted node's first sample ({len(in_kills)} "
             f'gaps) | {missing(in_kills)} |',
             f'| missing inside schedule pauses ({len(inside)} gaps) | {missing(inside)} |',
             f'| the node says withheld (`samples withheld`, all runs) | {total["withheld"]} |',
             f'| **lost outside pauses and kills** ({len(outside)} gaps) | '
             f'**{missing(outside)}** |',
             f'| of them while the subscriber was itself behind (read the next sample '
             f'≥ {STARVED_PERIODS} periods after the node sent it; {len(behind)} gaps) | '
             f'{missing(behind)} |',
             f'| the node says skipped / dropped > 1 s late / published > 5 ms late (all '
             f'runs) | {total["skipped"]} / {total["dropped"]} / {total["late"]} |',
             f'| stamps off the grid (each run its own grid: {last.get("grids", "1")}) | '
             f'{last["off_grid"]} |',
             f'| out of order or repeated | {last["out_of_order"]} |', '']
    headline.update(lost=sum(int(g['missing']) for g in outside), span=span)
    if recorded_gaps:
        # Each bag is one run: a kill makes no hole in a recording.
        held, missed = classify_gaps(recorded_gaps, pauses)
        lines[-1:-1] = [
            f'| the recording (what the pacer published; the files read) misses inside '
            f'pauses | {missing(held)} |',
            f'| **the recording misses outside pauses and kills** ({len(missed)} gaps) | '
            f'**{missing(missed)}** |']
        lines += ["The recording logs each sample as the node's pacer published it: a sample "
                  'missing at the subscriber but recorded left the node and was lost on the '
                  'way (DDS, or a subscriber starved for more than five sample periods). With '
                  'retention only the files kept until a check read them are compared.', '']
    if outside:
        largest = max(outside, key=lambda g: int(g['missing']))
        lines += [f'Largest loss outside pauses and kills: {largest["missing"]} samples at '
                  f'{(int(largest["before_stamp_ns"]) - t0) / 3.6e12:.3f} h.', '']
    return lines + offset_lines(stream_rows)


def offset_lines(stream_rows):
    """Return the offset of the stamps from the subscriber's clock: first, last, slope."""
    wall = column(stream_rows, 'wall_ns')
    t_h = (wall - wall[0]) / 3.6e12
    p50 = column(stream_rows, 'offset_p50_us')
    low = column(stream_rows, 'offset_min_us')
    slope_p50, error_p50, _ = fit(t_h, p50)
    slope_min, error_min, _ = fit(t_h, low)
    low, p50 = low[np.isfinite(low)], p50[np.isfinite(p50)]
    if not len(low):
        return []
    return ["Offset of the stamps from the subscriber's system clock (receive time - "
            'stamp, per interval; the node stamps on its grid and publishes when the '
            'system clock reaches the stamp, so this is the delivery delay):', '',
            '| per interval | first | last | median | slope [µs/h] |', '|---|---|---|---|---|',
            f'| minimum [µs] | {low[0]:.0f} | {low[-1]:.0f} | {np.nanmedian(low):.0f} | '
            f'{slope_min:+.2f} ± {error_min:.2f} |',
            f'| median [µs] | {p50[0]:.0f} | {p50[-1]:.0f} | {np.nanmedian(p50):.0f} | '
            f'{slope_p50:+.2f} ± {error_p50:.2f} |', '']


def restart_section(run, restarts, events, gaps, headline):
    """Return one line per kill: what it hit, the first sample after, what the kill left."""
    kills = [e for e in events if e['kind'] == 'kill']
    if not kills:
        return []
    firsts = {}
    for gap in (g for g in gaps if g.get('kind') == 'restart'):
        firsts[int(gap['after_stamp_ns'])] = gap
    rows = {int(r['run']): r for r in restarts}
    lines = ['## Kills and restarts', '',
             f'{len(kills)} kills (SIGSTOP at the instant, the recorder directory noted, '
             'SIGKILL to the process group, the same command again). *First sample*: from '
             "the restart to the subscriber's first sample of the new node; *recorded "
             "before the kill*: from the killed run's last recorded sample (after the "
             f'start-up recovery) to the kill, at most {LOSS_BOUND_S:g} s (docs/node.md, '
             '*Crash safety*); *files*: finished at the kill / gone since (retention, '
             'oldest first) / in the directory at the check, read now, unreadable; *bags*: '
             "bag directories whose `metadata.yaml` lists exactly their files, each file's "
             'count, and that `AnyReader` opens with it / all.', '',
             '| # | at [h] | mode (hit) | first sample [s] | recovered after [s] | '
             'recorded before the kill [s] | newest kept [min] | files | bags | '
             'listing as the kill left it | problems |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    worst = 0.0
    for number, event in enumerate(kills, 1):
        kill, restarted = int(event['sent_ns']), int(event['answered_ns'])
        first = next((g for stamp, g in sorted(firsts.items()) if stamp >= restarted), None)
        first_s = f'{(int(first["received_ns"]) - restarted) / 1e9:.2f}' if first else '–'
        row = rows.get(number)
        cells = [str(number), f'{(kill - run["started_ns"]) / 3.6e12:.2f}',
                 f'{event["name"]} ({event["success"]})', first_s]
        if row is None:
            lines.append('| ' + ' | '.join(cells + ['not checked'] + [''] * 6) + ' |')
            continue
        before = (kill - int(row['last_stamp_ns'])) / 1e9 if row['last_stamp_ns'] else np.nan
        worst = np.nanmax([worst, before])
        kept = (kill - int(row['kept_from_ns'])) / 6e10 if row['kept_from_ns'] else np.nan
        good = int(row['bags']) - int(row['bags_untrue'])
        cells += [f'{(int(row["recovered_ns"]) - restarted) / 1e9:.1f}',
                  f'{before:.2f}' if before <= LOSS_BOUND_S else f'**{before:.2f}**',
                  f'{kept:.1f}',
                  f'{row["finished_at_kill"]} / {row["finished_missing"]} / '
                  f'{row["files_present"]}, {row["files_read"]}, {row["files_unreadable"]}',
                  f'{good} / {row["bags"]}', row['listing_as_left'], row['problem'] or '–']
        lines.append('| ' + ' | '.join(cells) + ' |')
    warned = sum(r['warn_line'] == '1' for r in restarts)
    headline['restarts'] = (sum(
        r['files_unreadable'] == '0' and r['bags_untrue'] == '0' and not r['problem']
        and r['last_stamp_ns'] and (int(kills[int(r['run']) - 1]['sent_ns'])
                                    - int(r['last_stamp_ns'])) / 1e9 <= LOSS_BOUND_S
        for r in restarts), len(kills))
    lines += ['', f'The recording ended at most {worst:.2f} s before a kill; the start-up '
              f'recovery said so in a WARN line after {warned} of {len(restarts)} restarts.',
              '']
    return lines


def resource_section(run, node_rows, t_h, headline):
    """RSS, descriptors and threads: per run after its warm-up, and across the runs."""
    if len(t_h) < 3:
        return ['## Node process', '', 'Too few rows.', '']
    runs = column(node_rows, 'run')
    measures = (('rss_kib', 'RSS [MiB]', 1024.0), ('rss_anon_kib', 'RSS anonymous [MiB]',
                1024.0), ('fds', 'open descriptors', 1.0), ('threads', 'threads', 1.0))
    lines = ['## Node process (`/proc/<pid>`)', '']
    ages = run_ages(runs, t_h)
    warm_h = run['warmup_s'] / 3600.0
    if run.get('kill_every_s'):
        warm_h = min(warm_h, run['kill_every_s'] / 7200.0)
    after = ages >= warm_h
    lines += [f'Each run after {60 * warm_h:.0f} min of its own (its warm-up): at its start '
              'and end, the slope within runs (each run its own intercept), and the slope '
              "of the runs' medians against the time they ran (across runs).", '',
              '| | first run, after warm-up | last run, at the end | within runs [/h] | '
              'across runs [/h] | projected at 24 h |', '|---|---|---|---|---|---|']
    for name, label, scale in measures:
        y = column(node_rows, name) / scale
        within, error = within_slope(t_h[after], y[after], runs[after])
        medians = [(np.median(t_h[after & (runs == r)]), np.median(y[after & (runs == r)]))
                   for r in np.unique(runs[after])]
        across, across_error, intercept = fit(*(np.array(v) for v in zip(*medians))) \
            if len(medians) >= 3 else (np.nan, np.nan, np.nan)
        first = y[after & (runs == runs[after][0])] if after.any() else [np.nan]
        slope = across if np.isfinite(across) else within
        base = intercept if np.isfinite(across) else np.nan
        headline[name] = (first[0], y[-1])
        lines.append(f'| {label} | {first[0]:.2f} | {y[-1]:.2f} | {within:+.3f} ± '
                     f'{error:.3f} | {across:+.3f} ± {across_error:.3f} | '
                     f'{base + slope * 24.0:.2f} |')
    cpu = column(node_rows, 'cpu_s')
    wall = column(node_rows, 'wall_ns') / 1e9
    steps = np.diff(cpu)[np.diff(runs) == 0]
    share = steps.sum() / np.diff(wall)[np.diff(runs) == 0].sum() if len(steps) else np.nan
    lines += ['', f'CPU of the node: {100 * share:.1f} % of one core; {len(np.unique(runs))} '
              'runs.', '']
    return lines


def run_ages(runs, t_h):
    """Return each row's time since its run's first row [h]."""
    ages = np.empty_like(t_h)
    for r in np.unique(runs):
        mask = runs == r
        ages[mask] = t_h[mask] - t_h[mask].min()
    return ages


def within_slope(t_h, y, runs):
    """Return the common slope of ``y`` over ``t_h`` [/h] with one intercept per run."""
    ok = np.isfinite(t_h) & np.isfinite(y)
    t_h, y, runs = t_h[ok], y[ok], runs[ok]
    if len(t_h) < 3:
        return np.nan, np.nan
    levels = np.unique(runs)
    design = np.column_stack([t_h] + [(runs == r).astype(float) for r in levels])
    coef, residual, rank, _ = np.linalg.lstsq(design, y, rcond=None)
    dof = len(y) - rank
    if dof <= 0 or rank < design.shape[1]:
        return coef[0], np.nan
    sigma2 = float(np.sum((y - design @ coef) ** 2)) / dof
    return coef[0], float(np.sqrt(sigma2 * np.linalg.pinv(design.T @ design)[0, 0]))


def over_words(values, bound):
    """
    Say how many samples were over a bound, and whether the next sample was within.

    A retention pass runs on its own thread of low priority after a file finishes, so a
    sample taken between the two may be over until the pass; one still over at the next
    sample is not.
    """
    counted = np.isfinite(values)
    over = np.where(counted, values, -np.inf) > bound
    lasting = int(np.sum(over[:-1] & over[1:]))
    if not over.any():
        return f'within (0 of {int(counted.sum())} samples over)'
    return (f'{"within after each pass" if not lasting else "**over**"} ({int(over.sum())} '
            f'of {int(counted.sum())} samples over before the pass after a split, '
            f'{lasting} over at the next sample too)')


def kept_recording(node_rows, restarts, files):
    """
    Return the recording time kept at each sample [s] and the longest file read [s].

    From the oldest finished file's start to the newest's end (``metadata.yaml``), less
    each kill's downtime inside (the killed run's last recorded sample to the restarted
    node's first): the time retention counts (``docs/node.md``, *Retention*). A sample
    whose oldest file listed is empty (a part recovered with no message, its start 0) is
    NaN.
    """
    oldest = column(node_rows, 'oldest_start_ns')
    newest = column(node_rows, 'newest_end_ns')
    oldest[oldest <= 0] = np.nan
    span = (newest - oldest) / NS_PER_S
    for row in restarts:
        if row['last_stamp_ns'] and row['first_published_ns']:
            down_from, down_to = int(row['last_stamp_ns']), int(row['first_published_ns'])
            inside = (oldest <= down_from) & (newest >= down_to)
            span[inside] -= (down_to - down_from) / NS_PER_S
    longest = max((int(f['last_stamp_ns']) - int(f['first_stamp_ns'])
                   for f in files if f['first_stamp_ns'] and f['last_stamp_ns']), default=0)
    return span, longest / NS_PER_S


def disk_section(run, node_rows, t_h, files, restarts, headline):
    """Disk: the recorder directory against its limits, traces, the state file."""
    if not node_rows:
        return []
    last = node_rows[-1]
    whole = column(node_rows, 'recorder_bytes')
    largest = np.nanmax(column(node_rows, 'largest_file_bytes'))
    sizes = [int(f['bytes']) for f in files if f['file'].endswith('.mcap')]
    by_size = sum(s > 0.9 * run['max_bytes'] for s in sizes)
    lines = ['## Disk and state file', '',
             f'- Recorder directory (finished files, `.part`, `metadata.yaml`): at most '
             f'{np.nanmax(whole) / MIB:.1f} MiB, {int(last["recorder_bytes"]) / MIB:.1f} MiB '
             f'at the end in {last["bags"]} bag(s); the largest file '
             f'{largest / MIB:.2f} MiB against `recorder.max_bytes` '
             f'{run["max_bytes"] / MIB:.2f} MiB '
             f'({"within" if largest <= run["max_bytes"] else "**over**"}); {by_size} of '
             f'{len(sizes)} files read ended within 10 % of the size limit.']
    if run.get('keep_bytes'):
        bound = run['keep_bytes'] + largest
        headline['disk'] = (np.nanmax(whole) / MIB, bound / MIB)
        lines.append(f'- Against `{run["retention"]["keep_bytes"]}` plus one split (the '
                     f'largest file; {bound / MIB:.1f} MiB): {over_words(whole, bound)}.')
    if run.get('keep_s'):
        span, longest = kept_recording(node_rows, restarts, files)
        bound = run['keep_s'] + max(longest, run['split_s'] + RECORD_PERIOD_S)
        empty = int(np.sum(np.isnan(span) & np.isfinite(column(node_rows, 'newest_end_ns'))))
        lines.append(f"- Recording kept (the oldest finished file's start to the newest's "
                     "end, less the time from a kill to the restarted node's first sample: "
                     f'the time retention counts): at most {np.nanmax(span):.2f} s against '
                     f'`{run["retention"]["keep_s"]}` plus one file ({bound:.2f} s; a file '
                     f'ends at the first flush, every {RECORD_PERIOD_S} s, after '
                     f'`recorder.max_duration_s`; the longest read {longest:.2f} s): '
                     f'{over_words(span, bound)}' + (
                         f'; {empty} samples while the oldest file listed was an empty one '
                         'recovered from a kill (its start 0) not counted' if empty else '')
                     + '.')
    recorded = column(node_rows, 'recorded_bytes') / MIB
    slope, _, _ = fit(t_h, recorded)
    if not run.get('keep_s') and not run.get('keep_bytes'):
        lines.append(f'- Without retention the recording grew {slope:.1f} MiB/h '
                     f'({24 * slope / 1024:.2f} GiB a day).')
    state = column(node_rows, 'state_bytes')
    readable = column(node_rows, 'state_readable')
    written = len({r['state_mtime_ns'] for r in node_rows if r['state_mtime_ns'] != '0'})
    present = state > 0
    lines += [f'- Traces: {last["trace_files"]} files, '
              f'{int(last["trace_bytes"]) / MIB:.1f} MiB (one per schedule call).',
              f'- State file: written {written} times (distinct modification times seen), '
              f'readable JSON in {int(np.nansum(readable[present]))} of {int(present.sum())} '
              f'samples since it was first written, size '
              f'{np.min(state[present]) if present.any() else 0:.0f}…'
              f'{np.max(state[present]) if present.any() else 0:.0f} bytes.', '']
    return lines


def readback_section(files, bags, stream_rows):
    """Every recorded file read back once by rosbags and the mcap reader; every bag checked."""
    if not files:
        return ['## Read back', '', 'Nothing read back (the bench ended before; '
                "`--report --readback` reads what the run's recording holds).", '']
    agree = sum(f['readable'] == '1' and f['metadata_messages'] == f['summary_messages']
                for f in files)
    bad = [f for f in files if f['readable'] == '0']
    gone = sum(f['readable'] == '' for f in files)
    imu = sum(int(f['imu_messages'] or 0) for f in files)
    at_end = [b for b in bags if b['check'] == 'end']
    lines = ['## Read back', '',
             f'{len(files)} files read (each once, after the restart that found it or at the '
             f'end): {len(files) - len(bad) - gone} by both readers with the count their '
             f'summary states ({agree} also as `metadata.yaml` listed it), {len(bad)} '
             f'unreadable, {gone} deleted while read (retention); '
             f'{sum(int(f["mcap_messages"] or 0) for f in files):,} messages, '
             f'`imu/data_raw` {imu:,}.',
             f'Bag directories checked {len(bags)} times: {sum(b["true"] == "1" for b in bags)}'
             f' true to their files; at the end {sum(b["true"] == "1" for b in at_end)} of '
             f'{len(at_end)}.']
    if stream_rows:
        lines[-1] += f' The subscriber received {int(stream_rows[-1]["received"]):,} samples.'
    for f in bad[:5]:
        lines.append(f'- not readable: {f["bag"]}/{f["file"]}: {f["problem"]}')
    for b in [b for b in bags if b['true'] != '1'][:5]:
        lines.append(f'- bag {b["bag"]} (check {b["check"]}): {b["problem"]}')
    return lines + ['']


def days_figures(paths, run, node_rows, t_h, headline):
    """
    Return the ``figures`` block of a days run (kills and retention; ``docs/figures.md``).

    The ids carry the report's name (``soak_days``, ``soak_days_jazzy``): one per
    distribution.
    """
    if not (run.get('kill_every_s') and run.get('keep_s')) or 'restarts' not in headline:
        return []
    stem, distro = paths.out.stem, ('Jazzy' if 'jazzy' in paths.out.stem else 'Kilted')
    days = (f'Days simulated on {distro} ({t_h[-1]:.1f} h; a kill -9 every '
            f'{run["kill_every_s"] / 60:g} min, retention {run["keep_s"] / 60:g} min, a file '
            f'every {run["split_s"]:g} s, a parameter change every {run["param_every_s"]:g} '
            f's, `~/self_calibrate` every {run["calibrate_every_s"] / 60:g} min)')
    command = f'.venv/bin/python {run["bench"].split(" ", 1)[1].split(" --workdir")[0]}'
    if distro == 'Jazzy':
        command = command.replace('.venv/', '.venv-jazzy/')
    clean, kills = headline['restarts']
    rss_first, rss_last = headline['rss_kib']
    disk, bound = headline.get('disk', (np.nan, np.nan))
    load = np.median(column(node_rows, 'load1'))
    common = [f'  command: {command}',
              f'  machine: {run["machine"].split(", Linux")[0]} (load median {load:.1f})',
              f'  date: {run["started"][:10]}']
    return ['```figures',
            f'- id: {stem}_restarts', '  group: Recording',
            f'  what: "{days}: restarts after which every recording left read in full (mcap, '
            'rosbags), each bag true to its files, at most 1 s lost before the kill"',
            f"  value: '{clean}'", f'  unit: of {kills}',
            f'  note: recorder directory at most {disk:.1f} MiB against `recorder.keep_bytes` '
            f'plus one file ({bound:.1f} MiB)', *common,
            f'- id: {stem}_lost', '  group: The node over DDS',
            f'  what: "{days}: `imu/data_raw` samples a SensorDataQoS subscriber (depth 5) '
            'lost outside schedules and kills"',
            f"  value: '{headline['lost']:,}'", f"  unit: of {headline['span']:,}",
            f'  note: node RSS {rss_first:.0f} MiB after the first warm-up, {rss_last:.0f} MiB '
            'at the end', *common, '```', '']


def calls_section(events, node_rows):
    """Schedule calls and parameter changes: how many, refused, how long."""
    calls = [e for e in events if e['kind'] == 'schedule']
    refusals = [e for e in events if e['kind'] == 'parameter']
    lines = ['## Calls', '',
             f'{len(calls)} schedule calls ({sum(e["success"] == "1" for e in calls)} '
             f'succeeded), {node_rows[-1]["parameter_changes"] if node_rows else 0} '
             f'parameter changes ({len(refusals)} refused).']
    durations = [(int(e['answered_ns']) - int(e['sent_ns'])) / 1e9 for e in calls]
    if durations:
        lines[-1] += (f' A call took {np.median(durations):.2f} s (median), '
                      f'{max(durations):.2f} s at most (request to answer).')
    for event in ([e for e in calls if e['success'] != '1'] + refusals)[:5]:
        lines.append(f'- {event["name"]}: {event["message"]}')
    return lines


def figure(paths, run, node_rows, stream_rows, events):
    """RSS, descriptors, threads, the stamp offset and the load against time; kills marked."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t0 = run['started_ns']
    fig, axes = plt.subplots(5, 1, figsize=(9, 12), sharex=True)
    t_h = (column(node_rows, 'wall_ns') - t0) / 3.6e12
    runs = column(node_rows, 'run')
    for r in np.unique(runs):
        mask = runs == r
        first = r == runs[0]
        axes[0].plot(t_h[mask], column(node_rows, 'rss_kib')[mask] / 1024, 'C0',
                     label='RSS' if first else None)
        axes[0].plot(t_h[mask], column(node_rows, 'rss_anon_kib')[mask] / 1024, 'C1',
                     label='RSS anonymous' if first else None)
        axes[1].plot(t_h[mask], column(node_rows, 'fds')[mask], 'C0',
                     label='open descriptors' if first else None)
        axes[1].plot(t_h[mask], column(node_rows, 'threads')[mask], 'C1',
                     label='threads' if first else None)
    axes[0].set_ylabel('MiB')
    axes[0].legend(loc='lower right')
    axes[1].set_ylabel('count')
    axes[1].legend(loc='center right')
    if stream_rows:
        ts = (column(stream_rows, 'wall_ns') - t0) / 3.6e12
        axes[2].plot(ts, column(stream_rows, 'offset_min_us') / 1e3, label='minimum')
        axes[2].plot(ts, column(stream_rows, 'offset_p50_us') / 1e3, label='median')
        axes[2].plot(ts, column(stream_rows, 'offset_p99_us') / 1e3, label='99th percentile')
        axes[2].set_yscale('log')
        axes[2].set_ylabel('receive - stamp [ms]')
        axes[2].legend(loc='upper right')
    axes[3].plot(t_h, column(node_rows, 'recorder_bytes') / MIB, label='recorder directory')
    axes[3].set_ylabel('MiB')
    axes[3].legend(loc='upper left')
    axes[4].plot(t_h, column(node_rows, 'load1'), label='machine load (1 min)')
    axes[4].set_ylabel('load (1 min)')
    steady = np.diff(runs) == 0
    cpu = axes[4].twinx()
    cpu.plot(t_h[1:][steady], (100 * np.diff(column(node_rows, 'cpu_s')) / np.diff(
        column(node_rows, 'wall_ns') / 1e9))[steady], '.', ms=2, color='tab:orange',
        label='node CPU')
    cpu.set_ylabel('node CPU [% of a core]')
    axes[4].set_xlabel('hours since start')
    axes[4].legend(loc='upper left')
    cpu.legend(loc='upper right')
    for axis in axes:
        for event in (e for e in events if e['kind'] == 'kill'):
            axis.axvline((int(event['sent_ns']) - t0) / 3.6e12, color='red', lw=0.6, ls=':')
        axis.grid(alpha=0.3)
    axes[0].set_title(f'qfa_node soak ({run["commit"]}, {run["started"]}); kills dotted')
    fig.tight_layout()
    fig.savefig(paths.figure, dpi=90)
    plt.close(fig)

