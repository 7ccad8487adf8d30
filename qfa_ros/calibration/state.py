"""Persistable calibration state: references, applied words and the temperature ROM."""

from dataclasses import asdict, dataclass, field
import math

import numpy as np

from qfa_ros.calibration.thermal_compensation import ThermalCompensation
from qfa_ros.model.triad import AXES


@dataclass
class AxisReference:
    """
    Reference gains of one axis (Ran et al. 2019, §IV-A step 1).

    Attributes
    ----------
    forward_slope : float or None
        Eq-forward-gain k_pre-eq0: dN_out/dN_FPGA in open loop, including k(D(z)).
    feedback_step : float or None
        N_out-on - N_out-off [count] (eq. 27), i.e. -I_ref / (k_VI0 k_DA0).
    temperature : float or None
        On-board temperature reading when the feedback reference was captured [degC].
    """

    forward_slope: float = None
    feedback_step: float = None
    temperature: float = None


REFERENCE_FIELDS = frozenset(('forward_slope', 'feedback_step', 'temperature'))
"""The fields of one stored :class:`AxisReference`."""


@dataclass
class CalibrationState:
    """
    Persistable calibration state: references and the words currently applied.

    Attributes
    ----------
    references : list of AxisReference
        One per axis.
    controller_gain : list of float
        k(D(z)) per axis as last applied.
    n_vref : list of int
        N_VREF per axis as last applied.
    last_estimates : dict
        Last estimate per schedule kind: ``{'forward': [ppm x, y, z], ...}``.
    captured_at_ns, updated_at_ns : int
        Sensor times [ns].
    temperature : dict
        Temperature-compensation coefficients (filled by the temperature schedule).
    reference_tc_ppm : list of float
        Temperature coefficient of the I_ref step per axis [ppm/degC], relative to the
        output scale in service; empty until measured. The feedback schedule's
        temperature correction uses it. The temperature calibration (the node's
        ``calibrate_temperature``) measures the step in counts at every chamber plateau
        (:func:`qfa_ros.calibration.reference_tc.fit_plateau_steps`): right while its
        temperature compensation keeps the output scale flat. Without that compensation
        (offline studies) :func:`qfa_ros.calibration.reference_tc.reference_tc_schedule`
        measures the step against gravity, which also carries the scale's own curve.
    gyro_bias : list of float
        Gyro bias correction per axis [rad/s]
        (:func:`qfa_ros.calibration.gyro_bias.gyro_bias_schedule`); empty until measured.
    reference_settings : dict
        The schedule settings each reference was captured with, ``{'forward': {...},
        'feedback': {...}}`` (the settings that change what an estimate expects, and the
        loop and sample rates; :func:`qfa_ros.calibration.estimation.reference_settings`).
        An estimate with other settings is refused. Empty in a state file written before
        they were stored: its references cannot be compared and must be captured again.
    """

    references: list = field(default_factory=lambda: [AxisReference() for _ in AXES])
    controller_gain: list = field(default_factory=list)
    n_vref: list = field(default_factory=list)
    last_estimates: dict = field(default_factory=dict)
    captured_at_ns: int = 0
    updated_at_ns: int = 0
    temperature: dict = field(default_factory=dict)
    reference_tc_ppm: list = field(default_factory=list)
    gyro_bias: list = field(default_factory=list)
    reference_settings: dict = field(default_factory=dict)

    @property
    def has_reference(self):
        """Return True when both references exist on every axis."""
        return all(r.forward_slope is not None and r.feedback_step is not None
                   for r in self.references)

    def to_dict(self):
        """Return a JSON-serializable dict."""
        data = asdict(self)
        data['format'] = STATE_FORMAT
        return data

    @classmethod
    def from_dict(cls, data):
        """
        Build a state from :meth:`to_dict` output, validating it.

        Raises
        ------
        StateFormatError
            ``data`` is not a calibration state. The message names the field and the rule,
            never a value: the data comes from a file.
        """
        try:
            return cls._from_dict(data)
        except StateFormatError:
            raise
        except RecursionError:
            raise StateFormatError('calibration state: nested too deeply') from None
        except Exception as error:
            # Whatever else a hostile file triggers; its message may quote the file.
            raise StateFormatError(
                f'calibration state: malformed ({type(error).__name__})') from None

    @classmethod
    def _from_dict(cls, data):
        if not isinstance(data, dict) or data.get('format') != STATE_FORMAT:
            raise StateFormatError('calibration state: unknown or missing format tag')
        references = data.get('references')
        if not isinstance(references, list) or len(references) != len(AXES):
            raise StateFormatError('calibration state: references must hold three axes')
        refs = [_reference(r) for r in references]
        for key in ('controller_gain', 'n_vref'):
            if key not in data:
                raise StateFormatError(f'calibration state: {key} missing')
        state = cls(references=refs,
                    controller_gain=_numbers(data, 'controller_gain'),
                    n_vref=[_integer(v, 'n_vref') for v in _axes_list(data, 'n_vref')],
                    last_estimates=_estimates(data.get('last_estimates', {})),
                    captured_at_ns=_integer(data.get('captured_at_ns', 0), 'captured_at_ns'),
                    updated_at_ns=_integer(data.get('updated_at_ns', 0), 'updated_at_ns'),
                    temperature=_temperature(data.get('temperature', {})),
                    reference_tc_ppm=_numbers(data, 'reference_tc_ppm'),
                    gyro_bias=_numbers(data, 'gyro_bias'),
                    reference_settings=_settings_from(data.get('reference_settings', {})))
        for value in [v for r in refs for v in (r.forward_slope, r.feedback_step)
                      if v is not None] + state.controller_gain:
            if value == 0:
                raise StateFormatError('calibration state: zero gain')
        return state

    def apply_to(self, triad):
        """
        Write the stored words, temperature ROM and gyro bias correction into ``triad``.

        Raises
        ------
        ValueError
            The gyro bias correction is not three numbers within the gyro range
            ``|b| <= range`` [rad/s] (a bias beyond it could not have been measured);
            nothing is written. The message quotes no value (they come from a file).
        """
        if self.gyro_bias:
            bias = np.array(self.gyro_bias, dtype=float)
            limit = math.inf if triad.config.gyro is None else triad.config.gyro.range
            if bias.shape != (len(AXES),) or not np.all(np.abs(bias) <= limit):
                raise ValueError('gyro_bias must be three numbers within the gyro range '
                                 f'+-{limit:g} rad/s')
        for axis in range(len(AXES)):
            if self.controller_gain:
                triad.set_controller_gain(axis, self.controller_gain[axis])
            if self.n_vref:
                triad.set_n_vref(axis, self.n_vref[axis])
        if self.temperature:
            install_compensation(triad, self.temperature)
        if self.gyro_bias:
            triad.gyro_bias_correction = np.array(self.gyro_bias, dtype=float)

    def reference_readings_c(self):
        """Return the on-board temperature reading of each feedback reference [degC]."""
        return [r.temperature for r in self.references]

    def set_reference_reading(self, axis, reading_c):
        """Store the on-board temperature reading [degC] of the feedback reference."""
        self.references[axis].temperature = reading_c

    def record_words(self, port):
        """Store the gain and reference words now in the sensor behind ``port``, and when."""
        self.controller_gain = [port.controller_gain(axis) for axis in range(port.n_axes)]
        self.n_vref = [port.n_vref(axis) for axis in range(port.n_axes)]
        self.updated_at_ns = port.sensor_time_ns()


class StateFormatError(ValueError):
    """Not a calibration state; the message names the field and the rule, never a value."""


STATE_FORMAT = 'qfa_ros.calibration/1'
"""Format tag of a persisted calibration state."""
LARGEST_INTEGER = 2 ** 63 - 1
"""Largest magnitude of an integer field (words, sensor times in ns)."""
ESTIMATE_KINDS = ('forward', 'feedback')


def _number(value, field):
    """Return ``value`` as a finite float; StateFormatError naming ``field`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not -1e308 < value < 1e308:
        raise StateFormatError(f'calibration state: {field} must hold finite numbers')
    return float(value)


def _integer(value, field):
    """Return ``value`` as an int of at most 63 bits (a whole float is taken too)."""
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) \
            or abs(value) > LARGEST_INTEGER:
        raise StateFormatError(f'calibration state: {field} must hold integers of at most '
                               '63 bits')
    return value


def _axes_list(data, key):
    """Return ``data[key]`` (default empty): a list of nothing or one entry per axis."""
    values = data.get(key, [])
    if not isinstance(values, list) or len(values) not in (0, len(AXES)):
        raise StateFormatError(f'calibration state: {key} must be empty or hold three axes')
    return values


def _numbers(data, key):
    return [_number(v, key) for v in _axes_list(data, key)]


def _reference(record):
    """Return the :class:`AxisReference` of one stored axis."""
    if not isinstance(record, dict) or not set(record) <= REFERENCE_FIELDS:
        raise StateFormatError('calibration state: each reference must map '
                               f'{", ".join(sorted(REFERENCE_FIELDS))} to numbers or null')
    return AxisReference(**{key: None if value is None else _number(value, f'references.{key}')
                            for key, value in record.items()})


def _estimates(data):
    """Validate the last estimates: per kind three numbers [ppm]."""
    if not isinstance(data, dict) or not set(data) <= set(ESTIMATE_KINDS):
        raise StateFormatError('calibration state: last_estimates must map forward/feedback '
                               'to three numbers')
    estimates = {}
    for kind, values in data.items():
        if not isinstance(values, list) or len(values) != len(AXES):
            raise StateFormatError(f'calibration state: last_estimates.{kind} must hold '
                                   'three numbers')
        estimates[kind] = [_number(v, f'last_estimates.{kind}') for v in values]
    return estimates


def _temperature(data):
    """Validate the temperature ROM record by building it (an empty one: none stored)."""
    if not isinstance(data, dict):
        raise StateFormatError('calibration state: temperature must be a record')
    if data:
        try:
            ThermalCompensation.from_dict(data)
        except Exception as error:
            raise StateFormatError(f'calibration state: temperature is not a temperature '
                                   f'compensation record ({type(error).__name__})') from None
    return dict(data)


def _settings_from(data):
    """Validate the stored reference settings: per kind a flat mapping of scalars."""
    if not isinstance(data, dict) or not set(data) <= set(ESTIMATE_KINDS):
        raise StateFormatError('calibration state: reference_settings must map '
                               'forward/feedback to settings')
    settings = {}
    for kind, values in data.items():
        if not isinstance(values, dict) or len(values) > 32 or not all(
                isinstance(k, str) and isinstance(v, (bool, int, float, str))
                and len(k) <= 64 and len(str(v)) <= 64 for k, v in values.items()):
            raise StateFormatError(f'calibration state: reference_settings.{kind} must map '
                                   'names to scalars')
        settings[kind] = dict(values)
    return settings


def install_compensation(triad, temperature_state):
    """Load the temperature ROM of a calibration state into ``triad`` and switch it on."""
    compensation = ThermalCompensation.from_dict(temperature_state)
    triad.temperature_compensator = compensation
    triad.temperature_compensation = True
    return compensation
