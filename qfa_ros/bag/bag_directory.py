"""
rosbag2 bag directories: ``metadata.yaml`` (version 9) beside ``NAME_0.mcap``, ``NAME_1.mcap``...

This is the layout ``ros2 bag record -o NAME`` makes with the MCAP storage plugin and
``--max-bag-size``/``--max-bag-duration`` splits, and what ``ros2 bag play/info``,
``rosbags.rosbag2.Reader`` and :class:`qfa_ros.bag.reader.BagSource` open.
"""

import datetime

from qfa_ros.bag.files import write_text_atomically
from qfa_ros.bag.qos import dump_yaml
from qfa_ros.bag.writer import BAG_METADATA_VERSION, ROS_DISTRO

METADATA_FILE = 'metadata.yaml'


def default_bag_name(prefix, time_ns):
    """Return rosbag2's default bag name pattern: ``PREFIX_YYYY_MM_DD-HH_MM_SS`` (UTC)."""
    moment = datetime.datetime.fromtimestamp(time_ns / 1e9, tz=datetime.timezone.utc)
    return f'{prefix}_{moment:%Y_%m_%d-%H_%M_%S}'


def split_file_name(bag_name, index):
    """Return the name of split ``index`` of bag ``bag_name`` (rosbag2: ``NAME_INDEX.mcap``)."""
    return f'{bag_name}_{index}.mcap'


def merge_bag_metadata(files, custom_data=None, ros_distro=ROS_DISTRO):
    """
    Return the rosbag2 ``BagMetadata`` mapping of a bag made of ``files``.

    Parameters
    ----------
    files : list of dict
        Each file's own metadata (:meth:`McapBagWriter.bag_metadata`), or a bag's made
        by this function (several files), in recording order: a recorder merges each
        finished file into what it had, so it keeps one ``files`` entry per file.
    custom_data : mapping, optional
        rosbag2 ``custom_data``.

    Returns
    -------
    dict
        Counts and per-topic counts summed, the time span of all files, one ``files``
        entry per file.
    """
    topics = {}
    entries = []
    starts, ends = [], []
    for meta in files:
        for entry in meta['files']:
            entries.append(entry)
            if entry['message_count']:
                start = entry['starting_time']['nanoseconds_since_epoch']
                starts.append(start)
                ends.append(start + entry['duration']['nanoseconds'])
        for item in meta['topics_with_message_count']:
            name = item['topic_metadata']['name']
            if name in topics:
                topics[name]['message_count'] += item['message_count']
            else:
                topics[name] = {'topic_metadata': dict(item['topic_metadata']),
                                'message_count': item['message_count']}
    start = min(starts, default=0)
    return {
        'version': BAG_METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': max(ends, default=0) - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(entry['message_count'] for entry in entries),
        'topics_with_message_count': list(topics.values()),
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [entry['path'] for entry in entries],
        'files': entries,
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ros_distro,
    }


def write_bag_metadata(directory, metadata):
    """Write ``directory/metadata.yaml`` atomically; return its path."""
    path = directory / METADATA_FILE
    write_text_atomically(path, dump_yaml({'rosbag2_bagfile_information': metadata}) + '\n')
    return path
