"""Helpers for the example-bag tests: the ``make bags`` commands and a bag comparison."""

from pathlib import Path
import re
import shlex

import numpy as np
from numpy.testing import assert_allclose
from rosbags.highlevel import AnyReader

from qfa_ros.bag.trace import key_values_to_dict

REPO = Path(__file__).resolve().parents[1]
BAGS = REPO / 'bags'
EXPECTED_BAGS = {'static_10s.mcap', 'paper_2019.mcap', 'temperature_cycle.mcap'}
# Trace values come out of least-squares fits, whose last bits depend on the BLAS kernel
# the CPU selects; everything else (sensor output, points, settings) must be identical.
FIT_RTOL = 1e-6
FIT_ATOL = 1e-6


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


def _numbers_close(actual, expected, where):
    if isinstance(expected, float):
        assert isinstance(actual, float), where
        if np.isnan(expected):
            assert np.isnan(actual), where
        else:
            assert_allclose(actual, expected, rtol=FIT_RTOL, atol=FIT_ATOL, err_msg=where)
    elif isinstance(expected, list) and expected and isinstance(expected[0], float):
        assert_allclose(actual, expected, rtol=FIT_RTOL, atol=FIT_ATOL, err_msg=where)
    else:
        assert actual == expected, where


def assert_same_bag(fresh_path, committed_path):
    """Check that a regenerated bag carries the committed bag's messages.

    Topics, types, log times and counts must be identical, and every message
    byte-identical, except the trace results and residuals, which are compared
    value by value within ``FIT_RTOL``.
    """
    fresh, committed = read_raw(fresh_path), read_raw(committed_path)
    assert [m[:3] for m in fresh] == [m[:3] for m in committed]
    with AnyReader([Path(committed_path)]) as reader:
        store = reader.typestore
    for (topic, msgtype, time_ns, data), (_, _, _, want) in zip(fresh, committed):
        if data == want:
            continue
        where = f'{topic} at {time_ns}'
        assert topic.startswith('/qfa/trace/'), f'{where} differs'
        got, expected = (store.deserialize_cdr(raw, msgtype) for raw in (data, want))
        if msgtype == 'std_msgs/msg/Float64MultiArray':
            assert got.layout == expected.layout, where
            assert topic.endswith('/residuals'), f'{where}: raw points differ'
            assert_allclose(got.data, expected.data, rtol=FIT_RTOL, atol=FIT_ATOL,
                            err_msg=where)
        else:
            assert msgtype == 'diagnostic_msgs/msg/DiagnosticArray', where
            assert topic.endswith('/result'), f'{where}: settings differ'
            got_values = key_values_to_dict(got.status[0].values)
            expected_values = key_values_to_dict(expected.status[0].values)
            assert got_values.keys() == expected_values.keys(), where
            for key, value in expected_values.items():
                _numbers_close(got_values[key], value, f'{where} {key}')
