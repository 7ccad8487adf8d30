"""The example bags decode with an independent reader and are reproducible."""

from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader

from qfa_ros.sim import main as sim_main

BAGS = Path(__file__).resolve().parents[1] / 'bags'


def read_all(path):
    """Return {topic: [(log time, message)]} decoded by rosbags."""
    messages = {}
    with AnyReader([path]) as reader:
        for connection, time_ns, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                (time_ns, reader.deserialize(raw, connection.msgtype)))
    return messages


def test_example_bags_are_small_and_every_message_decodes():
    files = sorted(BAGS.glob('*.mcap'))
    assert {f.name for f in files} == {'static_10s.mcap', 'paper_2019.mcap',
                                       'temperature_cycle.mcap'}
    assert sum(f.stat().st_size for f in files) < 5 * 1024 * 1024
    paper = read_all(BAGS / 'paper_2019.mcap')
    phases = [m.data for _, m in paper['/qfa/scenario/phase']]
    assert phases == ['reference', 'drifted', 'estimation', 'compensated']
    assert len(paper['/imu/data_raw']) == 30000
    assert len(paper['/qfa/trace/self_calibrate/forward/points']) == 11
    result = paper['/qfa/trace/self_calibrate/result'][0][1]
    assert 'forward gain drift' in result.status[0].message
    cycle = read_all(BAGS / 'temperature_cycle.mcap')
    assert len(cycle['/imu/temperature']) == 7200
    labels = [d.label for d in cycle['/qfa/trace/temperature/points'][0][1].layout.dim]
    assert labels[:2] == ['v_temp', 'bias_x']


def test_static_bag_is_reproduced_by_its_command(tmp_path):
    regenerated = tmp_path / 'static_10s.mcap'
    assert sim_main(['static', '--duration', '10', '--seed', '1',
                     '--out', str(regenerated)]) == 0
    committed = read_all(BAGS / 'static_10s.mcap')
    fresh = read_all(regenerated)
    assert committed.keys() == fresh.keys()
    imu_old = committed['/imu/data_raw']
    imu_new = fresh['/imu/data_raw']
    assert len(imu_old) == len(imu_new) == 10000
    old = np.array([[m.linear_acceleration.x, m.linear_acceleration.y,
                     m.linear_acceleration.z] for _, m in imu_old])
    new = np.array([[m.linear_acceleration.x, m.linear_acceleration.y,
                     m.linear_acceleration.z] for _, m in imu_new])
    assert np.array_equal(old, new)
    assert [t for t, _ in imu_old] == [t for t, _ in imu_new]
    first = imu_old[0][1]
    assert first.header.frame_id == 'imu_link'
    assert first.orientation_covariance[0] == -1 and first.angular_velocity_covariance[0] == -1
    assert first.linear_acceleration_covariance[0] > 0
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                       for _, m in imu_old])
    assert np.all(np.diff(stamps) == 1_000_000)
