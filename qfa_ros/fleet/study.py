"""
A fleet study file: what to simulate, validated before any work starts.

A study is YAML with these keys (every one optional but ``units``)::

    name: monthly-improved        # label in summaries and figures
    units: 2000                   # units drawn, unit i from seed (seed, i)
    seed: 0
    batch_units: 10               # units per Dask task
    schedule:
      name: improved              # paper | improved
      forward: {points: 10}       # overrides of ForwardSettings fields
      feedback: {cycles: 16}      # overrides of FeedbackSettings fields
    horizon_years: 1.0
    calibration_interval_days: 30.0
    aging:                        # per-unit linear aging rates [ppm/year]
      distribution: normal        # normal: N(0, value) | uniform: U(-value, +value)
      forward_ppm_per_year: 100.0
      feedback_ppm_per_year: 100.0
      torquer_ppm_per_year: 0.0   # k_t (magnet, coil): unobservable by the schedule
    environment:
      room_c: 22.0                # mean room temperature
      seasonal_amplitude_c: 3.0   # annual sinusoid, phase drawn per unit
      wander_c: 1.0               # room wander amplitude (12 h correlation)
      error_profile: paper        # paper | ideal: Ran et al.'s temperature coefficients
      magnet_tc_ppm: null         # override the profile's k_t temperature coefficient
      component_tcs: type         # type: every unit the profile's coefficients; drawn:
                                  # each unit its own I_ref and forward-chain ones
                                  # (qfa_ros.model.drawn_unit spreads)

A Monte Carlo of one self-calibration after drifts of a given size is the study with one
calibration a year after the reference and uniform aging of that size (the scenarios of
``bench/estimation_accuracy.py``).

``kind: temperature`` is the other procedure: every unit (drawn by :mod:`qfa_ros.model.drawn_unit`
from a seed the study derives, reported in the rows) runs the temperature calibration
(``~/calibrate_temperature``'s schedule) and is verified in eight attitudes at constant
chamber temperatures off its 10 degC grid (:mod:`qfa_ros.calibration.verification`);
``schedule``, ``aging`` and the calendar keys are unused. Its keys::

    kind: temperature
    temperature: {period_s: 3600.0}      # overrides of TemperatureSettings fields
    sensor:                              # the sensor the procedure runs on
      sensor_tau_s: 300.0                # body time constant [s]
      loop_rate_hz: 10000.0
      sample_rate_hz: 1000.0
      crossover_hz: 300.0
    verification:
      temperatures_c: [-27.0, 8.0, 41.0, 64.0]
      average_s: 1.5
"""

from dataclasses import asdict, dataclass, field, fields, replace
import hashlib
import json
import math

import yaml

from qfa_ros.calibration.estimation import FeedbackSettings, ForwardSettings
from qfa_ros.calibration.experiments import IMPROVED_SCHEDULE, PAPER_SCHEDULE
from qfa_ros.calibration.temperature import TemperatureSettings
from qfa_ros.model.checks import is_finite
from qfa_ros.model.error_profiles import ERROR_PROFILES
from qfa_ros.model.safe_files import read_regular_file, UntrustedFileError

SCHEDULES = {'paper': PAPER_SCHEDULE, 'improved': IMPROVED_SCHEDULE}
AGING_DISTRIBUTIONS = ('normal', 'uniform')
COMPONENT_TCS = ('type', 'drawn')
KINDS = ('self_calibration', 'temperature')
SENSOR_KEYS = {'sensor_tau_s': (1.0, 1e5), 'loop_rate_hz': (100.0, 1e5),
               'sample_rate_hz': (1.0, 1e4), 'crossover_hz': (1.0, 1e4)}
VERIFICATION_KEYS = ('temperatures_c', 'average_s')
SPANS_PPM = {'paper': 200.0, 'year': 100.0, 'large': 1000.0}
"""Drift spans of the one-calibration Monte Carlo [ppm]: the paper's +-200 ppm; one year
of aging (+-100 ppm/year, the navigation-grade QFA scale-factor stability class);
+-1000 ppm."""
TORQUER_SPAN_PPM = 50.0
"""Span of the k_t drift in the Monte Carlo with k_t drift [ppm]."""
MAX_STUDY_BYTES = 1 << 20
"""Largest study file read [bytes] (the shipped ones are under 2 KiB)."""
MAX_UNITS = 1_000_000
MAX_HORIZON_YEARS = 30.0


class StudyError(ValueError):
    """The study file is invalid; the message names the key."""


def _number(where, value, low, high, integer=False, allow_low=True):
    if not is_finite(value, bool_ok=False, types=(int, float)) \
            or (integer and int(value) != value):
        kind = 'an integer' if integer else 'a finite number'
        raise StudyError(f'{where} must be {kind}, got {value!r}')
    if value < low or value > high or (value == low and not allow_low):
        bound = '>=' if allow_low else '>'
        raise StudyError(f'{where} must be {bound} {low:g} and <= {high:g}, got {value!r}')
    return int(value) if integer else float(value)


def _choice(where, value, allowed):
    if value not in allowed:
        raise StudyError(f'{where} must be one of {", ".join(allowed)}, got {value!r}')
    return value


def _mapping(where, value, known):
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise StudyError(f'{where} must be a mapping, got {type(value).__name__}')
    unknown = sorted(set(value) - set(known))
    if unknown:
        raise StudyError(f'unknown key {where + "." if where else ""}{unknown[0]} '
                         f'(known: {", ".join(sorted(known))})')
    return value


@dataclass(frozen=True)
class Aging:
    """
    Spreads of the per-unit linear aging rates [ppm/year].

    ``distribution`` 'normal' draws each rate from N(0, value), 'uniform' from
    U(-value, +value).
    """

    forward_ppm_per_year: float = 100.0
    feedback_ppm_per_year: float = 100.0
    torquer_ppm_per_year: float = 0.0
    distribution: str = 'normal'

    def draw(self, rng, value):
        """Draw one rate of spread ``value`` [ppm/year] from ``rng``."""
        if self.distribution == 'uniform':
            return rng.uniform(-value, value)
        return rng.normal(0.0, value)


@dataclass(frozen=True)
class Environment:
    """Room temperature model [degC] and the paper's error sources."""

    room_c: float = 22.0
    seasonal_amplitude_c: float = 3.0
    wander_c: float = 1.0
    error_profile: str = 'paper'
    magnet_tc_ppm: float = None
    component_tcs: str = 'type'


@dataclass(frozen=True)
class Study:
    """
    One fleet study (see the module docstring for the file format).

    Attributes
    ----------
    units : int
        Number of units; unit ``i`` draws its randomness from ``SeedSequence([seed, i])``.
    schedule : str
        ``'paper'`` or ``'improved'`` (see :mod:`qfa_ros.calibration.experiments`).
    forward, feedback : dict
        Overrides of :class:`ForwardSettings` / :class:`FeedbackSettings` fields.
    horizon_years, calibration_interval_days : float
        Study length and time between self-calibrations.
    """

    units: int
    name: str = 'study'
    seed: int = 0
    batch_units: int = 10
    schedule: str = 'improved'
    forward: dict = field(default_factory=dict)
    feedback: dict = field(default_factory=dict)
    horizon_years: float = 1.0
    calibration_interval_days: float = 30.0
    aging: Aging = field(default_factory=Aging)
    environment: Environment = field(default_factory=Environment)
    kind: str = 'self_calibration'
    temperature: dict = field(default_factory=dict)
    sensor: dict = field(default_factory=dict)
    verification: dict = field(default_factory=dict)

    @property
    def calibrations(self):
        """Return the number of self-calibrations within the horizon (1: temperature)."""
        if self.kind == 'temperature':
            return 1
        return int(math.floor(self.horizon_years * 365.25 / self.calibration_interval_days
                              + 1e-9))

    @property
    def batches(self):
        """Return the unit index ranges of the Dask tasks, in order."""
        return [(start, min(start + self.batch_units, self.units))
                for start in range(0, self.units, self.batch_units)]

    def schedule_settings(self):
        """Return the :class:`~qfa_ros.calibration.experiments.Schedule` with overrides."""
        base = SCHEDULES[self.schedule]
        forward = replace(base.forward, **self.forward)
        feedback = replace(base.feedback, **self.feedback)
        capture = replace(base.reference_feedback, **self.feedback)
        return replace(base, forward=forward, feedback=feedback, capture_feedback=capture)

    def temperature_settings(self):
        """Return the :class:`TemperatureSettings` of a temperature study."""
        return TemperatureSettings(**self.temperature)

    def to_dict(self):
        """Return the study as plain data (the resumable run's identity)."""
        return asdict(self)

    def digest(self):
        """Return a short hash of everything that changes the results."""
        data = self.to_dict()
        data.pop('batch_units')
        data.pop('name')
        text = json.dumps(data, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @classmethod
    def from_dict(cls, data):
        """Validate ``data`` (the parsed study file); raise :class:`StudyError` naming a key."""
        data = _mapping('', data, {f.name for f in fields(cls)})
        if 'units' not in data:
            raise StudyError('units is required (how many units to simulate)')
        schedule = data.get('schedule', 'improved')
        overrides = {}
        if isinstance(schedule, dict):
            schedule = _mapping('schedule', schedule, {'name', 'forward', 'feedback'})
            for key, settings in (('forward', ForwardSettings), ('feedback', FeedbackSettings)):
                overrides[key] = dict(_mapping(f'schedule.{key}', schedule.get(key),
                                               {f.name for f in fields(settings)}))
            schedule = schedule.get('name', 'improved')
        _choice('schedule.name', schedule, SCHEDULES)
        aging = _mapping('aging', data.get('aging'), {f.name for f in fields(Aging)})
        environment = _mapping('environment', data.get('environment'),
                               {f.name for f in fields(Environment)})
        name = data.get('name', 'study')
        if not isinstance(name, str) or not name:
            raise StudyError(f'name must be a non-empty string, got {name!r}')
        _choice('aging.distribution', aging.get('distribution', 'normal'), AGING_DISTRIBUTIONS)
        _choice('environment.component_tcs', environment.get('component_tcs', 'type'),
                COMPONENT_TCS)
        _choice('environment.error_profile', environment.get('error_profile', 'paper'),
                ERROR_PROFILES)
        study = cls(
            units=_number('units', data['units'], 1, MAX_UNITS, integer=True),
            name=name,
            seed=_number('seed', data.get('seed', 0), 0, 2 ** 63 - 1, integer=True),
            batch_units=_number('batch_units', data.get('batch_units', 10), 1, 10000,
                                integer=True),
            schedule=schedule,
            forward=overrides.get('forward', {}),
            feedback=overrides.get('feedback', {}),
            horizon_years=_number('horizon_years', data.get('horizon_years', 1.0), 0.0,
                                  MAX_HORIZON_YEARS, allow_low=False),
            calibration_interval_days=_number(
                'calibration_interval_days', data.get('calibration_interval_days', 30.0),
                0.0, 3650.0, allow_low=False),
            aging=Aging(**{k: (v if k == 'distribution' else _number(f'aging.{k}', v, 0.0, 1e5))
                           for k, v in aging.items()}),
            environment=Environment(**{
                k: (v if k in ('error_profile', 'component_tcs')
                    or (k == 'magnet_tc_ppm' and v is None)
                    else _number(f'environment.{k}', v,
                                 -1e3 if k in ('room_c', 'magnet_tc_ppm') else 0.0, 1e3))
                for k, v in environment.items()}))
        kind = _choice('kind', data.get('kind', 'self_calibration'), KINDS)
        temperature = dict(_mapping('temperature', data.get('temperature'),
                                    {f.name for f in fields(TemperatureSettings)}))
        sensor = {k: _number(f'sensor.{k}', v, *SENSOR_KEYS[k], allow_low=True)
                  for k, v in _mapping('sensor', data.get('sensor'), SENSOR_KEYS).items()}
        verification = dict(_mapping('verification', data.get('verification'),
                                     VERIFICATION_KEYS))
        if 'temperatures_c' in verification:
            temps = verification['temperatures_c']
            if not isinstance(temps, list) or not 2 <= len(temps) <= 50:
                raise StudyError('verification.temperatures_c must be a list of 2 to 50 '
                                 f'temperatures, got {temps!r}')
            verification['temperatures_c'] = [
                _number('verification.temperatures_c', t, -60.0, 125.0) for t in temps]
        if 'average_s' in verification:
            verification['average_s'] = _number('verification.average_s',
                                                verification['average_s'], 0.01, 600.0)
        study = replace(study, kind=kind, temperature=temperature, sensor=sensor,
                        verification=verification)
        try:
            study.schedule_settings()
            study.temperature_settings()
        except (TypeError, ValueError) as error:
            raise StudyError(f'schedule settings: {error}') from None
        if study.calibrations < 1:
            raise StudyError('horizon_years must hold at least one calibration_interval_days')
        return study

    @classmethod
    def one_calibration(cls, schedule, span_ppm, torquer_drift, units, seed=0):
        """
        Return the Monte Carlo of one self-calibration after drifts within ``+-span_ppm``.

        The reference is captured, a year passes in the paper's room (25 degC, wander
        +-1.5 degC, 12 h correlation, no season; :class:`PaperRoom`), the forward and
        feedback chains have aged uniformly within the span, and ``schedule`` calibrates
        once. With ``torquer_drift`` k_t also ages within +-50 ppm and follows the magnet's
        temperature coefficient; without, k_t is stable.
        """
        return cls.from_dict({
            'name': f'{schedule}-kt-{"drift" if torquer_drift else "stable"}-{span_ppm:g}ppm',
            'units': units, 'seed': seed, 'batch_units': 2, 'schedule': {'name': schedule},
            'horizon_years': 1.0, 'calibration_interval_days': 365.25,
            'aging': {'distribution': 'uniform', 'forward_ppm_per_year': span_ppm,
                      'feedback_ppm_per_year': span_ppm,
                      'torquer_ppm_per_year': TORQUER_SPAN_PPM if torquer_drift else 0.0},
            'environment': {'room_c': 25.0, 'seasonal_amplitude_c': 0.0, 'wander_c': 1.5,
                            'error_profile': 'paper',
                            **({} if torquer_drift else {'magnet_tc_ppm': 0.0})}})

    @classmethod
    def load(cls, path):
        """Read and validate a study file."""
        name = str(path)
        try:
            # A stranger's file: a regular file of bounded size, parsed by the safe loader;
            # no message quotes it (PyYAML's quote the offending line).
            data = yaml.safe_load(read_regular_file(path, MAX_STUDY_BYTES))
        except UntrustedFileError as error:
            reason = str(error).removeprefix(f'{name}: ')
            raise StudyError(f'cannot read the study file: {reason}') from None
        except yaml.YAMLError as error:
            mark = getattr(error, 'problem_mark', None)
            where = f' (line {mark.line + 1}, column {mark.column + 1})' if mark else ''
            raise StudyError(f'the study file is not YAML{where}') from None
        except RecursionError:
            raise StudyError('the study file is not YAML (nested too deeply)') from None
        return cls.from_dict(data)
