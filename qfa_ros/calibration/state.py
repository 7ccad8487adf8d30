"""Persistable calibration state: references, applied words and the temperature ROM."""

from dataclasses import asdict, dataclass, field
import math

import numpy as np

from qfa_ros.calibration.tempfit import ThermalCompensation
from qfa_ros.model.triad import AXES


@dataclass
class AxisReference:
    """
    Reference gains of one axis (seed 1 §IV-A step 1).

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
        (:func:`qfa_ros.calibration.estimation.fit_plateau_steps`): right while its
        temperature compensation keeps the output scale flat. Without that compensation
        (offline studies) :func:`qfa_ros.calibration.estimation.reference_tc_schedule`
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
        data['format'] = 'qfa_ros.calibration/1'
        return data

    @classmethod
    def from_dict(cls, data):
        """Build a state from :meth:`to_dict` output, validating it."""
        if not isinstance(data, dict) or data.get('format') != 'qfa_ros.calibration/1':
            raise ValueError('calibration state: unknown or missing format tag')
        try:
            refs = [AxisReference(**r) for r in data['references']]
            state = cls(references=refs,
                        controller_gain=[float(g) for g in data['controller_gain']],
                        n_vref=[int(n) for n in data['n_vref']],
                        last_estimates=dict(data.get('last_estimates', {})),
                        captured_at_ns=int(data.get('captured_at_ns', 0)),
                        updated_at_ns=int(data.get('updated_at_ns', 0)),
                        temperature=dict(data.get('temperature', {})),
                        reference_tc_ppm=[float(v) for v in data.get('reference_tc_ppm', [])],
                        gyro_bias=[float(v) for v in data.get('gyro_bias', [])],
                        reference_settings=_settings_from(data.get('reference_settings', {})))
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f'calibration state: malformed ({error})') from error
        if len(refs) != len(AXES) or len(state.controller_gain) not in (0, len(AXES)) \
                or len(state.n_vref) not in (0, len(AXES)) \
                or len(state.reference_tc_ppm) not in (0, len(AXES)) \
                or len(state.gyro_bias) not in (0, len(AXES)):
            raise ValueError('calibration state: expected three axes')
        if not all(math.isfinite(v) for v in state.reference_tc_ppm + state.gyro_bias):
            raise ValueError('calibration state: non-finite reference_tc_ppm or gyro_bias')
        for value in [v for r in refs for v in (r.forward_slope, r.feedback_step)
                      if v is not None] + state.controller_gain:
            if not math.isfinite(value) or value == 0:
                raise ValueError('calibration state: non-finite or zero gain')
        return state

    def apply_to(self, triad):
        """Write the stored words and temperature ROM into ``triad``."""
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


def _settings_from(data):
    """Validate the stored reference settings: per kind a flat mapping of scalars."""
    if not isinstance(data, dict) or not set(data) <= {'forward', 'feedback'}:
        raise ValueError('reference_settings must map forward/feedback to settings')
    settings = {}
    for kind, values in data.items():
        if not isinstance(values, dict) or len(values) > 32 or not all(
                isinstance(k, str) and isinstance(v, (bool, int, float, str))
                and len(k) <= 64 and len(str(v)) <= 64 for k, v in values.items()):
            raise ValueError(f'reference_settings.{kind} must map names to scalars')
        settings[kind] = dict(values)
    return settings


def install_compensation(triad, temperature_state):
    """Load the temperature ROM of a calibration state into ``triad`` and switch it on."""
    compensation = ThermalCompensation.from_dict(temperature_state)
    triad.temperature_compensator = compensation
    triad.temperature_compensation = True
    return compensation
