"""
Durable MCAP files: written under ``NAME.mcap.part``, published atomically.

A :class:`PartFile` is the unbuffered stream the mcap ``Writer`` writes into, so the
operating system holds every complete chunk, and holds an exclusive ``flock`` on it while
it is written, so that no recovery (:mod:`qfa_ros.bag.recovery`) touches a file someone
is still writing; :func:`make_durable` fsyncs what was written so far without any lock of
the writer's; :func:`publish_part` gives a finished file its final name without replacing
anything; :func:`fsync_directory` makes that rename durable. What a crash leaves in a
``.part`` is finished by :mod:`qfa_ros.bag.recovery`. :func:`delete_finished_file` takes a
finished file out of its bag directory (retention) so that a kill at any instant leaves
the bag readable, and what it leaves half done is finished by the same recovery
(:func:`finish_deletion`).
"""

import errno
import fcntl
import os
import stat

from qfa_ros.model.safe_files import write_atomically

PART_SUFFIX = '.part'
METADATA_FILE = 'metadata.yaml'
"""A rosbag2 bag directory's metadata file."""
DELETION_SUFFIX = '.deleting'
"""``NAME.mcap.deleting`` beside ``NAME.mcap``: the file is being deleted (retention)."""


class RecorderError(OSError):
    """Writing or finishing an MCAP file failed; the ``.part`` file is left in place."""


class PartFile:
    """Unbuffered write-only file that the mcap ``Writer`` treats as its stream."""

    def __init__(self, path):
        self.path = path
        self.position = 0
        self._fd = None
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
        except OSError as error:
            raise os_error_with_context(error, 'cannot create MCAP file', path) from None
        # Held until the file is closed (or the process dies): a recovery leaves it alone.
        lock_exclusively(self._fd, wait=True)

    def write(self, data):
        view = memoryview(data)
        while view.nbytes:
            try:
                written = os.write(self._fd, view)
            except OSError as error:
                raise RecorderError(
                    error.errno, f'writing MCAP file failed: {error.strerror}', str(self.path)
                ) from error
            view = view[written:]
            self.position += written
        return len(data)

    def tell(self):
        return self.position

    def flush(self):
        """Do nothing: every write already went to the operating system."""

    def sync_and_close(self):
        try:
            os.fsync(self._fd)
        finally:
            self.close()

    def close(self):
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def __del__(self):
        # An abandoned writer must not leak its descriptor; the .part file stays as is.
        self.close()


def lock_exclusively(descriptor, wait):
    """
    Take an exclusive ``flock`` on ``descriptor``; return whether it is held.

    The lock is the writer's mark "in use": the kernel drops it when the descriptor is
    closed or the process dies, so a killed writer leaves no stale lock behind. With
    ``wait`` false, a lock someone else holds returns False at once. A file system without
    ``flock`` (some network file systems) returns True: nothing can be told there.
    """
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
    except BlockingIOError:
        return False
    except OSError as error:
        if error.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL):
            return True
        raise
    return True


def make_durable(paths):
    """
    Make what was written to ``paths`` so far durable (``fdatasync``, ``fsync`` for a directory).

    Each path is opened anew (no symlink followed), so the call needs no lock of the
    writer's and may run beside it; a path already gone (a ``.part`` renamed by
    ``finish()``, which synced it itself) is skipped.
    """
    for path in paths:
        try:
            descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        except FileNotFoundError:
            continue
        try:
            if stat.S_ISDIR(os.fstat(descriptor).st_mode):
                os.fsync(descriptor)
            else:
                os.fdatasync(descriptor)
        finally:
            os.close(descriptor)


def os_error_with_context(error, what, path):
    """Re-raise an ``OSError`` as its own subclass with a message that says what failed."""
    return type(error)(error.errno, f'{what}: {error.strerror}', str(path))


def publish_part(part_path, final_path, overwrite):
    """Give a finished ``.part`` file its final name atomically."""
    if overwrite:
        os.replace(part_path, final_path)
        return
    try:
        # link() refuses to replace an existing file, unlike rename().
        os.link(part_path, final_path)
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        if final_path.exists():
            raise FileExistsError(errno.EEXIST, 'file exists', str(final_path)) from None
        os.replace(part_path, final_path)  # filesystem without hard links
        return
    os.unlink(part_path)


def write_text_atomically(path, text):
    """
    Replace ``path`` with ``text`` atomically and durably (:func:`write_atomically`).

    ``text`` is a str, or a list of str written one after the other (a long document
    without a joined copy of it). A reader sees the old content or the new one, never a
    mix; after a crash one of the two is on disk.
    """
    parts = [text] if isinstance(text, str) else text
    try:
        write_atomically(path, lambda stream: stream.writelines(
            part.encode('utf-8') for part in parts))
    except OSError as error:
        raise os_error_with_context(error, f'cannot write {path.name}', path) from None


def delete_finished_file(directory_fd, name, unlist):
    """
    Delete the finished file ``name`` of a bag directory so that a kill leaves the bag whole.

    The order: (1) the empty marker ``NAME.deleting`` is created and the directory
    fsynced, so from here on the deletion is recorded on disk; (2) ``unlist()`` replaces
    ``metadata.yaml`` atomically by one without the file; (3) the file, then the marker,
    are unlinked. ``metadata.yaml`` therefore lists only
    files that exist at every instant (rosbag2 and rosbags open the bag, every listed file
    complete), and a kill after (1) leaves the marker, which makes the directory one that
    needs recovery (:func:`qfa_ros.bag.recovery.needs_recovery`); the recovery finishes
    the deletion (:func:`finish_deletion`) and lists what remains. Nothing is followed:
    the names are taken in ``directory_fd``, the marker opened with ``O_NOFOLLOW``.

    Parameters
    ----------
    directory_fd : int
        The bag directory, open (``O_DIRECTORY | O_NOFOLLOW``).
    name : str
        The finished file's name, e.g. ``NAME_3.mcap``.
    unlist : callable
        Rewrites ``metadata.yaml`` without ``name``, atomically and durably.

    Raises
    ------
    OSError
        The marker could not be made, or ``unlist`` failed: the file is still listed,
        or it is unlisted and its marker stays for a recovery to finish.
    """
    marker = name + DELETION_SUFFIX
    os.close(os.open(marker, os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644,
                     dir_fd=directory_fd))
    os.fsync(directory_fd)
    unlist()
    finish_deletion(directory_fd, marker)
    # No fsync here: were the two unlinks lost in a power cut, the marker and the unlisted
    # file are what (1) and (2) left, which a recovery finishes.


def finish_deletion(directory_fd, marker):
    """Unlink the file a deletion marker names, if still there, then the marker (no symlink)."""
    try:
        os.unlink(marker[:-len(DELETION_SUFFIX)], dir_fd=directory_fd)
    except FileNotFoundError:
        pass
    os.unlink(marker, dir_fd=directory_fd)
