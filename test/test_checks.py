"""One test of a caller's number (qfa_ros.model.checks.is_finite), asked by every layer."""

from decimal import Decimal
from fractions import Fraction
import math
import types

import numpy as np
import pytest

from qfa_ros.calibration.chamber import idle
from qfa_ros.calibration.estimation import check_seconds
from qfa_ros.calibration.tempfit import fit_double_exponential
from qfa_ros.model import checks
from qfa_ros.model.design import design_controller
from qfa_ros.model.drift import DriftModel
from qfa_ros.model.gyro import GyroConfig, GyroTriad
from qfa_ros.model.hardware import AxisHardware
from qfa_ros.model.triad import QfaTriad
from qfa_ros.model.triad_config import TriadConfig

NUMBERS = (0, -2, 1.5, np.float32(1.5), np.float64(-3.0), np.int64(7), Fraction(1, 2),
           Decimal('2.5'), True, np.True_)
NO_NUMBERS = (None, '1.5', 'x', [1.0], (), math.nan, math.inf, -math.inf, 10 ** 400)


def test_is_finite_says_which_values_are_finite_numbers_and_never_raises():
    assert all(checks.is_finite(value) for value in NUMBERS)
    assert not any(checks.is_finite(value) for value in NO_NUMBERS)
    assert not checks.is_finite(True, bool_ok=False)
    assert not checks.is_finite(np.True_, bool_ok=False)
    assert checks.is_finite(1, bool_ok=False)
    assert checks.is_finite(2, types=(int, float)) and checks.is_finite(2.5, types=(int, float))
    assert not checks.is_finite(np.int64(2), types=(int, float))
    assert not checks.is_finite(Decimal('2.5'), types=(int, float))


def test_finite_given_types_refuses_in_one_message_and_otherwise_reads_strings():
    assert checks.finite('x', '1.5') == 1.5
    with pytest.raises(ValueError, match='^x must be finite, got nan$'):
        checks.finite('x', 'nan')
    for value in ('1.5', math.nan, np.int64(1), 10 ** 400):
        with pytest.raises(ValueError, match='^x must be a finite number, got '):
            checks.finite('x', value, types=(int, float, np.floating))
    assert checks.finite('x', True, types=(int, float)) == 1.0
    with pytest.raises(ValueError, match='^x must be a finite number, got True'):
        checks.finite('x', True, types=(int, float), bool_ok=False)


@pytest.mark.parametrize('value', [None, 'x', [1.0], 10 ** 400],
                         ids=['None', 'str', 'list', 'huge'])
@pytest.mark.parametrize('call, name', [
    (lambda v: design_controller(AxisHardware(), 10000.0).with_gain(v), 'controller gain'),
    (lambda v: QfaTriad(TriadConfig()).set_controller_gain(0, v), 'controller gain'),
    (lambda v: GyroTriad(GyroConfig(), v, 1), 'sample_rate_hz'),
    (lambda v: idle(types.SimpleNamespace(thermal=None), v), 'seconds'),
    (lambda v: fit_double_exponential(np.linspace(0, 1, 20), np.linspace(0, 1, 20), tol=v),
     'tol'),
    (lambda v: check_seconds('settle_s', v), 'settle_s'),
    (lambda v: DriftModel().set_step(0, 'forward', v), 'delta'),
    (lambda v: TriadConfig(settle_time=v), 'settle_time'),
    (lambda v: AxisHardware(i_ref=v), 'i_ref'),
], ids=['with_gain', 'set_controller_gain', 'gyro_rate', 'idle', 'tol', 'check_seconds',
        'drift', 'settle_time', 'hardware'])
def test_a_value_that_is_no_number_or_beyond_the_float_range_is_refused_by_name(
        call, name, value):
    # Before they asked checks.is_finite, math.isfinite raised TypeError for None, a
    # string or a list, and OverflowError for an integer beyond the float range.
    with pytest.raises(ValueError, match=f'^{name} must'):
        call(value)
