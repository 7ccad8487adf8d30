"""The example bags decode with an independent reader and are reproduced by ``make bags``."""


from bag_helpers import assert_same_bag, BAGS, EXPECTED_BAGS, make_bags_commands
from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
import yaml

from qfa_ros.bag.scenario_bag import SIM_START_NS
from qfa_ros.bag.trace import key_values_to_dict
from qfa_ros.cli.sim import main as sim_main


def read_all(path):
    """Return {topic: [(log time, message)]} decoded by rosbags."""
    messages = {}
    with AnyReader([path]) as reader:
        for connection, time_ns, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                (time_ns, reader.deserialize(raw, connection.msgtype)))
    return messages



# --- every example bag ---------------------------------------------------------------------

def test_example_bags_are_the_make_bags_outputs_and_small():
    files = sorted(BAGS.glob('*.mcap'))
    assert {f.name for f in files} == EXPECTED_BAGS == set(make_bags_commands())
    assert sum(f.stat().st_size for f in files) < 5 * 1024 * 1024
    assert not list(BAGS.glob('*.part'))


@pytest.mark.parametrize('name', sorted(EXPECTED_BAGS))
def test_every_message_decodes_and_counts_match_the_index(name):
    path = BAGS / name
    counts = {}
    with AnyReader([path]) as reader:
        for connection, _, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            # A decoder that dropped or misread a field would not re-encode the same bytes.
            assert bytes(reader.typestore.serialize_cdr(message, connection.msgtype)) == \
                bytes(raw), connection.topic
            counts[connection.topic] = counts.get(connection.topic, 0) + 1
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


def test_example_bag_contents():
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
    values = key_values_to_dict(cycle['/qfa/trace/result'][0][1].status[0].values)
    assert values['temperature.rom.x.m_bits'] == 16


# --- reproduced by their commands ----------------------------------------------------------

def test_static_bag_is_reproduced_by_its_command(tmp_path):
    regenerated = tmp_path / 'static_10s.mcap'
    assert sim_main([*make_bags_commands()['static_10s.mcap'], '--out', str(regenerated)]) == 0
    assert_same_bag(regenerated, BAGS / 'static_10s.mcap')
    imu = read_all(regenerated)['/imu/data_raw']
    assert len(imu) == 10000
    first = imu[0][1]
    assert first.header.frame_id == 'imu_link'
    assert first.orientation_covariance[0] == -1 and first.angular_velocity_covariance[0] == -1
    assert first.linear_acceleration_covariance[0] > 0
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in imu])
    assert np.all(np.diff(stamps) == 1_000_000)
    assert stamps.tolist() == [t for t, _ in imu]
    # A documented start on the timeline, not 1970: 2026-01-01T00:00:00Z + one sample.
    assert stamps[0] == SIM_START_NS + 1_000_000
    phase_time, phase = read_all(regenerated)['/qfa/scenario/phase'][0]
    assert (phase_time, phase.data) == (SIM_START_NS, 'static')


def test_sim_start_time_option_moves_every_time_in_the_bag(tmp_path):
    out = tmp_path / 'moved.mcap'
    assert sim_main(['paper-2019', '--trials', '1', '--seed', '2', '--out', str(out),
                     '--start-time', '2027-03-04T05:06:07+01:00']) == 0
    start = 1_804_133_167_000_000_000  # 2027-03-04T04:06:07Z
    times = [t for messages in read_all(out).values() for t, _ in messages]
    # The first trial's first record comes a little after the start (reference capture).
    assert start <= min(times) < start + 60 * 10**9
    assert max(times) < start + 3600 * 10**9


def test_paper_bag_is_reproduced_by_its_command(tmp_path):
    regenerated = tmp_path / 'paper_2019.mcap'
    assert sim_main([*make_bags_commands()['paper_2019.mcap'], '--out', str(regenerated)]) == 0
    assert_same_bag(regenerated, BAGS / 'paper_2019.mcap')


def test_bag_comparison_detects_a_changed_message(tmp_path):
    """The reproduction check fails on a sensor sample or a fit result that differs."""
    from qfa_ros.bag.types import stamp
    from qfa_ros.bag.writer import McapBagWriter

    def write(path, z, estimate):
        with McapBagWriter(path) as bag:
            bag.add_topic('/imu/data_raw', 'sensor_msgs/msg/Imu')
            bag.add_topic('/qfa/trace/result', 'diagnostic_msgs/msg/DiagnosticArray')
            bag.write('/imu/data_raw', {'header': {'stamp': stamp(5)},
                                        'linear_acceleration': {'z': z}}, 5)
            bag.write('/qfa/trace/result', {'status': [{'values': [
                {'key': 'estimate', 'value': repr(estimate)}]}]}, 6)
        return path

    committed = write(tmp_path / 'a.mcap', 9.8, -180.0)
    assert_same_bag(write(tmp_path / 'b.mcap', 9.8, -180.0 * (1 + 1e-9)), committed)
    with pytest.raises(AssertionError, match='imu'):
        assert_same_bag(write(tmp_path / 'c.mcap', 9.8 + 1e-12, -180.0), committed)
    with pytest.raises(AssertionError, match='estimate'):
        assert_same_bag(write(tmp_path / 'd.mcap', 9.8, -180.001), committed)
