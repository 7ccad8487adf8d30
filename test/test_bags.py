"""The example bags decode with an independent reader and are reproduced by ``make bags``.

Reproduced under the contract of ``bag_helpers`` (docs/reproducibility.md); under other
dispatches (numpy, OpenBLAS and numba as another CPU runs them) by ``make reproducibility``
(bench/results/reproducibility.md).
"""

import hashlib
import subprocess
import sys

from bag_helpers import (
    assert_same_bag,
    BAGS,
    DERIVED_RTOL,
    EXPECTED_BAGS,
    make_bags_commands,
    RAW_ATOL,
    SE_FRACTION,
)
from mcap.reader import make_reader
from mcap.writer import Writer
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
import yaml

from qfa_ros.bag.imu_cdr import ImuEncoder
from qfa_ros.bag.imu_series import read_imu
from qfa_ros.bag.trace_writer import key_values_to_dict
from qfa_ros.cli.sim import main as sim_main
from qfa_ros.cli.sim import SIM_START_NS
from qfa_ros.model.gyro import GyroConfig


@pytest.fixture(scope='module')
def example_bags():
    """Return ``{name: {topic: [(log time, message)]}}`` of every example bag, read once.

    Every message is decoded by rosbags and re-encoded: a decoder that dropped or misread a
    field would not give the same bytes back.
    """
    bags = {}
    for name in sorted(EXPECTED_BAGS):
        messages = bags[name] = {}
        with AnyReader([BAGS / name]) as reader:
            for connection, time_ns, raw in reader.messages():
                message = reader.deserialize(raw, connection.msgtype)
                assert bytes(reader.typestore.serialize_cdr(message, connection.msgtype)) == \
                    bytes(raw), (name, connection.topic)
                messages.setdefault(connection.topic, []).append((time_ns, message))
    return bags


# --- every example bag ---------------------------------------------------------------------

def test_example_bags_are_the_make_bags_outputs_and_small():
    files = sorted(BAGS.glob('*.mcap'))
    assert {f.name for f in files} == EXPECTED_BAGS == set(make_bags_commands())
    assert sum(f.stat().st_size for f in files) < 5 * 1024 * 1024
    assert not list(BAGS.glob('*.part'))


@pytest.mark.parametrize('name', sorted(EXPECTED_BAGS))
def test_every_message_decodes_and_counts_match_the_index(example_bags, name):
    path = BAGS / name
    counts = {topic: len(messages) for topic, messages in example_bags[name].items()}
    with open(path, 'rb') as stream:
        mcap = make_reader(stream)
        summary = mcap.get_summary()
        info = yaml.safe_load(next(mcap.iter_metadata()).metadata['serialized_metadata'])
        assert mcap.get_header().profile == 'ros2'
    by_channel = {summary.channels[i].topic: n
                  for i, n in summary.statistics.channel_message_counts.items()}
    by_metadata = {t['topic_metadata']['name']: t['message_count']
                   for t in info['topics_with_message_count']}
    assert {c.topic for c in summary.channels.values()} == set(by_metadata)
    # A registered topic may be empty (the temperature bag has no /imu/data_raw samples).
    assert counts == {t: n for t, n in by_channel.items() if n} == {
        t: n for t, n in by_metadata.items() if n}
    assert sum(counts.values()) == summary.statistics.message_count == info['message_count']


def test_example_bag_contents(example_bags):
    paper = example_bags['paper_2019.mcap']
    phases = [m.data for _, m in paper['/qfa/scenario/phase']]
    assert phases == ['reference', 'drifted', 'estimation', 'compensated']
    assert len(paper['/imu/data_raw']) == 30000
    assert len(paper['/qfa/trace/self_calibrate/forward/points']) == 11
    result = paper['/qfa/trace/self_calibrate/result'][0][1]
    assert 'forward gain drift' in result.status[0].message
    cycle = example_bags['temperature_cycle.mcap']
    # One reading per raw block of the calibration (one per tumble position), each at its
    # block's end: the temperature line of the points the fit used.
    blocks = cycle['/qfa/trace/temperature/blocks']
    assert len(cycle['/imu/temperature']) == len(blocks) > 1000
    assert [t for t, _ in cycle['/imu/temperature']] == [t for t, _ in blocks]
    labels = [d.label for d in cycle['/qfa/trace/temperature/points'][0][1].layout.dim]
    assert labels[:2] == ['v_temp', 'bias_x']
    values = key_values_to_dict(cycle['/qfa/trace/result'][0][1].status[0].values)
    assert values['temperature.rom.x.m_bits'] == 16


# --- reproduced by their commands ----------------------------------------------------------

def test_static_bag_is_reproduced_by_its_command(tmp_path, example_bags):
    regenerated = tmp_path / 'static_10s.mcap'
    assert sim_main([*make_bags_commands()['static_10s.mcap'], '--out', str(regenerated)]) == 0
    assert_same_bag(regenerated, BAGS / 'static_10s.mcap')
    # The same bag under the contract (every non-float field exact, floats within 1e-7):
    # its contents are checked as the committed bag decodes (read once, in example_bags).
    static = example_bags['static_10s.mcap']
    imu = static['/imu/data_raw']
    assert len(imu) == 10000
    first = imu[0][1]
    assert first.header.frame_id == 'imu_link'
    assert first.orientation_covariance[0] == -1
    assert first.linear_acceleration_covariance[0] > 0
    # The full IMU: the gyros see the Earth rate, level at 45 deg north, x east (yaw 0).
    assert first.angular_velocity_covariance[0] > 0
    rate = np.mean([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                    for _, m in imu], axis=0)
    earth_rate = 7.292115e-5 * np.array([0.0, np.cos(np.pi / 4), np.sin(np.pi / 4)])
    gyro = GyroConfig()
    # 5 sigma of a 10 s mean of the angle random walk, plus 5 sigma of the turn-on bias.
    np.testing.assert_allclose(rate, earth_rate,
                               atol=5 * gyro.arw / np.sqrt(10.0) + 5 * gyro.turn_on_bias)
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in imu])
    assert np.all(np.diff(stamps) == 1_000_000)
    assert stamps.tolist() == [t for t, _ in imu]
    # A documented start on the timeline, not 1970: 2026-01-01T00:00:00Z + one sample.
    assert stamps[0] == SIM_START_NS + 1_000_000
    phase_time, phase = static['/qfa/scenario/phase'][0]
    assert (phase_time, phase.data) == (SIM_START_NS, 'static')


def test_sim_is_byte_for_byte_the_same_in_another_process_and_moves_with_start_time(
        tmp_path):
    # Same seed, same machine: identical bytes, in this process and in another one (started
    # first, so that the two run side by side). One trial of the paper scenario: the code
    # of the paper bag (test_paper_bag_is_reproduced_under_the_contract), a third cheaper
    # to start in a fresh process.
    command = ['paper-2019', '--trials', '1', '--seed', '2',
               '--start-time', '2027-03-04T05:06:07+01:00', '--out']
    there = tmp_path / 'there' / 'moved.mcap'
    here = tmp_path / 'here' / 'moved.mcap'
    there.parent.mkdir()
    here.parent.mkdir()
    process = subprocess.Popen([sys.executable, '-m', 'qfa_ros.cli.sim', *command, str(there)],
                               stdout=subprocess.DEVNULL)
    try:
        assert sim_main([*command, str(here)]) == 0
    finally:
        assert process.wait(timeout=600) == 0
    assert hashlib.sha256(here.read_bytes()).digest() == \
        hashlib.sha256(there.read_bytes()).digest()
    start = 1_804_133_167_000_000_000  # 2027-03-04T04:06:07Z
    with AnyReader([here]) as reader:
        times = [t for _, t, _ in reader.messages()]
    # The first trial's first record comes a little after the start (reference capture).
    assert start <= min(times) < start + 60 * 10**9
    assert max(times) < start + 3600 * 10**9


def test_paper_bag_is_reproduced_under_the_contract(tmp_path):
    here = tmp_path / 'paper_2019.mcap'
    assert sim_main([*make_bags_commands()['paper_2019.mcap'], '--out', str(here)]) == 0
    assert_same_bag(here, BAGS / 'paper_2019.mcap')


def write_bag(path, z=9.8, estimate=-180.0, alpha=0.25, phase='drifted', time_ns=6):
    from qfa_ros.bag.types import stamp
    from qfa_ros.bag.writer import McapBagWriter
    with McapBagWriter(path) as bag:
        bag.add_topic('/imu/data_raw', 'sensor_msgs/msg/Imu')
        bag.add_topic('/qfa/scenario/phase', 'std_msgs/msg/String')
        bag.add_topic('/qfa/trace/result', 'diagnostic_msgs/msg/DiagnosticArray')
        bag.write('/imu/data_raw', {'header': {'stamp': stamp(5)},
                                    'linear_acceleration': {'z': z}}, 5)
        bag.write('/qfa/scenario/phase', {'data': phase}, 5)
        bag.write('/qfa/trace/result', {'status': [{'values': [
            {'key': 'forward.estimate_ppm.x', 'value': repr(estimate)},
            {'key': 'forward.std_error_ppm.x', 'value': '0.02'},
            {'key': 'fit.x.alpha1', 'value': repr(alpha)},
            {'key': 'rom.x.beta_q', 'value': '[-39570, 129012]'}]}]}, time_ns)
    return path


@pytest.mark.parametrize('change, passes', [
    ({}, True),
    ({'z': 9.8 + 0.5 * RAW_ATOL}, True),
    ({'z': 9.8 + 2 * RAW_ATOL}, False),
    ({'estimate': -180.0 + 0.5 * SE_FRACTION * 0.02}, True),
    ({'estimate': -180.0 + 2 * SE_FRACTION * 0.02}, False),
    ({'alpha': 0.25 * (1 + 0.5 * DERIVED_RTOL)}, True),
    ({'alpha': 0.25 * (1 + 2 * DERIVED_RTOL)}, False),
    ({'phase': 'drifted '}, False),
    ({'time_ns': 7}, False),
])
def test_bag_comparison_holds_the_contract_and_nothing_looser(tmp_path, change, passes):
    """The reproduction check fails on a sensor sample or a fit result beyond its tolerance."""
    committed = write_bag(tmp_path / 'committed.mcap')
    fresh = write_bag(tmp_path / 'fresh.mcap', **change)
    if passes:
        assert_same_bag(fresh, committed)
    else:
        with pytest.raises(AssertionError):
            assert_same_bag(fresh, committed)


def test_read_imu_gives_the_log_time_order_whatever_the_file_order(tmp_path):
    # read_imu reads in file order and sorts once (faster than mcap's log-time merge).
    stamps = np.array([3, 1, 2, 5, 4], dtype=np.int64) * 1_000_000
    accel = np.arange(15.0).reshape(5, 3)
    path = tmp_path / 'shuffled.mcap'
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start()
        schema = writer.register_schema('sensor_msgs/msg/Imu', 'ros2msg', b'')
        channel = writer.register_channel('/imu/data_raw', 'cdr', schema)
        for stamp, data in zip(stamps, ImuEncoder('imu', [0.0] * 9, [0.0] * 9).encode(
                stamps, accel, -accel)):
            writer.add_message(channel, log_time=int(stamp), data=data,
                               publish_time=int(stamp))
        writer.finish()
    order = np.argsort(stamps)
    read = read_imu(path)
    for got, expected in zip(read, (stamps[order], accel[order], -accel[order])):
        np.testing.assert_array_equal(got, expected)
