"""The files of one soak (``bench/soak.py``): where they go, their columns, how they are read.

Every measurement is appended to a CSV file as it is made, flushed at once, so that a soak
that dies keeps what it measured; the report (``soak_report.py``) is written from these
files alone.
"""

import csv
import os
from pathlib import Path
import struct

import numpy as np

NS_PER_S = 1_000_000_000
MIB = float(1 << 20)
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')
STAMP = struct.Struct('<iI')
"""``header.stamp`` (sec, nanosec) right after the 4-byte CDR encapsulation header."""
IMU_TOPIC = '/imu/data_raw'

NODE_COLUMNS = [
    'wall_ns', 't_s', 'run', 'node_pid', 'rss_kib', 'rss_anon_kib', 'fds', 'threads',
    'cpu_s', 'load1', 'recorded_bytes', 'recorded_files', 'part_bytes', 'largest_file_bytes',
    'metadata_bytes', 'recorder_bytes', 'bags', 'oldest_start_ns', 'newest_end_ns',
    'trace_files',
    'trace_bytes', 'state_bytes', 'state_readable', 'state_mtime_ns', 'computed',
    'published', 'withheld', 'skipped', 'late', 'max_delay_ms', 'waiting', 'dropped',
    'parameter_changes', 'parameter_refusals', 'calibrations', 'calibration_failures',
    'recorder_problem']
"""``soak.csv``: the node process (``/proc``), what it wrote, its ``/diagnostics`` counters
(those of the running process: each run starts from zero)."""
STREAM_COLUMNS = [
    'wall_ns', 'received', 'lost', 'gaps', 'off_grid', 'out_of_order', 'first_stamp_ns',
    'last_stamp_ns', 'offset_min_us', 'offset_p50_us', 'offset_p99_us', 'offset_max_us',
    'interval_received', 'grids']
"""``soak_stream.csv``: the subscriber, every ``--sample-every`` s (totals since its start)."""
GAP_COLUMNS = ['received_ns', 'published_ns', 'before_stamp_ns', 'after_stamp_ns', 'missing',
               'kind']
"""``soak_gaps.csv``: every hole in the stamps the subscriber received (``kind`` ``restart``:
the hole from the last sample of a killed node to the first of the next)."""
EVENT_COLUMNS = ['kind', 'name', 'sent_ns', 'answered_ns', 'success', 'message']
"""``soak_events.csv``: service calls, parameter refusals and kills (``sent_ns``: the node
stopped; ``answered_ns``: the next one started)."""
FILE_COLUMNS = ['check', 'bag', 'file', 'bytes', 'metadata_messages', 'summary_messages',
                'mcap_messages', 'rosbags_messages', 'imu_messages', 'first_stamp_ns',
                'last_stamp_ns', 'missing_inside', 'readable', 'problem']
"""``soak_files.csv``: each recorded file read back (``check``: the restart after which it was
read, ``end`` at the end of the soak)."""
BAG_COLUMNS = ['check', 'bag', 'listed', 'present', 'listed_messages', 'summary_messages',
               'rosbags_opens', 'true', 'problem']
"""``soak_bags.csv``: each bag directory's ``metadata.yaml`` against the files it holds."""
RESTART_COLUMNS = [
    'run', 'mode', 'kill_ns', 'hit', 'restarted_ns', 'first_published_ns', 'recovered_ns',
    'checked_ns', 'killed_bag', 'finished_at_kill', 'part_bytes_at_kill',
    'listing_as_left', 'finished_missing', 'last_stamp_ns', 'kept_from_ns',
    'files_present', 'files_read', 'files_unreadable', 'bags', 'bags_untrue', 'warn_line',
    'problem']
"""``soak_restarts.csv``: one row per kill, written once its check is done."""


class Paths:
    """The files of one soak, beside its report ``out`` (``soak.md``)."""

    def __init__(self, out):
        self.out = Path(out)
        stem = self.out.with_suffix('')
        self.run = Path(f'{stem}_run.json')
        self.node = Path(f'{stem}.csv')
        self.stream = Path(f'{stem}_stream.csv')
        self.gaps = Path(f'{stem}_gaps.csv')
        self.events = Path(f'{stem}_events.csv')
        self.files = Path(f'{stem}_files.csv')
        self.bags = Path(f'{stem}_bags.csv')
        self.restarts = Path(f'{stem}_restarts.csv')
        self.recorded_gaps = Path(f'{stem}_recorded_gaps.csv')
        self.figure = Path(f'{stem}.png')


class CsvLog:
    """
    Append rows to a CSV file, flushed at once (a soak that dies keeps its rows).

    Parameters
    ----------
    path : pathlib.Path
        The file.
    columns : list of str
        Its header, written when the file is new (or ``append`` is false).
    append : bool
        Add to an existing file (a checker process adding its rows).
    """

    def __init__(self, path, columns, append=False):
        new = not append or not Path(path).exists()
        self._file = open(path, 'a' if append else 'w', newline='')
        self._writer = csv.writer(self._file)
        if new:
            self._writer.writerow(columns)
        self._file.flush()

    def write(self, row):
        """Write one row and flush it."""
        self._writer.writerow(row)
        self._file.flush()

    def close(self):
        """Close the file."""
        self._file.close()


def read_csv(path):
    """Return the rows of a CSV file as dicts of strings ([] if it does not exist)."""
    if not Path(path).exists():
        return []
    with open(path, newline='') as file:
        return list(csv.DictReader(file))


def column(rows, name, dtype=float):
    """Return one column of ``rows`` as an array (empty or missing cells as NaN)."""
    return np.array([dtype(row[name]) if row.get(name) not in ('', 'None', None) else np.nan
                     for row in rows], dtype=float)
