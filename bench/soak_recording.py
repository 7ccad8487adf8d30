"""What the soaked node recorded: disk use, kill instants, and every file read back.

- :func:`disk_sample`: the recorder directory, traces and state file in a few ``stat``
  calls (a ``soak.csv`` row, every ``--sample-every`` s).
- :func:`disk_state`: the recorder directory as a kill left it (the node stopped).
- :func:`check_recordings`: every bag directory's ``metadata.yaml`` against the files it
  holds, and every file not read before read by the ``mcap`` reader and ``rosbags``'
  ``AnyReader`` (``soak_bags.csv``, ``soak_files.csv``); after each restart in a process of
  niceness 19 (``bench/soak.py --check-restart``), and at the end of the soak.
"""

import json
from pathlib import Path
import time

from crash_helpers import bag_directories, entries, split_index
import numpy as np
from soak_csv import (
    BAG_COLUMNS,
    CsvLog,
    FILE_COLUMNS,
    GAP_COLUMNS,
    IMU_TOPIC,
    NS_PER_S,
    read_csv,
    RESTART_COLUMNS,
    STAMP,
)

SETTLE_TRIES = 5
"""Looks at a bag whose listing and files disagree before it counts [number]: a split or a
deletion in progress changes the files and ``metadata.yaml`` one after the other."""
SETTLE_S = 0.2
"""Time between two such looks [s]."""


# --- the directory ---------------------------------------------------------------------------

def listing(bag):
    """Return ``{name: (messages, start, end [ns])}`` of a bag's ``metadata.yaml``, or None."""
    import yaml
    try:
        info = yaml.safe_load((Path(bag) / 'metadata.yaml').read_text())
    except (OSError, ValueError, yaml.YAMLError):
        return None
    files = (info or {}).get('rosbag2_bagfile_information', {}).get('files') or []
    spans = ((int(f['starting_time']['nanoseconds_since_epoch']),
              int(f['duration']['nanoseconds'])) for f in files)
    return {Path(f['path']).name: (int(f['message_count']), start, start + duration)
            for f, (start, duration) in zip(files, spans)}


def disk_sample(output_dir):
    """
    Return what the node wrote under ``output_dir``: recordings, traces, state file.

    Parameters
    ----------
    output_dir : pathlib.Path
        The node's ``output_dir``.

    Returns
    -------
    list
        The ``soak.csv`` cells ``recorded_bytes`` to ``state_mtime_ns``: finished files
        (bytes, count, largest), ``.part`` and ``metadata.yaml`` bytes, the whole recorder
        directory, bags, the start of the oldest finished file and the end of the newest
        [ns] (``metadata.yaml``), traces, the state file.
    """
    recorded = files = part = largest = metadata = 0
    bags = bag_directories(output_dir / 'recordings')
    holding = []  # the bags with finished files
    for bag in bags:
        finished, parts = entries(bag)
        sizes = [s.st_size for s in finished.values()]
        recorded += sum(sizes)
        files += len(sizes)
        largest = max([largest, *sizes])
        part += sum(s.st_size for s in parts.values())
        try:
            metadata += (bag / 'metadata.yaml').stat().st_size
        except FileNotFoundError:
            pass
        if finished:
            holding.append((bag, finished))
    # The oldest start and the newest end are in the oldest and the newest of those bags.
    looked = holding[:1] + holding[-1:] if len(holding) > 1 else holding
    # A file with no message (a part cut right after a split, recovered) is listed with
    # start 0: it covers nothing.
    spans = [(start, end) for bag, finished in looked
             for name, (count, start, end) in (listing(bag) or {}).items()
             if name in finished and count]
    traces = trace_bytes = 0
    for path in (output_dir / 'traces').glob('*.mcap'):
        traces += 1
        trace_bytes += path.stat().st_size
    state = output_dir / 'state.json'
    state_bytes, readable, mtime = 0, 0, 0
    try:
        text = state.read_bytes()
        mtime = state.stat().st_mtime_ns
        state_bytes = len(text)
        json.loads(text)
        readable = 1
    except (OSError, ValueError):
        pass
    return [recorded, files, part, largest, metadata, recorded + part + metadata, len(bags),
            min(spans)[0] if spans else '', max(end for _, end in spans) if spans else '',
            traces, trace_bytes, state_bytes, readable, mtime]


def disk_state(recordings):
    """
    Return the recorder directory as it is (the node stopped: as a kill leaves it).

    Returns
    -------
    dict
        Per bag name: ``finished`` (``{name: [bytes, mtime ns]}``), ``parts``
        (``{name: bytes}``) and ``listed`` (the names ``metadata.yaml`` lists, or None).
    """
    state = {}
    for bag in bag_directories(recordings):
        finished, parts = entries(bag)
        listed = listing(bag)
        state[bag.name] = {
            'finished': {name: [s.st_size, s.st_mtime_ns] for name, s in finished.items()},
            'parts': {name: s.st_size for name, s in parts.items()},
            'listed': None if listed is None else sorted(listed)}
    return state


def stale_listings(state):
    """Return the bags of a :func:`disk_state` whose ``metadata.yaml`` misses or adds a file."""
    return [bag for bag, s in state.items()
            if (s['finished'] or s['listed']) and sorted(s['finished']) != s['listed']]


# --- reading back ----------------------------------------------------------------------

def read_file(path, period_ns):
    """
    Read one finished MCAP file with the ``mcap`` reader (CRCs) and ``rosbags``' ``AnyReader``.

    Parameters
    ----------
    path : pathlib.Path
        The file.
    period_ns : int
        The IMU grid [ns]: holes inside the file are counted on it.

    Returns
    -------
    tuple
        ``(cells, stamps)``: the ``soak_files.csv`` cells from ``summary_messages`` to
        ``problem``, and the IMU stamps [ns] (int64). ``readable`` is 1, 0, or empty when
        the file was deleted while it was read (retention: not a finding).
    """
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    summary = mcap = rosbags = 0
    stamps = []
    try:
        with open(path, 'rb') as stream:
            reader = make_reader(stream, validate_crcs=True)
            summary = reader.get_summary().statistics.message_count
            for _, channel, message in reader.iter_messages():
                mcap += 1
                if channel.topic == IMU_TOPIC:
                    sec, nanosec = STAMP.unpack_from(message.data, 4)
                    stamps.append(sec * NS_PER_S + nanosec)
        with AnyReader([path]) as reader:
            rosbags = sum(1 for _ in reader.messages())
    except Exception as error:  # a file neither reader opens is the finding
        gone = not path.exists()
        return [summary, mcap, rosbags, len(stamps), '', '', '', '' if gone else 0,
                'deleted while read' if gone else f'{type(error).__name__}: {error}'[:200]
                ], np.array(stamps, dtype=np.int64)
    stamps = np.array(stamps, dtype=np.int64)
    steps = np.diff(np.sort(stamps)) // period_ns - 1
    agree = summary == mcap == rosbags
    return [summary, mcap, rosbags, len(stamps), stamps.min() if len(stamps) else '',
            stamps.max() if len(stamps) else '', int(steps[steps > 0].sum()), int(agree),
            '' if agree else 'readers disagree'], stamps


def check_bag(bag, check, bags_log):
    """
    Hold one bag's ``metadata.yaml`` against its finished files; write a ``soak_bags.csv`` row.

    The listing must name exactly the finished files present, with each file's summary
    message count, and ``AnyReader`` must open the bag with the total. A bag being split or
    trimmed is looked at again (:data:`SETTLE_TRIES`).

    Returns
    -------
    tuple
        ``(true, finished names, listing)``.
    """
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    for attempt in range(SETTLE_TRIES):
        finished = entries(bag)[0]
        listed = listing(bag)
        problem, summaries, opens = '', 0, ''
        if listed is None and finished:
            problem = 'no readable metadata.yaml'
        elif listed is not None and sorted(listed) != sorted(finished):
            problem = (f'lists {len(set(listed) - set(finished))} missing, '
                       f'{len(set(finished) - set(listed))} unlisted')
        if not problem and finished:
            try:
                for name in finished:
                    with open(bag / name, 'rb') as stream:
                        count = make_reader(stream).get_summary().statistics.message_count
                    summaries += count
                    if count != listed[name][0]:
                        problem = f'{name}: listed {listed[name][0]} messages, holds {count}'
                with AnyReader([bag]) as reader:
                    opens = int(reader.message_count == summaries)
                if not opens:
                    problem = problem or 'AnyReader counts differently'
            except Exception as error:
                problem, opens = f'{type(error).__name__}: {error}'[:200], 0
        if not problem or attempt == SETTLE_TRIES - 1:
            break
        time.sleep(SETTLE_S)
    listed_messages = sum(value[0] for value in (listed or {}).values())
    bags_log.write([check, bag.name, len(listed or {}), len(finished), listed_messages,
                    summaries, opens, int(not problem), problem])
    return not problem, set(finished), listed or {}


def check_recordings(paths, check, recordings, period_ns):
    """
    Read back what the recorder directory holds; every file read once in a soak.

    Files already read readable (``soak_files.csv``, same bag, name and size) are not read
    again: a finished file does not change. The holes in the IMU stamps inside each file
    read go to ``soak_recorded_gaps.csv`` (``kind``: the file); those between two files of a
    bag follow from ``soak_files.csv`` (first and last stamp of each).

    Returns
    -------
    dict
        ``bags``, ``bags_untrue``, ``files_present``, ``files_read``, ``files_unreadable``
        and ``spans`` (``{bag name: [(first, last IMU stamp)]}`` of its present files).
    """
    known = {(row['bag'], row['file'], row['bytes']): row for row in read_csv(paths.files)
             if row['readable'] == '1'}
    files_log = CsvLog(paths.files, FILE_COLUMNS, append=True)
    bags_log = CsvLog(paths.bags, BAG_COLUMNS, append=True)
    gaps_log = CsvLog(paths.recorded_gaps, GAP_COLUMNS, append=True)
    result = {'bags': 0, 'bags_untrue': 0, 'files_present': 0, 'files_read': 0,
              'files_unreadable': 0, 'spans': {}}
    try:
        for bag in bag_directories(recordings):
            true, finished, listed = check_bag(bag, check, bags_log)
            result['bags'] += 1
            result['bags_untrue'] += not true
            spans = result['spans'].setdefault(bag.name, [])
            for name in sorted(finished, key=lambda n: split_index(Path(n))):
                path = bag / name
                try:
                    size = path.stat().st_size
                except FileNotFoundError:  # retention, meanwhile
                    continue
                result['files_present'] += 1
                row = known.get((bag.name, name, str(size)))
                if row is None:
                    cells, stamps = read_file(path, period_ns)
                    result['files_read'] += 1
                    result['files_unreadable'] += cells[7] == 0
                    files_log.write([check, bag.name, name, size,
                                     listed.get(name, ('', ''))[0], *cells])
                    steps = np.diff(stamps) // period_ns - 1
                    for index in np.flatnonzero(steps > 0):
                        gaps_log.write(['', '', stamps[index], stamps[index + 1],
                                        steps[index], f'{bag.name}/{name}'])
                    first, last = cells[4], cells[5]
                else:
                    first, last = row['first_stamp_ns'], row['last_stamp_ns']
                if first != '':
                    spans.append((int(first), int(last)))
    finally:
        files_log.close()
        bags_log.close()
        gaps_log.close()
    return result


def check_restart(paths, restart_file):
    """
    After a restart: read back the recorder directory, and judge what the kill left.

    ``restart_file`` (JSON, written by the driver once the new node's start-up recovery
    finished the killed run's bag) holds the kill and the directory as the kill left it
    (:func:`disk_state`). Finished files of that moment may since be gone only oldest
    first, and only with retention; the killed run's last recorded sample is held against
    the kill instant in the report. Writes one ``soak_restarts.csv`` row.
    """
    restart = json.loads(Path(restart_file).read_text())
    recordings = Path(restart['recordings'])
    result = check_recordings(paths, restart['run'], recordings, restart['period_ns'])
    present = {(bag.name, name) for bag in bag_directories(recordings)
               for name in entries(bag)[0]}
    state = restart['state']
    order = list(state)  # oldest bag first (bag_directories)
    at_kill = sorted(((bag, name) for bag, s in state.items() for name in s['finished']),
                     key=lambda item: (order.index(item[0]), split_index(Path(item[1]))))
    gone = [item for item in at_kill if item not in present]
    problems = []
    if gone and not restart['retention']:
        problems.append(f'{len(gone)} files finished at the kill gone without retention')
    elif gone != at_kill[:len(gone)]:
        problems.append(f'{len(gone)} files finished at the kill gone, not the oldest first')
    if result['bags_untrue']:
        problems.append(f'{result["bags_untrue"]} bag(s) not as their metadata.yaml lists')
    if result['files_unreadable']:
        problems.append(f'{result["files_unreadable"]} file(s) unreadable')
    killed = restart['killed_bag']
    spans = result['spans'].get(killed, [])
    firsts = [first for spans in result['spans'].values() for first, _ in spans]
    log = Path(restart['log'])
    warned = log.exists() and 'earlier run left unfinished' in log.read_text(errors='replace')
    stale = stale_listings(state)
    restarts = CsvLog(paths.restarts, RESTART_COLUMNS, append=True)
    restarts.write([
        restart['run'], restart['mode'], restart['kill_ns'], restart['hit'],
        restart['restarted_ns'], restart['first_published_ns'], restart['recovered_ns'],
        time.time_ns(), killed, len(state.get(killed, {}).get('finished', {})),
        sum(state.get(killed, {}).get('parts', {}).values()),
        f'stale: {" ".join(stale)}' if stale else 'true', len(gone),
        max((last for _, last in spans), default=''), min(firsts, default=''),
        result['files_present'], result['files_read'], result['files_unreadable'],
        result['bags'], result['bags_untrue'], int(warned), '; '.join(problems)])
    restarts.close()


def readback(paths, recordings, period_ns):
    """Read back everything at the end (the node stopped): :func:`check_recordings`."""
    return check_recordings(paths, 'end', recordings, period_ns)
