"""Checks of a caller's numbers, shared by every layer.

:func:`is_finite` is the one test of whether a caller's value is a finite number; every
other check here, and every layer's check that words its own refusal, asks it. Each
raises ``ValueError`` naming the parameter. They differ in what they accept on purpose (a
string ``float()`` reads, a bool, a numpy scalar): each keeps the set of inputs its callers
refused before they shared it.
"""

import math

import numpy as np


def is_finite(value, bool_ok=True, types=None):
    """
    Return True for a finite real number (``math.isfinite``), False for anything else.

    Parameters
    ----------
    value : object
        The caller's value: None, a string, a sequence or an integer beyond the float
        range is no finite number (False, not an exception).
    bool_ok : bool
        A bool is a number to ``math.isfinite``; False counts it (and ``numpy.bool_``) as
        none (a time or a limit given as ``True``).
    types : type or tuple of type, optional
        Accept only instances of these (``(int, float)``: not a numpy integer, not a
        ``Decimal``); None accepts whatever ``math.isfinite`` reads.

    Returns
    -------
    bool
    """
    if not bool_ok and isinstance(value, (bool, np.bool_)):
        return False
    if types is not None and not isinstance(value, types):
        return False
    try:
        return math.isfinite(value)
    except (TypeError, OverflowError):
        # None, a string, a sequence; an integer beyond the float range.
        return False


def count(name, value, least=0):
    """Return ``value`` as an int: a whole number (``2.0`` too, not a bool) >= ``least``."""
    try:
        valid = not isinstance(value, bool) and int(value) == value and value >= least
    except (TypeError, ValueError, OverflowError):
        # None, a string, NaN, infinity: not a count.
        valid = False
    if not valid:
        raise ValueError(f'{name} must be an integer >= {least}, got {value!r}')
    return int(value)


def index(name, value, size):
    """Return ``value`` as an int in ``[0, size)``: an integer type only, not a bool."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or not 0 <= value < size:
        raise ValueError(f'{name} must be an integer in [0, {size}), got {value!r}')
    return int(value)


def finite(name, value, types=None, bool_ok=True):
    """
    Return ``value`` as a float if it is a finite number; raise ``ValueError`` otherwise.

    Parameters
    ----------
    name : str
        The parameter the refusal names.
    value : object
        The caller's value.
    types : type or tuple of type, optional
        None: anything ``float()`` reads (a numeric string too). Given: an instance of
        these only, refused as ``'{name} must be a finite number'`` whatever is wrong.
    bool_ok : bool
        With ``types``, whether a bool counts as a number (:func:`is_finite`).

    Returns
    -------
    float

    Raises
    ------
    ValueError
        ``value`` is no finite number (the message names ``name`` and quotes ``value``).
    """
    if types is not None:
        if not is_finite(value, bool_ok, types):
            raise ValueError(f'{name} must be a finite number, got {value!r}')
        return float(value)
    try:
        value = float(value)
    except (TypeError, ValueError, OverflowError) as error:
        raise ValueError(f'{name} must be a finite number, got {value!r}') from error
    if not is_finite(value):
        raise ValueError(f'{name} must be finite, got {value!r}')
    return value


def positive(name, value, allow_zero=False):
    """Return ``value`` as a float (as :func:`finite`), if > 0 (``allow_zero``: >= 0)."""
    value = finite(name, value)
    if value < 0 or (value == 0 and not allow_zero):
        raise ValueError(f'{name} must be {">= 0" if allow_zero else "> 0"}, got {value!r}')
    return value


def non_negative(name, value, types=None):
    """Refuse a non-finite or negative number (given ``types``, also one not of them)."""
    if not is_finite(value, types=types) or value < 0:
        raise ValueError(f'{name} must be finite and >= 0, got {value!r}')


def positive_times(name, values):
    """Refuse an empty sequence of times or one with a time not finite and > 0."""
    try:
        valid = len(values) > 0 and all(is_finite(t) and t > 0 for t in values)
    except TypeError:
        # Not a sequence (None, a number).
        valid = False
    if not valid:
        raise ValueError(f'{name} must be positive and finite')


def finite_vector(name, value, size=3):
    """Return ``value`` as a float array of ``size`` finite numbers."""
    vector = np.asarray(value, dtype=float)
    if vector.shape != (size,) or not np.all(np.isfinite(vector)):
        raise ValueError(f'{name} must be {size} finite numbers, got {value!r}')
    return vector
