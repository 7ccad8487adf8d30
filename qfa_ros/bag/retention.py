"""
Retention: a flight recorder's directory kept within a duration and a size, oldest first.

:class:`Retention` looks at the bag directories one node's flight recorder wrote into one
directory, earlier sessions and restarts included, and deletes the oldest finished files
until what remains is within the limits: the newest files are kept while the time they
cover adds up to less than ``keep_ns`` (the first to reach it is kept too) and their
sizes to at most ``keep_bytes`` (0: no limit). The file being written is never deleted
nor counted; so the directory holds at most ``keep_bytes``, or ``keep_ns`` of recording
plus one file, and the file being written.

What it touches is the recorder's own, and nothing else:

- **where**: bag directories directly in the directory (real directories, no symlink
  followed: every name is taken in a directory opened with ``O_NOFOLLOW``), named as the
  recorder names them for the node (``PREFIX_YYYY_MM_DD-HH_MM_SS[_N]``);
- **what**: a finished file ``BAG_i.mcap`` that the bag's ``metadata.yaml`` (rosbag2's, as
  the recorder writes it) lists, whose MCAP header names this package's writer and whose
  summary reads (checked before it is deleted: a file that fails is left alone and no
  longer counted);
- **when**: only a bag no one records into or recovers (its ``flock`` taken without
  waiting) and that needs no recovery (:func:`~qfa_ros.bag.recovery.needs_recovery`); a
  bag skipped so is not counted, and nothing as new as it or newer is deleted, so the
  oldest go first. The live recorder's bag is deleted from through the recorder itself
  (:meth:`~qfa_ros.bag.flight_recorder.FlightRecorder.delete_finished`).

Each deletion is crash-safe (:func:`~qfa_ros.bag.part_files.delete_finished_file`); a bag
left without a file is removed with its ``metadata.yaml`` (a directory holding anything
else is left). Times are the recording's own (the files' first and last messages, the
node clock), so a node started again after days off keeps what it recorded before.
"""

import dataclasses
import itertools
import os
from pathlib import Path
import re
import stat
import threading

import yaml

from qfa_ros.bag.bag_directory import BagMetadata
from qfa_ros.bag.part_files import (
    delete_finished_file,
    lock_exclusively,
    METADATA_FILE,
)
from qfa_ros.bag.part_repair import finished_file_metadata, NotRecoverableError
from qfa_ros.bag.reader import MAX_METADATA_BYTES
from qfa_ros.bag.recovery import MAX_ENTRIES, needs_recovery

__all__ = ['RecordedFile', 'Retention', 'RetentionSummary', 'spans_ns', 'to_delete']

MAX_GAP_NS = 1_000_000_000
"""Longest time between a file's last message and the next file's first counted as
recorded [ns]: a longer gap (nothing recorded meanwhile: a managed node inactive) is not."""

_DIRECTORY_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_SKIP = 'skip'
"""A bag in use or left unfinished: not counted, and nothing as new or newer deleted."""
_EMPTY = 'empty'
"""A bag of the recorder's without a file: removed."""
_IGNORED = 'ignored'
"""Not a bag as the recorder leaves one (no file of its, unreadable or inconsistent
``metadata.yaml``): not counted, not touched."""


@dataclasses.dataclass(frozen=True)
class RecordedFile:
    """One finished file of a bag, as retention counts it."""

    bag: str
    """The bag directory's name."""
    name: str
    """The file's name in it."""
    size: int
    """Its size [bytes]."""
    start_ns: int
    """Its first message [ns, node clock]."""
    span_ns: int
    """The recording time it covers [ns] (:func:`spans_ns`)."""


@dataclasses.dataclass
class RetentionSummary:
    """What retention deleted since it started, and what the last pass kept."""

    deleted: int = 0
    """Files deleted."""
    deleted_bytes: int = 0
    """Their bytes."""
    kept: int = 0
    """Finished files kept after the last pass (every bag counted)."""
    kept_bytes: int = 0
    """Their bytes."""
    kept_ns: int = 0
    """The recording time they cover [ns]."""
    oldest_kept_ns: int = None
    """First message of the oldest file kept [ns, node clock], or None."""
    problem: str = ''
    """Why the last pass stopped short, or empty."""


def spans_ns(entries, next_start_ns=None):
    """
    Return the recording time each file of one bag covers [ns].

    A file covers from its first message to the next file's first message (the split
    between them included), but a gap longer than :data:`MAX_GAP_NS` after its last
    message is not counted; the last file covers its own duration, or up to
    ``next_start_ns``, the first message of the file being written after it. A file with
    no message (a part a kill cut right after a split, recovered; its start 0) covers
    nothing and is passed over as the next file.

    Parameters
    ----------
    entries : list of tuple
        ``(name, start [ns], duration [ns], message count)`` per file, in order
        (:attr:`BagMetadata.files`).
    next_start_ns : int, optional
        First message of the file being written after the last entry [ns].

    Returns
    -------
    list of int
        One span per entry [ns], none negative.
    """
    spans, following = [], next_start_ns
    for _, start, duration, count in reversed(entries):
        if not count:
            spans.append(0)
            continue
        span = duration if following is None else min(following - start, duration + MAX_GAP_NS)
        spans.append(max(0, span))
        following = start
    return spans[::-1]


def to_delete(files, keep_ns, keep_bytes):
    """
    Return how many of ``files`` (oldest first) to delete, the oldest first.

    The newest are kept while the time they cover adds up to less than ``keep_ns`` (the
    file that reaches it is kept too) and their sizes to at most ``keep_bytes``; 0 is no
    limit on that side.

    Parameters
    ----------
    files : list of RecordedFile
        Every finished file counted, oldest first.
    keep_ns : int
        Recording time to keep [ns]; 0: no limit.
    keep_bytes : int
        Bytes to keep at most; 0: no limit.

    Returns
    -------
    int
        How many of the first files go.
    """
    covered = size = kept = 0
    for file in reversed(files):
        if (keep_ns and covered >= keep_ns) or (keep_bytes and size + file.size > keep_bytes):
            break
        covered += file.span_ns
        size += file.size
        kept += 1
    return len(files) - kept


class Retention:
    """
    Keep one node's recordings in one directory within a duration and a size.

    Parameters
    ----------
    directory : pathlib.Path
        The recorder's directory, resolved (the caller confines it).
    prefix : str
        The bag name prefix (the node's name).
    keep_ns : int
        Recording time to keep [ns]; 0: no limit.
    keep_bytes : int
        Bytes of finished files to keep at most; 0: no limit.

    Raises
    ------
    ValueError
        A limit is negative or not an integer, or the prefix is not a plain name.
    """

    def __init__(self, directory, prefix, keep_ns, keep_bytes):
        for name, value in (('keep_ns', keep_ns), ('keep_bytes', keep_bytes)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise ValueError(f'{name} must be a whole number, 0 or more, got {value!r}')
        if not re.match(r'^[A-Za-z0-9_.-]+$', prefix):
            raise ValueError(f'prefix must be a plain file name part, got {prefix!r}')
        self.directory = Path(directory)
        self.keep_ns, self.keep_bytes = keep_ns, keep_bytes
        self._bag_name = re.compile(
            rf'^{re.escape(prefix)}_(\d{{4}}_\d\d_\d\d-\d\d_\d\d_\d\d)(?:_(\d+))?$')
        # One pass at a time. Protects summary, _metadata and _foreign.
        self._lock = threading.Lock()
        self.summary = RetentionSummary()
        # Per bag of an earlier session: (metadata.yaml's (inode, size, mtime), its
        # BagMetadata), read again only when it changed.
        self._metadata = {}
        # (bag, name, inode) of files whose check failed: left alone, not counted.
        self._foreign = set()

    @property
    def active(self):
        """Return whether a limit is set."""
        return bool(self.keep_ns or self.keep_bytes)

    def apply(self, live=None):
        """
        Delete the oldest finished files beyond the limits; return the :class:`RetentionSummary`.

        Parameters
        ----------
        live : FlightRecorder, optional
            The recorder writing into the directory now: its finished files are counted
            last (the newest) and deleted through it; its file being written never.

        Returns
        -------
        RetentionSummary
            A copy of :attr:`summary` after the pass.

        Raises
        ------
        OSError
            The directory cannot be opened; what a bag or a file raises stops the pass
            (said in ``problem``), what was deleted stays deleted.
        """
        with self._lock:
            root = os.open(self.directory, _DIRECTORY_FLAGS)
            try:
                self._pass(root, live)
            finally:
                os.close(root)
            return dataclasses.replace(self.summary)

    def _pass(self, root, live):
        live_name, live_files = (None, []) if live is None else self._live_files(live)
        files, barrier = [], None
        for key, name in self._bags(root, live_name):
            found = self._bag_files(root, name)
            if found is _SKIP:
                barrier = key if barrier is None else barrier
            elif found is _EMPTY:
                self._remove_bag(root, name)
            elif found is not _IGNORED:
                files += [(key, file) for file in found]
        files += [(None, file) for file in live_files]
        self.summary.problem = ''
        deleted = 0
        for key, file in files[:to_delete([f for _, f in files], self.keep_ns, self.keep_bytes)]:
            if barrier is not None and (key is None or key >= barrier):
                self.summary.problem = 'a bag in use or left unfinished holds older files'
                break
            try:
                done = live.delete_finished(file.name) if key is None \
                    else self._delete(root, file)
            except (OSError, ValueError) as error:
                self.summary.problem = f'{file.name}: {type(error).__name__}: {error}'
                break
            if not done:
                break
            deleted += 1
            self.summary.deleted += 1
            self.summary.deleted_bytes += file.size
        kept = [file for _, file in files[deleted:]]
        self.summary.kept, self.summary.kept_bytes = len(kept), sum(f.size for f in kept)
        self.summary.kept_ns = sum(f.span_ns for f in kept)
        self.summary.oldest_kept_ns = kept[0].start_ns if kept else None

    def _live_files(self, live):
        name, entries, next_start = live.finished_entries()
        if name is None:
            return None, []
        files = []
        for (file, start, _, _), span in zip(entries, spans_ns(entries, next_start)):
            try:
                size = os.lstat(self.directory / name / file).st_size
            except FileNotFoundError:
                continue
            files.append(RecordedFile(name, file, size, start, span))
        return name, files

    def _bags(self, root, live_name):
        """Return ``(key, name)`` of the node's bag directories but the live one, oldest first."""
        with os.scandir(root) as iterator:
            entries = list(itertools.islice(iterator, MAX_ENTRIES))
        bags = []
        for entry in entries:
            match = self._bag_name.match(entry.name)
            if match and entry.name != live_name and entry.is_dir(follow_symlinks=False):
                bags.append(((match.group(1), int(match.group(2) or 1)), entry.name))
        return sorted(bags)

    def _bag_files(self, root, name):
        """Return the counted files of bag ``name``, or ``_SKIP``, ``_EMPTY``, ``_IGNORED``."""
        try:
            descriptor = os.open(name, _DIRECTORY_FLAGS, dir_fd=root)
        except OSError:
            return _IGNORED
        try:
            if not lock_exclusively(descriptor, wait=False) \
                    or needs_recovery(self.directory / name):
                return _SKIP
            entries = _listing(descriptor)
            if METADATA_FILE not in entries:
                # No finished file either (needs_recovery): empty, or a stranger's files.
                return _IGNORED if entries else _EMPTY
            metadata = self._read_metadata(descriptor, name)
            if metadata is None:
                return _IGNORED
            listed = metadata.files
            if not listed:
                return _EMPTY
            found = []
            for (file, start, _, _), span in zip(listed, spans_ns(listed)):
                entry = entries.get(file)
                if entry is None or not entry.is_file(follow_symlinks=False):
                    return _IGNORED  # listed but gone: not the recorder's doing
                info = entry.stat(follow_symlinks=False)
                if (name, file, info.st_ino) not in self._foreign:
                    found.append(RecordedFile(name, file, info.st_size, start, span))
            return found
        finally:
            os.close(descriptor)

    def _read_metadata(self, descriptor, name):
        """Return bag ``name``'s BagMetadata (cached while unchanged), or None if not ours."""
        try:
            opened = os.open(METADATA_FILE, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK
                             | os.O_CLOEXEC, dir_fd=descriptor)
        except OSError:
            return None
        with os.fdopen(opened, 'rb') as stream:
            info = os.fstat(opened)
            signature = _signature(info)
            cached = self._metadata.get(name)
            if cached is not None and cached[0] == signature:
                return cached[1]
            if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_METADATA_BYTES:
                return None
            text = stream.read(MAX_METADATA_BYTES)
        try:
            document = yaml.load(text, Loader=getattr(yaml, 'CSafeLoader', yaml.SafeLoader))
            metadata = BagMetadata.from_mapping(document['rosbag2_bagfile_information'])
        except (yaml.YAMLError, RecursionError, ValueError, TypeError, KeyError):
            return None
        pattern = re.compile(rf'^{re.escape(name)}_\d+\.mcap$')
        if not all(pattern.match(file) for file in metadata.file_names):
            return None
        self._metadata[name] = (signature, metadata)
        return metadata

    def _delete(self, root, file):
        """Delete ``file`` of a bag of an earlier session; return whether it was."""
        descriptor = os.open(file.bag, _DIRECTORY_FLAGS, dir_fd=root)
        try:
            cached = self._metadata.get(file.bag)
            if not lock_exclusively(descriptor, wait=False) or cached is None \
                    or self._read_metadata(descriptor, file.bag) is not cached[1]:
                return False  # in use, or changed since it was counted
            path = self.directory / file.bag
            try:
                own = finished_file_metadata(path / file.name, recorder_only=True)
            except NotRecoverableError:
                self._foreign.add((file.bag, file.name, os.lstat(path / file.name).st_ino))
                self.summary.problem = f'{file.name}: not recognised as a recording: left alone'
                return False
            metadata = cached[1]
            # Until it is done the cached metadata is not what is on disk: read it anew.
            del self._metadata[file.bag]
            metadata.remove(file.name, own)
            # Listing no file once the last goes: a bag holding something else stays so.
            delete_finished_file(descriptor, file.name, lambda: metadata.write(path))
            info = os.stat(METADATA_FILE, dir_fd=descriptor, follow_symlinks=False)
            self._metadata[file.bag] = (_signature(info), metadata)
        finally:
            os.close(descriptor)
        if not metadata.files:
            self._remove_bag(root, file.bag)
        return True

    def _remove_bag(self, root, name):
        """Remove bag ``name`` of the recorder's left without a file, if nothing else is in it."""
        self._metadata.pop(name, None)
        try:
            descriptor = os.open(name, _DIRECTORY_FLAGS, dir_fd=root)
        except OSError:
            return
        try:
            if not lock_exclusively(descriptor, wait=False):
                return
            entries = set(_listing(descriptor))
            if entries - {METADATA_FILE}:
                return
            if entries:
                os.unlink(METADATA_FILE, dir_fd=descriptor)
            os.rmdir(name, dir_fd=root)
        except OSError:
            pass  # something came meanwhile, or it is not ours to remove: it stays
        finally:
            os.close(descriptor)


def _listing(descriptor):
    """Return ``{name: os.DirEntry}`` of at most MAX_ENTRIES entries of an open directory."""
    with os.scandir(descriptor) as iterator:
        return {entry.name: entry for entry in itertools.islice(iterator, MAX_ENTRIES)}


def _signature(info):
    """Return what tells a ``metadata.yaml`` replaced: inode, size, modification time."""
    return info.st_ino, info.st_size, info.st_mtime_ns
