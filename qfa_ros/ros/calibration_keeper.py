"""The node's calibration state: stored corrections, the compensation switch, the state file."""

import numpy as np

from qfa_ros.calibration.state import CalibrationState
from qfa_ros.model.triad import AXES
from qfa_ros.ros.state_store import StateFileError, StateStore


class CalibrationKeeper:
    """
    Keep the calibration state of the running sensor and persist it.

    The state is changed by a schedule (sensor thread) or a service (executor thread);
    the caller holds the node lock around every method.

    Parameters
    ----------
    triad
        The running model; its present words are the nominal ones.
    state_file
        Path of the persisted state, or '' for memory only.
    logger
        The node's logger.
    """

    def __init__(self, triad, state_file, logger):
        self.triad = triad
        self._logger = logger
        self._nominal_gains = [loop.controller.gain for loop in triad.axes]
        self._nominal_n_vref = [loop.n_vref for loop in triad.axes]
        self.store = StateStore(state_file)
        self.state = CalibrationState()
        self.compensation = True
        self.problem = None
        self.unsaved = False
        self.loaded = 'not loaded yet'
        """Where the state came from at start (:meth:`load`), for the start-up line."""

    @property
    def is_calibrated(self):
        """Return True when references exist and the stored corrections are applied."""
        return self.state.has_reference and self.compensation

    def load(self, fresh=False):
        """
        Restore the persisted state; a bad file is set aside and the sensor starts bare.

        Parameters
        ----------
        fresh
            Do not read the state file at all (``state.fresh``): start on the nominal words,
            uncompensated; the next save replaces the file.
        """
        store = self.store
        if store.path is None:
            self.loaded = 'fresh (state_file empty: kept in memory only)'
            return
        removed = store.remove_leftovers()
        if removed:
            self._logger.warning(
                f'removed {len(removed)} temporary state file(s) an interrupted save left: '
                + ', '.join(path.name for path in removed))
        if fresh:
            self.loaded = f'fresh (state.fresh: {store.path} not loaded)'
            return
        self.loaded = f'fresh (no state file at {store.path})'
        try:
            state, compensation = store.load()
        except StateFileError as error:
            where = f'kept as {error.kept_as}' if error.kept_as else 'left in place'
            self.problem = f'{error}; {where}; starting uncalibrated'
            self._logger.error(self.problem)
            return
        if state is None:
            return
        try:
            if compensation:
                state.apply_to(self.triad)
        except Exception as error:
            # Whatever a stored word makes the model raise: the start goes on, bare. The
            # model's message quotes the word (the file's content): only its kind is told.
            self.restore_nominal_words()
            kept = store.set_aside()
            where = f'kept as {kept}' if kept else 'could not be set aside'
            self.problem = (f'state file {store.path} holds words the sensor cannot take '
                            '(k(D(z)), N_VREF, the temperature ROM or the gyro bias out of '
                            f'range: {type(error).__name__}); {where}; starting uncalibrated')
            self._logger.error(self.problem)
            return
        self.state = state
        self.compensation = compensation
        self.loaded = f'loaded from {store.path}'

    def startup_summary(self):
        """Return what :meth:`load` left: the state's origin and the compensation switch."""
        state = self.state
        stored = [name for name, present in (
            ('references', state.has_reference),
            ('gain corrections', state.controller_gain or state.n_vref),
            ('temperature ROM', state.temperature), ('gyro bias', state.gyro_bias))
            if present]
        applied = self.compensation and any(name != 'references' for name in stored)
        return (f'calibration state {self.loaded}: compensation {"on" if applied else "off"} '
                f'({", ".join(stored) or "nothing"} stored)')

    def save(self):
        """Persist the calibration state; return a problem description or None."""
        try:
            self.store.save(self.state, self.compensation)
        except OSError as error:
            self.problem = f'state file not written ({error})'
            self.unsaved = True
            return self.problem
        self.problem = None
        self.unsaved = False
        return None

    def restore_nominal_words(self):
        """Write the nominal words back; temperature compensation and gyro correction off."""
        triad = self.triad
        for axis in range(len(AXES)):
            triad.set_controller_gain(axis, self._nominal_gains[axis])
            triad.set_n_vref(axis, self._nominal_n_vref[axis])
        triad.temperature_compensation = False
        triad.gyro_bias_correction = np.zeros(3)

    def set_compensation(self, on):
        """
        Apply (``on``) the stored corrections or restore the nominal words.

        The caller saves the state afterwards (:meth:`save`), outside the node lock.

        Returns
        -------
        ``(success, message)`` for a ``SetBool`` answer.
        """
        state = self.state
        if on and not (state.controller_gain or state.n_vref or state.temperature
                       or state.gyro_bias):
            return False, ('no stored corrections: call capture_reference, '
                           'self_calibrate, calibrate_temperature or calibrate_gyros first')
        try:
            if on:
                state.apply_to(self.triad)
            else:
                self.restore_nominal_words()
        except Exception as error:
            # A stored word the sensor refuses (a file loaded with the compensation off):
            # no mix of words is left, and the model's message, which quotes the word, is
            # not passed on.
            self.restore_nominal_words()
            self.compensation = False
            return False, ("bad calibration state: a stored word is out of the sensor's range "
                           f'({type(error).__name__}); nominal words restored')
        self.compensation = bool(on)
        words = ', '.join(f'{axis} k(D(z)) {loop.controller.gain:.6g} N_VREF {loop.n_vref}'
                          for axis, loop in zip(AXES, self.triad.axes))
        thermal = 'on' if self.triad.temperature_compensation else 'off'
        gyro = 'on' if np.any(self.triad.gyro_bias_correction) else 'off'
        applied = 'stored corrections applied' if on else 'nominal words restored'
        return True, (f'{applied}: {words}; temperature compensation {thermal}; gyro bias '
                      f'correction {gyro}')
