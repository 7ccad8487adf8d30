"""
Kalibr's ``imu.yaml``: read one a participant names, write one of this sensor.

Reading takes a stranger's file (``noise.imu_yaml`` of the node, ``qfa-sim --imu-yaml``):
through :func:`~qfa_ros.model.safe_files.read_regular_file` (a regular file of at most
:data:`MAX_BYTES`), PyYAML's safe loader, and errors that name the file and the key, never
its content (PyYAML's own messages quote the offending line; they are replaced). The four
noise figures (:data:`~qfa_ros.model.noise_figures.KEYS`) must be there, as numbers within
:data:`~qfa_ros.model.noise_figures.LIMITS`; ``update_rate`` and ``rostopic`` are not used (the
densities are continuous-time: the emulated sensor publishes them at its own rate, on its
own topic); other keys are ignored, as Kalibr ignores them.

Writing (:func:`imu_yaml_text`) gives each line its comment: what the figure is, its unit,
where it comes from.
"""

import math
import os

import yaml

from qfa_ros.model.checks import is_finite
from qfa_ros.model.noise_figures import ImuNoiseFigures, KEYS
from qfa_ros.model.safe_files import read_regular_file

MAX_BYTES = 64 * 1024
"""Largest ``imu.yaml`` read [bytes] (Kalibr's are a few hundred)."""
UNITS = {'accelerometer_noise_density': 'm/s^2/sqrt(Hz)',
         'accelerometer_random_walk': 'm/s^3/sqrt(Hz)',
         'gyroscope_noise_density': 'rad/s/sqrt(Hz)',
         'gyroscope_random_walk': 'rad/s^2/sqrt(Hz)', 'update_rate': 'Hz'}
"""Kalibr's unit of each key."""


def load_imu_yaml(path, max_bytes=MAX_BYTES):
    """
    Return the :class:`~qfa_ros.model.noise_figures.ImuNoiseFigures` of a Kalibr ``imu.yaml``.

    Raises
    ------
    ValueError
        The file cannot be read or is not one; the message names the path and the key, never
        the content.
    """
    return parse_imu_yaml(read_regular_file(path, max_bytes), os.fspath(path))


def parse_imu_yaml(data, name='imu.yaml'):
    """Return the figures of the bytes of an ``imu.yaml`` called ``name``."""
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError:
        raise ValueError(f'{name}: not UTF-8 text') from None
    try:
        document = yaml.safe_load(text)
    except (yaml.YAMLError, RecursionError):
        raise ValueError(f'{name}: not a YAML document') from None
    if not isinstance(document, dict):
        raise ValueError(f'{name}: not a mapping of Kalibr keys ({", ".join(KEYS)})')
    values = {}
    for key in KEYS:
        if key not in document:
            raise ValueError(f'{name}: no {key}')
        values[key] = _number(document[key])
        if values[key] is None:
            raise ValueError(f'{name}: {key} must be a number')
    try:
        return ImuNoiseFigures(**values)
    except ValueError as error:
        raise ValueError(f'{name}: {error}') from None


def _number(value):
    """Return ``value`` as a float, or None: a YAML number, or a string of one.

    PyYAML reads ``1e-05`` (no decimal point, what Python's ``repr`` writes) as a string;
    Kalibr's own files are read by PyYAML too, so such a figure is taken as the number it
    says.
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, float):
        return value
    if isinstance(value, int):
        try:
            return float(value)
        except OverflowError:
            # An integer beyond the float range (a literal of 309 digits): out of range.
            return math.inf if value > 0 else -math.inf
    if isinstance(value, str) and len(value) <= 40:
        try:
            number = float(value)
        except ValueError:
            return None
        return number if is_finite(number) else None
    return None


def yaml_float(value):
    """
    Return ``value`` written as a float PyYAML (Kalibr's reader) reads back as one.

    Python's shortest repr, with the decimal point YAML 1.1 needs before an exponent:
    ``repr(2e-05)`` is ``2e-05``, which PyYAML reads as a string; this writes ``2.0e-05``.
    """
    text = repr(float(value))
    mantissa, e, exponent = text.partition('e')
    return f'{mantissa}.0e{exponent}' if e and '.' not in mantissa else text


def imu_yaml_text(figures, comments, header):
    """
    Return the text of an ``imu.yaml``: ``header`` lines on top, one commented line a key.

    ``figures`` maps Kalibr keys (the noise keys, ``update_rate``, ``rostopic``) to values;
    ``comments`` the keys to what each line's comment says after its unit.
    """
    lines = ['# imu.yaml (Kalibr / OpenVINS / allan_variance_ros conventions), qfa-report '
             'imu-yaml']
    lines += [f'# {line}' for line in header]
    for key in KEYS + ('update_rate', 'rostopic'):
        if key not in figures:
            continue
        value = figures[key]
        text = f"{key}: '{value}'" if isinstance(value, str) else f'{key}: {yaml_float(value)}'
        note = '; '.join(part for part in (UNITS.get(key), comments.get(key)) if part)
        lines.append(f'{text}  # {note}' if note else text)
    return '\n'.join(lines) + '\n'
