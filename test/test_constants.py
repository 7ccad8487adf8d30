"""The unit constants: defined once (qfa_ros.model.constants), imported from there everywhere."""

import ast
from fractions import Fraction
import math
from pathlib import Path

import pytest

from qfa_ros.model import constants

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ('qfa_ros', 'bench', 'test')
UNITS_MODULE = 'qfa_ros.model.constants'
FORMER_NAMES = ('G0', '_MG')
"""Names the constants had before they moved (a new alias of a unit is still a definition)."""
GRAVITY_LITERALS = (9.80665, 9.80665e-3, 9.80665e-6)


def unit_offences(source, where='<source>'):
    """Return each definition, foreign import or gravity literal of a unit in ``source``."""
    names = set(constants.UNIT_NAMES) | set(FORMER_NAMES)
    offences = []
    for node in ast.walk(ast.parse(source)):
        targets = []
        if isinstance(node, ast.Assign):
            targets = node.targets
        elif isinstance(node, (ast.AnnAssign, ast.AugAssign)):
            targets = [node.target]
        offences += [f'{where}:{node.lineno}: defines {target.id}' for target in targets
                     if isinstance(target, ast.Name) and target.id in names]
        if isinstance(node, ast.ImportFrom) and node.module != UNITS_MODULE:
            offences += [f'{where}:{node.lineno}: imports {alias.name} from {node.module}'
                         for alias in node.names if alias.name in constants.UNIT_NAMES]
        if isinstance(node, ast.Constant) and type(node.value) is float and \
                node.value in GRAVITY_LITERALS:
            offences += [f'{where}:{node.lineno}: literal {node.value!r} (use the units)']
    return offences


def test_no_module_but_units_defines_or_re_exports_a_unit_constant():
    offences = []
    for top in SCANNED:
        for path in sorted((ROOT / top).rglob('*.py')):
            if path in (ROOT / 'qfa_ros' / 'model' / 'constants.py', Path(__file__).resolve()):
                continue
            offences += unit_offences(path.read_text(), path.relative_to(ROOT).as_posix())
    assert not offences, '\n'.join(offences)


@pytest.mark.parametrize('source', [
    'PPM = 1e-6\n',
    'class A:\n    MICRO_G: float = 1e-6\n',
    'G0 = 1.0\n',
    'scale = 3.0 * 9.80665\n',
    'from qfa_ros.model.noise import MICRO_G\n',
])
def test_the_scan_finds_a_planted_definition(source):
    assert len(unit_offences(source)) == 1


def test_the_scan_accepts_the_units_import_and_other_literals():
    source = 'from qfa_ros.model.constants import MICRO_G\nx = 2.0 * MICRO_G + 9.8\n'
    assert unit_offences(source) == []


def test_each_unit_is_its_si_value():
    assert constants.PPM == 1e-6
    assert constants.STANDARD_GRAVITY == 9.80665
    assert constants.MILLI_G == pytest.approx(9.80665e-3, rel=1e-15)
    # The double nearest 9.80665e-6 exactly (1e-6 * g0 rounds one ulp below it).
    exact = Fraction('9.80665e-6')
    assert abs(Fraction(constants.MICRO_G) - exact) <= abs(
        Fraction(math.nextafter(constants.MICRO_G, 0.0)) - exact)
    assert abs(Fraction(constants.MICRO_G) - exact) <= abs(
        Fraction(math.nextafter(constants.MICRO_G, 1.0)) - exact)
    assert constants.DEGREE * 180.0 == pytest.approx(math.pi, rel=1e-15)
    assert constants.ARCSEC * 3600.0 == pytest.approx(constants.DEGREE, rel=1e-15)
    assert constants.DEG_PER_HOUR * 3600.0 == pytest.approx(constants.DEGREE, rel=1e-15)
    assert constants.DEG_PER_ROOT_HOUR * math.sqrt(3600.0) == pytest.approx(constants.DEGREE,
                                                                        rel=1e-15)


def test_unit_names_lists_every_constant_of_the_module():
    defined = {name for name in vars(constants) if name.isupper() and name != 'UNIT_NAMES'}
    assert defined == set(constants.UNIT_NAMES)
