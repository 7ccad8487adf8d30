"""
Recover what a killed node left unfinished: bag directories and traces, ``qfa-report recover``.

:func:`recover_bag_directory` finishes every ``.part`` of a flight-recorder bag directory
(:func:`~qfa_ros.bag.part_repair.recover_part`) and rewrites its ``metadata.yaml`` from
the files' own summaries, as ``ros2 bag reindex`` does; :func:`recover_trace` finishes a
trace; :func:`recover` is ``qfa-report recover PATH`` and :func:`unfinished_recordings`
with :func:`unfinished_traces` are what the node looks for at start.

Finding what needs recovery reads no file and imports no MCAP package; recovering does.

**Never under a live recorder**: the flight recorder ``flock``-s its bag directory from
its creation to its close; a locked directory is left alone (two nodes may share
``output_dir``). **Idempotent**: a directory that needs nothing (:func:`needs_recovery`,
``stat`` calls only) is not touched. **Bounded**: at most :data:`MAX_ENTRIES` directory
entries, only the recorder's and the trace writer's names, no symlink followed.
"""

import dataclasses
import errno
import itertools
import os
from pathlib import Path
import re

from qfa_ros.bag.part_files import (
    DELETION_SUFFIX,
    finish_deletion,
    lock_exclusively,
    METADATA_FILE,
    PART_SUFFIX,
)

__all__ = [
    'MAX_ENTRIES',
    'needs_recovery',
    'recover',
    'recover_bag_directory',
    'recover_trace',
    'Recovery',
    'unfinished_recordings',
    'unfinished_traces',
]

MAX_ENTRIES = 100_000
"""Directory entries looked at per directory."""
TRACE_PART_RE = re.compile(r'^qfa_[a-z_]+_\d{19}\.mcap\.part$')
"""What :func:`~qfa_ros.bag.estimation_trace.trace_path` names a trace while it is written."""
METADATA_LEFTOVER_RE = re.compile(r'^\.metadata\.yaml\.\d+\.tmp$')
"""What a kill while ``metadata.yaml`` was being replaced leaves (``write_atomically``)."""


@dataclasses.dataclass
class Recovery:
    """What became of one bag directory or trace."""

    path: Path
    kind: str
    """``bag`` or ``trace``."""
    status: str
    """``recovered``, ``nothing to recover``, ``in use`` or ``failed``."""
    files: list = dataclasses.field(default_factory=list)
    problem: str = ''
    listed: tuple = None
    """``(files, messages)`` that the rewritten ``metadata.yaml`` lists (bags)."""

    @property
    def changed(self):
        """Whether anything on disk was changed."""
        return self.status == 'recovered'

    def describe(self):
        """Return one line naming the path, what was recovered and what is wrong."""
        parts = [file.describe() for file in self.files
                 if file.status in ('recovered', 'failed')]
        if self.listed is not None:
            parts.append(f'metadata.yaml lists {self.listed[0]} files, {self.listed[1]} '
                         'messages')
        if self.problem:
            parts.append(self.problem)
        status = {'in use': 'in use by a running writer: left as it is'}.get(
            self.status, self.status)
        if self.status == 'recovered' or (self.status == 'failed' and parts):
            status = '; '.join(parts)
        return f'{self.path}: {status}'


def _entries(directory):
    """Return at most :data:`MAX_ENTRIES` ``os.DirEntry`` of ``directory``."""
    with os.scandir(directory) as iterator:
        return list(itertools.islice(iterator, MAX_ENTRIES))


def _split_files(directory, entries):
    """Return ``{index: [finished name or None, part name or None]}`` of a bag's files."""
    pattern = re.compile(rf'^{re.escape(directory.name)}_(\d+)\.mcap(\.part)?$')
    files = {}
    for entry in entries:
        match = pattern.match(entry.name)
        if match and entry.is_file(follow_symlinks=False):
            files.setdefault(int(match.group(1)), [None, None])[bool(match.group(2))] = \
                entry.name
    return files


def _deletions(directory, entries):
    """Return the deletion markers (``NAME_i.mcap.deleting``) of a bag's files."""
    pattern = re.compile(rf'^{re.escape(directory.name)}_\d+\.mcap{re.escape(DELETION_SUFFIX)}$')
    return [entry.name for entry in entries
            if pattern.match(entry.name) and entry.is_file(follow_symlinks=False)]


def needs_recovery(directory):
    """
    Return whether bag directory ``directory`` was left unfinished by a kill.

    True when it holds a ``.part`` file, a half-written ``metadata.yaml`` or a deletion
    marker (retention killed while deleting a file), or finished files that
    ``metadata.yaml`` cannot list (missing, or older than the newest file). Only ``stat``
    calls: no file is read.
    """
    directory = Path(directory)
    entries = _entries(directory)
    if any(METADATA_LEFTOVER_RE.match(entry.name) for entry in entries) \
            or _deletions(directory, entries):
        return True
    files = _split_files(directory, entries)
    if any(part for _, part in files.values()):
        return True
    finished = [directory / name for name, _ in files.values() if name]
    if not finished:
        return False
    try:
        metadata = os.lstat(directory / METADATA_FILE)
    except FileNotFoundError:
        return True
    return metadata.st_mtime_ns < max(os.lstat(path).st_mtime_ns for path in finished)


def recover_bag_directory(directory, should_stop=None):
    """
    Recover a flight-recorder bag directory left unfinished; return a :class:`Recovery`.

    A deletion retention began is finished (the file its marker names deleted:
    :func:`~qfa_ros.bag.part_files.finish_deletion`), every ``.part`` finished
    (:func:`recover_part`), a half-written ``metadata.yaml`` removed, and ``metadata.yaml``
    rewritten listing every finished file with counts from the files' own summaries. A
    directory locked by a live recorder is left alone (``in use``); one that needs nothing
    is not touched (``nothing to recover``).
    """
    # Imported here: finding what to recover needs no MCAP package (the node's start).
    from qfa_ros.bag.bag_directory import merge_bag_metadata, write_bag_metadata
    from qfa_ros.bag.part_repair import (
        finished_file_metadata,
        NotRecoverableError,
        recover_part,
        RecoveredFile,
        RecoveryStoppedError,
    )

    directory = Path(directory)
    result = Recovery(directory, 'bag', 'failed')
    try:
        descriptor = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW
                             | os.O_CLOEXEC)
    except OSError as error:
        result.problem = ('a symlink or not a directory, not followed'
                          if error.errno in (errno.ELOOP, errno.ENOTDIR)
                          else f'cannot open it: {error.strerror}')
        return result
    try:
        if not lock_exclusively(descriptor, wait=False):
            result.status = 'in use'
            return result
        if not needs_recovery(directory):
            result.status = 'nothing to recover'
            return result
        entries = _entries(directory)
        deletions = _deletions(directory, entries)
        for marker in deletions:
            finish_deletion(descriptor, marker)
        if deletions:
            result.problem = (f'finished deleting {len(deletions)} file(s) retention was '
                              'deleting')
            entries = _entries(directory)
        for entry in entries:
            if METADATA_LEFTOVER_RE.match(entry.name) and entry.is_file(follow_symlinks=False):
                os.unlink(directory / entry.name)
        metadata = []
        for _, (finished, part) in sorted(_split_files(directory, entries).items()):
            if part:
                recovered = recover_part(directory / part, should_stop)
                result.files.append(recovered)
                if recovered.status == 'recovered':
                    metadata.append(recovered.metadata)
                    continue
                if recovered.status != 'finished':
                    continue  # failed (left as it is), or not recoverable now
            name = finished or part[:-len(PART_SUFFIX)]
            try:
                metadata.append(finished_file_metadata(directory / name))
            except (NotRecoverableError, OSError) as error:
                result.files.append(RecoveredFile(directory / name, 'failed', problem=(
                    f'{error}: not listed in metadata.yaml')))
        merged = merge_bag_metadata(metadata)
        write_bag_metadata(directory, merged)
        result.listed = (len(metadata), merged['message_count'])
        failed = [file for file in result.files if file.status == 'failed']
        result.status = 'failed' if failed and not metadata else 'recovered'
    except RecoveryStoppedError:
        raise
    except OSError as error:
        result.problem = f'{type(error).__name__}: {error.strerror or error}'
    finally:
        os.close(descriptor)
    return result


def recover_trace(part, should_stop=None):
    """Recover a trace ``.part`` (one file, no bag directory); return a :class:`Recovery`."""
    from qfa_ros.bag.part_repair import final_path, recover_part

    part = Path(part)
    recovered = recover_part(part, should_stop)
    status = recovered.status if recovered.status in ('recovered', 'failed', 'in use') \
        else 'nothing to recover'
    return Recovery(final_path(part), 'trace', status, [recovered])


# --- what to recover ---------------------------------------------------------------------

def unfinished_recordings(directory, prefix):
    """
    Return the bag directories in ``directory`` that need recovery, oldest name first.

    Only real directories (no symlink) named as the flight recorder names them for
    ``prefix`` (``PREFIX_YYYY_MM_DD-HH_MM_SS[_N]``) are looked at, at most
    :data:`MAX_ENTRIES` entries; they need recovery by :func:`needs_recovery`. A missing
    ``directory`` has none.
    """
    pattern = re.compile(rf'^{re.escape(prefix)}_\d{{4}}_\d\d_\d\d-\d\d_\d\d_\d\d(_\d+)?$')
    try:
        entries = _entries(directory)
    except (FileNotFoundError, NotADirectoryError):
        return []
    return sorted(Path(directory) / entry.name for entry in entries
                  if pattern.match(entry.name) and entry.is_dir(follow_symlinks=False)
                  and needs_recovery(Path(directory) / entry.name))


def unfinished_traces(directory):
    """Return the trace ``.part`` files (``qfa_<kind>_<time>.mcap.part``) in ``directory``."""
    try:
        entries = _entries(directory)
    except (FileNotFoundError, NotADirectoryError):
        return []
    return sorted(Path(directory) / entry.name for entry in entries
                  if TRACE_PART_RE.match(entry.name) and entry.is_file(follow_symlinks=False))


def _is_bag_directory(directory, entries):
    return any(entry.name == METADATA_FILE for entry in entries) or bool(
        _split_files(directory, entries))


def recover(path, should_stop=None, depth=2):
    """
    Recover what ``path`` holds unfinished; return a list of :class:`Recovery`.

    ``path`` is a flight-recorder bag directory, a ``.mcap.part`` file (a trace) or a
    directory holding them, ``depth`` levels down: ``recorder.directory``, ``trace_dir``
    or ``output_dir``. A symlink given here is followed; none found inside is.

    Raises
    ------
    OSError
        ``path`` is missing, another file than a ``.mcap.part``, or neither a regular file
        nor a directory.
    """
    path = Path(path).resolve()
    if path.is_file():
        if not path.name.endswith('.mcap' + PART_SUFFIX):
            raise OSError(errno.EINVAL, 'not a .mcap.part file, nor a directory of them',
                          str(path))
        return [recover_trace(path, should_stop)]
    if path.exists() and not path.is_dir():
        raise OSError(errno.EINVAL, 'not a regular file or directory', str(path))
    if not path.is_dir():
        raise FileNotFoundError(errno.ENOENT, 'no such file or directory', str(path))
    return _recover_directory(path, should_stop, depth)


def _recover_directory(path, should_stop, depth):
    entries = _entries(path)
    if _is_bag_directory(path, entries):
        return [recover_bag_directory(path, should_stop)]
    results = []
    for entry in sorted(entries, key=lambda entry: entry.name):
        if entry.is_dir(follow_symlinks=False) and depth > 0:
            results += _recover_directory(path / entry.name, should_stop, depth - 1)
        elif entry.name.endswith('.mcap' + PART_SUFFIX) and entry.is_file(
                follow_symlinks=False):
            results.append(recover_trace(path / entry.name, should_stop))
    return results
