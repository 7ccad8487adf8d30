"""The example bags' commands and the reproducibility contract they are compared under.

The contract (docs/reproducibility.md):

- same seed, same machine: identical bytes;
- another CPU (other SIMD paths in numpy, other OpenBLAS kernels, another libm, numba
  compiled for another CPU): identical structure -- topics, types, message count and
  order, log times, and every field that is not a float (strings, integers, booleans,
  array lengths, labels, keys) -- and float values within the tolerances below, measured
  by ``bench/reproducibility.py``:

  - raw values (sensor samples, trace points and blocks) and fit residuals:
    ``|a - b| <= RAW_ATOL`` in the field's unit;
  - an estimate whose standard error the result carries (``<block>.estimate_ppm.<axis>``
    with ``<block>.std_error_ppm.<axis>``): ``|a - b| <= SE_FRACTION * std_error``; the
    measured gains and the loop words of that estimate relatively,
    ``|a - b| <= SE_FRACTION * std_error_ppm * 1e-6 * |b|``;
  - every other derived result value (fit coefficients, rms errors, standard errors,
    peak-to-peak figures): ``|a - b| <= DERIVED_RTOL * |b|``.
"""

import dataclasses
from pathlib import Path
import re
import shlex

import numpy as np
from rosbags.highlevel import AnyReader

from qfa_ros.bag.trace_writer import key_values_to_dict

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / 'bags'
EXPECTED_BAGS = {'static_10s.mcap', 'paper_2019.mcap', 'temperature_cycle.mcap'}

# Twice the worst difference measured by bench/reproducibility.py, rounded up to 1, 2 or 5
# times a power of ten (bench/results/reproducibility.md).
RAW_ATOL = 1e-7
SE_FRACTION = 1e-7
DERIVED_RTOL = 2e-5

# A different dispatch on this machine, as another CPU would run it: numpy without its
# AVX2 (x86-64-v3) loops, OpenBLAS's SSE3 kernels, numba compiled for a generic x86-64.
OTHER_DISPATCH = {'NPY_DISABLE_CPU_FEATURES': 'X86_V3', 'OPENBLAS_CORETYPE': 'Prescott',
                  'NUMBA_CPU_NAME': 'generic'}

_SE_KEY = re.compile(r'^(?P<block>.+)\.(?P<kind>estimate_ppm|measured|reference|words_before'
                     r'|words_after)\.(?P<axis>[^.]+)$')


def read_raw(path):
    """Return ``[(topic, type, log time, CDR bytes)]`` in log-time order with rosbags."""
    with AnyReader([Path(path)]) as reader:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]


def make_bags_commands():
    """Return ``{bag file name: qfa-sim arguments}`` from the Makefile's ``bags`` recipe."""
    text = (REPO / 'Makefile').read_text().replace('\\\n', ' ')
    recipe = re.search(r'^bags:.*\n((?:\t.*\n)+)', text, flags=re.MULTILINE).group(1)
    commands = {}
    for line in recipe.splitlines():
        words = shlex.split(line)
        if words and words[0].endswith('/qfa-sim'):
            out = words.index('--out')
            commands[Path(words[out + 1]).name] = words[1:out] + words[out + 2:]
    return commands


def _leaves(value, path):
    """Yield ``(path, value)`` for every scalar of a decoded message."""
    if dataclasses.is_dataclass(value):
        for field in dataclasses.fields(value):
            if field.name != '__msgtype__':
                yield from _leaves(getattr(value, field.name), f'{path}.{field.name}')
    elif isinstance(value, np.ndarray):
        yield f'{path}.size', value.size
        for index, item in enumerate(value.tolist()):
            yield f'{path}[{index}]', item
    elif isinstance(value, (list, tuple)):
        yield f'{path}.size', len(value)
        for index, item in enumerate(value):
            yield from _leaves(item, f'{path}[{index}]')
    else:
        yield path, value


TOLERANCES = {'raw': RAW_ATOL, 'estimate': SE_FRACTION, 'derived': DERIVED_RTOL}


@dataclasses.dataclass
class Difference:
    """
    One float that differs: where, the two values, and the unit of its tolerance.

    ``kind`` 'raw': absolute, unit 1; 'estimate': in standard errors, unit the standard
    error (relative ones for the measured gains and words); 'derived': relative, unit |b|.
    """

    where: str
    kind: str
    got: float
    expected: float
    unit: float

    @property
    def error(self):
        return abs(self.got - self.expected)

    @property
    def scaled(self):
        """The difference in the unit of its tolerance: compared with TOLERANCES[kind]."""
        return self.error / self.unit if self.unit else np.inf

    @property
    def bound(self):
        return TOLERANCES[self.kind] * self.unit

    @property
    def ok(self):
        return self.error <= self.bound


def _result_units(values):
    """Yield ``(key, kind, unit)``: how each value of a trace result is bounded."""
    for key, value in values.items():
        match = _SE_KEY.match(key)
        sigma = None
        if match:
            sigma = values.get(f'{match["block"]}.std_error_ppm.{match["axis"]}')
        scale = np.abs(np.asarray(value, dtype=float)) if _is_floats(value) else None
        if isinstance(sigma, float) and np.isfinite(sigma):
            if match['kind'] == 'estimate_ppm':
                yield key, 'estimate', sigma
            else:
                yield key, 'estimate', sigma * 1e-6 * scale
        else:
            yield key, 'derived', scale


def _is_floats(value):
    return isinstance(value, float) or (
        isinstance(value, list) and any(isinstance(v, float) for v in value))


def _compare_floats(got, expected, where, kind, unit, differences):
    if np.isnan(expected):
        assert np.isnan(got), f'{where}: {got!r} is not NaN'
    elif got != expected:
        differences.append(Difference(where, kind, got, expected, float(unit)))


def _compare_values(got, expected, where, kind, unit, differences):
    """Compare decoded result values: floats within the contract, anything else exactly."""
    if isinstance(expected, float):
        assert isinstance(got, float), f'{where}: {got!r} is not a float'
        _compare_floats(got, expected, where, kind, unit, differences)
    elif isinstance(expected, list):
        assert isinstance(got, list) and len(got) == len(expected), f'{where} differs'
        units = np.broadcast_to(unit, (len(expected),)) if unit is not None else [None] * len(
            expected)
        for index, (a, b, u) in enumerate(zip(got, expected, units)):
            _compare_values(a, b, f'{where}[{index}]', kind, u, differences)
    else:
        assert got == expected, f'{where}: {got!r} != {expected!r}'


def _compare_message(topic, msgtype, got, expected, where, differences):
    got_leaves, expected_leaves = list(_leaves(got, '')), list(_leaves(expected, ''))
    assert [p for p, _ in got_leaves] == [p for p, _ in expected_leaves], \
        f'{where}: fields differ'
    derived_topic = topic.endswith('/result') and msgtype.endswith('/DiagnosticArray')
    for (path, a), (_, b) in zip(got_leaves, expected_leaves):
        here = f'{where} {path}'
        if derived_topic and re.search(r'\.values\[\d+\]\.value$', path):
            continue  # compared as decoded values below
        if isinstance(b, float):
            assert isinstance(a, float), f'{here}: {a!r} is not a float'
            _compare_floats(a, b, here, 'raw', 1.0, differences)
        else:
            assert a == b, f'{here}: {a!r} != {b!r}'
    if derived_topic:
        for index, (status_a, status_b) in enumerate(zip(got.status, expected.status)):
            values_a = key_values_to_dict(status_a.values)
            values_b = key_values_to_dict(status_b.values)
            assert list(values_a) == list(values_b), f'{where}: keys differ'
            for key, kind, unit in _result_units(values_b):
                _compare_values(values_a[key], values_b[key], f'{where} {key}', kind, unit,
                                differences)


def compare_bags(fresh_path, committed_path):
    """
    Compare two bags under the contract; return the float differences found.

    Structure and non-float fields must be identical (an ``AssertionError`` names the
    first that is not); float differences are returned, each with its bound, for
    ``assert_same_bag`` to check and ``bench/reproducibility.py`` to measure.
    """
    fresh, committed = read_raw(fresh_path), read_raw(committed_path)
    assert [m[:3] for m in fresh] == [m[:3] for m in committed], \
        'topics, types, order or log times differ'
    differences = []
    with AnyReader([Path(committed_path)]) as reader:
        store = reader.typestore
    for (topic, msgtype, time_ns, data), (_, _, _, want) in zip(fresh, committed):
        if data == want:
            continue
        got, expected = (store.deserialize_cdr(raw, msgtype) for raw in (data, want))
        _compare_message(topic, msgtype, got, expected, f'{topic} at {time_ns}', differences)
    return differences


def assert_same_bag(fresh_path, committed_path):
    """Check that a regenerated bag keeps the reproducibility contract with the committed one."""
    beyond = [d for d in compare_bags(fresh_path, committed_path) if not d.ok]
    assert not beyond, '\n'.join(
        f'{d.where}: {d.got!r} != {d.expected!r} (|diff| {d.error:.3g} > {d.bound:.3g}, '
        f'{d.kind})' for d in beyond[:10])
