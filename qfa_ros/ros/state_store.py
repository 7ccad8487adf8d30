"""Persist the calibration state atomically; set a corrupt file aside instead of losing it."""

from contextlib import suppress
import datetime
import glob
import json
import os
from pathlib import Path

from qfa_ros.calibration.state import CalibrationState, StateFormatError
from qfa_ros.model.safe_files import (
    fsync_directory,
    read_regular_file,
    UntrustedFileError,
    write_atomically,
)

MAX_STATE_BYTES = 1 << 20
"""Largest state file read [bytes]; a real one is a few kB."""

COMPENSATION_KEY = 'compensation_enabled'
"""Extra key of the state file: whether the stored corrections are applied (node-level)."""


def corrupt_reason(error):
    """Return why a state file's text is no state, in words that never quote the file."""
    if isinstance(error, json.JSONDecodeError):
        # Its msg is the parser's rule ("Expecting value"), its doc the file: only the former.
        return f'not JSON ({error.msg} at line {error.lineno} column {error.colno})'
    if isinstance(error, StateFormatError):
        return str(error)
    if isinstance(error, RecursionError):
        return 'not JSON this parser takes (nested too deeply)'
    return f'not a calibration state ({type(error).__name__})'


class StateFileError(Exception):
    """The state file exists but cannot be used; ``kept_as`` names where it was set aside."""

    def __init__(self, message, kept_as=None):
        super().__init__(message)
        self.kept_as = kept_as


class StateStore:
    """
    Load and save a :class:`CalibrationState` as JSON at ``path``.

    Saving writes a temporary file in the same directory, fsyncs it, renames it over
    the old file and fsyncs the directory, so the file is always either the old or the
    new state, also across a power cut. A file that cannot be parsed is renamed to
    ``<name>.corrupt-<UTC time>`` so that the next save never overwrites it silently.

    Parameters
    ----------
    path
        State file; None or empty keeps the state in memory only.
    """

    def __init__(self, path):
        self.path = Path(os.path.expanduser(path)) if path else None

    def load(self):
        """
        Return ``(state, compensation_enabled)``; ``(None, True)`` when there is no file.

        Raises
        ------
        StateFileError
            The file is unreadable or corrupt (it is set aside when it can be renamed).
        """
        if self.path is None or not self.path.exists():
            return None, True
        try:
            text = read_regular_file(self.path, MAX_STATE_BYTES).decode('utf-8')
        except UntrustedFileError as error:
            # Not a state file at all (a FIFO, a device, too large, unreadable): it is
            # left where it is, untouched.
            raise StateFileError(f'state file {error}') from None
        except UnicodeDecodeError:
            raise StateFileError(f'state file {self.path} corrupt: not UTF-8 text',
                                 self.set_aside()) from None
        try:
            data = json.loads(text)
            state = CalibrationState.from_dict(data)
            compensation = data.get(COMPENSATION_KEY, True)
            if not isinstance(compensation, bool):
                raise StateFormatError(f'{COMPENSATION_KEY} must be true or false')
        except Exception as error:
            # Any malformed file is set aside, never the end of the start; the reason
            # never quotes it (a parser's message may).
            raise StateFileError(f'state file {self.path} corrupt: {corrupt_reason(error)}',
                                 self.set_aside()) from None
        return state, compensation

    def remove_leftovers(self):
        """
        Remove the temporary files an interrupted :meth:`save` left; return their paths.

        A save killed between creating its temporary file and the rename leaves
        ``.<name>.*.tmp`` beside the state file; the state file itself is whole either way.
        """
        if self.path is None or not self.path.parent.is_dir():
            return []
        removed = []
        for leftover in sorted(self.path.parent.glob(f'.{glob.escape(self.path.name)}.*.tmp')):
            with suppress(OSError):
                if leftover.is_file() and not leftover.is_symlink():
                    leftover.unlink()
                    removed.append(leftover)
        return removed

    def set_aside(self):
        """Rename the state file to ``<name>.corrupt-<UTC time>``; return the new path or None."""
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y%m%dT%H%M%S.%fZ')
        target = self.path.with_name(f'{self.path.name}.corrupt-{stamp}')
        try:
            os.rename(self.path, target)
        except OSError:
            return None
        # Best effort: the file is in place either way.
        with suppress(OSError):
            fsync_directory(self.path.parent)
        return target

    def save(self, state, compensation_enabled):
        """
        Write ``state`` atomically; return the path, or None without a state file.

        Raises
        ------
        OSError
            The directory is missing or not writable, or the disk is full.
        """
        if self.path is None:
            return None
        data = state.to_dict()
        data[COMPENSATION_KEY] = bool(compensation_enabled)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(data, indent=2, sort_keys=True) + '\n'
        write_atomically(self.path, lambda stream: stream.write(text.encode('utf-8')))
        return self.path
