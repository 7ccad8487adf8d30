"""
Files: read one someone else named (bounded, never echoed); replace one atomically.

Every file the package reads on a stranger's word (a trajectory CSV, the calibration
state) goes through :func:`read_regular_file`. It resolves symlinks first, opens without
blocking on a FIFO (``O_NONBLOCK``), takes regular files only, refuses the kernel's
pseudo file systems (``/proc``, ``/sys``, ``/dev``: their regular-looking files report
sizes that mean nothing) and reads at most ``max_bytes``. Its errors name the path and
the problem, never the content.

Every file the package replaces in place (the calibration state, bag metadata, fleet
results) goes through :func:`write_atomically`: a temporary file beside it, fsynced,
renamed over it, the directory fsynced, so a reader or a crash sees the old file or the
new one, never a mix.
"""

import os
from pathlib import Path
import stat

PSEUDO_FILE_SYSTEMS = (Path('/proc'), Path('/sys'), Path('/dev'))
"""Kernel file systems whose files are interfaces, not data: never read."""


class UntrustedFileError(ValueError):
    """The named file is not one the package reads; the message never quotes its content."""


def read_regular_file(path, max_bytes):
    """
    Return the bytes of the regular file ``path``, at most ``max_bytes`` of them.

    Parameters
    ----------
    path : str or os.PathLike
        The file; ``~`` is not expanded (the caller decides).
    max_bytes : int
        Largest size read [bytes]; a larger file is refused, not truncated.

    Raises
    ------
    UntrustedFileError
        Missing, unreadable, not a regular file, on a pseudo file system, or too large.
    """
    if max_bytes < 1:
        raise ValueError(f'max_bytes must be positive, got {max_bytes!r}')
    name = os.fspath(path)
    if not name:
        raise UntrustedFileError('no file named')
    try:
        resolved = Path(name).resolve()
    except (OSError, RuntimeError) as error:
        raise UntrustedFileError(f'{name}: cannot resolve: {_reason(error)}') from None
    if any(resolved == base or base in resolved.parents for base in PSEUDO_FILE_SYSTEMS):
        raise UntrustedFileError(f'{name}: files under /proc, /sys and /dev are not read')
    try:
        # O_NONBLOCK: opening a FIFO must not wait for a writer; it is refused below.
        descriptor = os.open(resolved, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as error:
        raise UntrustedFileError(f'{name}: cannot open: {_reason(error)}') from None
    try:
        info = os.fstat(descriptor)
        if not stat.S_ISREG(info.st_mode):
            raise UntrustedFileError(f'{name}: not a regular file')
        if info.st_size > max_bytes:
            raise UntrustedFileError(
                f'{name}: {info.st_size} bytes, more than the {max_bytes} read')
        chunks, total = [], 0
        # One byte past the limit tells a file that grew while it was read.
        while total <= max_bytes:
            chunk = os.read(descriptor, min(1 << 20, max_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
        if total > max_bytes:
            raise UntrustedFileError(f'{name}: grew past the {max_bytes} bytes read')
        return b''.join(chunks)
    except OSError as error:
        raise UntrustedFileError(f'{name}: cannot read: {_reason(error)}') from None
    finally:
        os.close(descriptor)


def fsync_directory(directory):
    """Make a rename in ``directory`` durable: fsync the directory entry itself."""
    descriptor = os.open(directory, os.O_RDONLY | getattr(os, 'O_DIRECTORY', 0))
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def write_atomically(path, write):
    """
    Replace ``path`` with what ``write(stream)`` writes, atomically and durably.

    The temporary file is ``.<name>.<pid>.tmp`` beside ``path`` (removed if anything
    fails); it is fsynced and renamed over ``path``, then the directory is fsynced.

    Parameters
    ----------
    path : pathlib.Path
        The file to replace (its directory must exist).
    write : callable
        Called with the temporary file open for binary writing.

    Raises
    ------
    OSError
        The file could not be written or renamed; ``path`` is unchanged.
    """
    temporary = path.with_name(f'.{path.name}.{os.getpid()}.tmp')
    try:
        with open(temporary, 'wb') as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, path)
    except BaseException:
        try:
            os.unlink(temporary)
        except OSError:
            pass
        raise
    fsync_directory(path.parent)


def _reason(error):
    """Return the system's words for ``error`` (never a file's content)."""
    return error.strerror or type(error).__name__
