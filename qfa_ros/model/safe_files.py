"""
Files: read one someone else named (bounded, never echoed); replace one atomically.

Every file the package reads on a stranger's word (a trajectory CSV, the calibration
state) goes through :func:`read_regular_file`. It resolves symlinks once, then opens
the resolved path one component at a time with ``O_NOFOLLOW`` (a symlink swapped in
since is refused, not followed), without blocking on a FIFO (``O_NONBLOCK``), and
judges the opened descriptor itself: a regular file (``fstat``), not on one of the
kernel's pseudo file systems (``fstatfs`` magic: proc, sysfs, debugfs ...; their
regular-looking files are interfaces whose sizes mean nothing), at most ``max_bytes``.
What was checked is what is read. Its errors name the path as given and the rule,
never the resolved path or the content.

Every file the package replaces in place (the calibration state, bag metadata, fleet
results) goes through :func:`write_atomically`: a temporary file beside it, created
exclusively under an unpredictable name, fsynced, renamed over it, the directory
fsynced, so a reader or a crash sees the old file or the new one, never a mix.
"""

import ctypes
import os
from pathlib import Path
import secrets
import stat

PSEUDO_FILE_SYSTEMS = {
    0x9FA0: 'proc', 0x62656572: 'sysfs', 0x1CD1: 'devpts', 0x64626720: 'debugfs',
    0x74726163: 'tracefs', 0x73636673: 'securityfs', 0x0027E0EB: 'cgroup',
    0x63677270: 'cgroup2', 0x62656570: 'configfs', 0xCAFE4A11: 'bpf',
    0xDE5E81E4: 'efivarfs', 0x6165676C: 'pstore', 0x65735543: 'fusectl',
    0x42494E4D: 'binfmt_misc', 0xF97CFF8C: 'selinuxfs', 0x43415D53: 'smackfs',
    0x6E736673: 'nsfs', 0x50495045: 'pipefs', 0x534F434B: 'sockfs',
    0x09041934: 'anon_inode'}
"""Kernel file systems whose files are interfaces, not data, by ``statfs`` magic
(``linux/magic.h``): never read. devtmpfs reports tmpfs's magic; every file on it a
read could harm is a device node, refused as not a regular file."""

_LIBC = ctypes.CDLL(None, use_errno=True)
_STATFS_BYTES = 256
"""Room for ``struct statfs`` (120 bytes on 64-bit Linux); ``f_type`` is its first word."""


class UntrustedFileError(ValueError):
    """The named file is not one the package reads; the message never quotes its content."""


def file_system_type(descriptor):
    """Return the ``statfs`` magic number of the file system holding ``descriptor``."""
    buffer = ctypes.create_string_buffer(_STATFS_BYTES)
    if _LIBC.fstatfs(descriptor, buffer) != 0:
        code = ctypes.get_errno()
        raise OSError(code, os.strerror(code))
    # f_type is a C long (__fsword_t); the magic numbers are 32 bits.
    return ctypes.c_long.from_buffer(buffer).value & 0xFFFFFFFF


def _open_without_symlinks(resolved):
    """
    Open the absolute, symlink-free path ``resolved`` for reading, following no symlink.

    Each directory on the way is opened ``O_PATH | O_NOFOLLOW`` relative to the one
    before (search permission suffices, as for a plain open), the file itself
    ``O_NOFOLLOW | O_NONBLOCK``: a component swapped for a symlink since ``resolved``
    was computed fails with ELOOP or ENOTDIR instead of leading elsewhere.
    """
    parts = resolved.parts
    directory = os.open(parts[0], os.O_PATH | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        for part in parts[1:-1]:
            inner = os.open(part, os.O_PATH | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC,
                            dir_fd=directory)
            os.close(directory)
            directory = inner
        last = parts[-1] if len(parts) > 1 else '.'
        # O_NONBLOCK: opening a FIFO must not wait for a writer; it is refused below.
        return os.open(last, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW | os.O_NOCTTY
                       | os.O_CLOEXEC, dir_fd=directory)
    finally:
        os.close(directory)


def _open_regular(name):
    """
    Return ``(descriptor, stat)`` of the regular file ``name``, opened non-blocking.

    Raises
    ------
    UntrustedFileError
        As :func:`read_regular_file` says, the size aside.
    """
    if not name:
        raise UntrustedFileError('no file named')
    try:
        resolved = Path(name).resolve()
    except (OSError, RuntimeError) as error:
        raise UntrustedFileError(f'{name}: cannot resolve: {system_reason(error)}') from None
    try:
        descriptor = _open_without_symlinks(resolved)
    except OSError as error:
        raise UntrustedFileError(f'{name}: cannot open: {system_reason(error)}') from None
    try:
        info = os.fstat(descriptor)
        kind = PSEUDO_FILE_SYSTEMS.get(file_system_type(descriptor))
        if kind:
            raise UntrustedFileError(f'{name}: on the kernel file system {kind}: its files '
                                     'are interfaces, not data, and are not read')
        if not stat.S_ISREG(info.st_mode):
            raise UntrustedFileError(f'{name}: not a regular file')
    except OSError as error:
        os.close(descriptor)
        raise UntrustedFileError(f'{name}: cannot read: {system_reason(error)}') from None
    except BaseException:
        os.close(descriptor)
        raise
    return descriptor, info


def open_regular_file(path):
    """
    Open the regular file ``path`` for reading (binary), to be read as a stream.

    The checks of :func:`read_regular_file` but the size: for files read a record at a
    time (a bag's MCAP files). A FIFO or a device would block or never end: refused
    without a byte read.

    Raises
    ------
    UntrustedFileError
        As :func:`read_regular_file`; the message names ``path``.
    """
    descriptor, _ = _open_regular(os.fspath(path))
    os.set_blocking(descriptor, True)
    return os.fdopen(descriptor, 'rb')


def read_regular_file(path, max_bytes):
    """
    Return the bytes of the regular file ``path``, at most ``max_bytes`` of them.

    Parameters
    ----------
    path : str or os.PathLike
        The file; ``~`` is not expanded (the caller decides). Symlinks are resolved once,
        then nothing on the resolved path may be a symlink when it is opened.
    max_bytes : int
        Largest size read [bytes]; a larger file is refused, not truncated.

    Raises
    ------
    UntrustedFileError
        Missing, unreadable, changed into a symlink while opened, not a regular file, on
        a pseudo file system, or too large. The message names ``path`` as given.
    """
    if max_bytes < 1:
        raise ValueError(f'max_bytes must be positive, got {max_bytes!r}')
    name = os.fspath(path)
    descriptor, info = _open_regular(name)
    try:
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
        raise UntrustedFileError(f'{name}: cannot read: {system_reason(error)}') from None
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

    The temporary file ``.<name>.<random>.tmp`` beside ``path`` is created exclusively
    (``O_CREAT | O_EXCL``: never an existing file or a planted symlink; 64 random bits
    in its name, so none can be planted in advance) and removed if anything fails; it is
    fsynced and renamed over ``path``, then the directory is fsynced.

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
    temporary, descriptor = _create_temporary(path)
    try:
        with open(descriptor, 'wb') as stream:
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


TEMPORARY_ATTEMPTS = 16
"""Names tried for a temporary file before giving up (a clash of 64 random bits)."""


def _create_temporary(path):
    """Create ``.<name>.<16 hex digits>.tmp`` beside ``path`` exclusively; return (path, fd)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    for attempt in range(TEMPORARY_ATTEMPTS):
        temporary = path.with_name(f'.{path.name}.{secrets.token_hex(8)}.tmp')
        try:
            return temporary, os.open(temporary, flags, 0o666)
        except FileExistsError:
            if attempt == TEMPORARY_ATTEMPTS - 1:
                raise


def system_reason(error):
    """Return the system's words for ``error`` (never a file's content nor a path)."""
    if isinstance(error, RuntimeError):
        return 'symlink loop'  # pathlib's resolve(); its message names the path
    return error.strerror or type(error).__name__
