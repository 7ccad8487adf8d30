"""What a run of a :class:`~qfa_ros.model.triad.QfaTriad` returns: the decimated output."""

from dataclasses import dataclass

import numpy as np


@dataclass
class TriadOutput:
    """
    Decimated output of a run.

    Attributes
    ----------
    stamps_ns : int64[n]
        Sample instants, sensor time [ns] (end of each averaging block).
    accel : float64[n, 3]
        Specific force through the nominal scale factor [m/s^2].
    counts : float64[n, 3]
        Mean raw output word per sample [count].
    flags : int8[n, 3]
        Saturation bits (``FLAG_*``).
    valid : bool[n, 3]
        False while the axis is open loop or settling after re-closing.
    truth : float64[n, 3]
        True specific force averaged over each sample [m/s^2].
    temperature : float64[n]
        Sensor body temperature [degC].
    v_temp : float64[n]
        On-board temperature-sensor reading [V] (NaN without a thermal model).
    gyro : float64[n, 3]
        Gyro triad output [rad/s] (NaN without gyros).
    rate_truth : float64[n, 3]
        True angular rate w.r.t. inertial space, body axes, averaged over each
        sample [rad/s].
    """

    stamps_ns: np.ndarray
    accel: np.ndarray
    counts: np.ndarray
    flags: np.ndarray
    valid: np.ndarray
    truth: np.ndarray
    temperature: np.ndarray
    v_temp: np.ndarray
    gyro: np.ndarray
    rate_truth: np.ndarray

    FIELDS = ('stamps_ns', 'accel', 'counts', 'flags', 'valid', 'truth', 'temperature',
              'v_temp', 'gyro', 'rate_truth')

    @property
    def saturated(self):
        """Return bool[n, 3]: any saturation bit set."""
        return self.flags != 0


def concatenate(outputs):
    """Concatenate :class:`TriadOutput` chunks in time order."""
    if not outputs:
        empty = np.empty((0, 3))
        return TriadOutput(np.empty(0, np.int64), empty, empty.copy(),
                           np.empty((0, 3), np.int8), np.empty((0, 3), bool), empty.copy(),
                           np.empty(0), np.empty(0), empty.copy(), empty.copy())
    return TriadOutput(*(np.concatenate([getattr(o, f) for o in outputs])
                         for f in TriadOutput.FIELDS))
