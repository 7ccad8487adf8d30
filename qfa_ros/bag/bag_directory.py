"""
rosbag2 bag directories: ``metadata.yaml`` (version 9) beside ``NAME_0.mcap``, ``NAME_1.mcap``...

This is the layout ``ros2 bag record -o NAME`` makes with the MCAP storage plugin and
``--max-bag-size``/``--max-bag-duration`` splits, and what ``ros2 bag play/info``,
``rosbags.rosbag2.Reader`` and :class:`qfa_ros.bag.reader.BagSource` open.
"""

import datetime

from qfa_ros.bag.part_files import METADATA_FILE, write_text_atomically
from qfa_ros.bag.qos import dump_yaml
from qfa_ros.bag.writer import bag_metadata_head, file_entry, ROS_DISTRO

__all__ = [
    'default_bag_name',
    'merge_bag_metadata',
    'METADATA_FILE',
    'split_file_name',
    'write_bag_metadata',
]


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
        Each file's own metadata (:meth:`McapBagWriter.bag_metadata`), in recording order.
    custom_data : mapping, optional
        rosbag2 ``custom_data``.

    Returns
    -------
    dict
        Counts and per-topic counts summed, the time span of all files, one ``files``
        entry per file.
    """
    metadata = BagMetadata(custom_data, ros_distro)
    for meta in files:
        metadata.add(meta)
    return metadata.as_dict()


class BagMetadata:
    """
    A bag's ``metadata.yaml``, grown one finished file at a time.

    A recorder that splits for days rewrites it after every file. Rendered whole by PyYAML
    each time, the document costs time and transient memory in proportion to the files
    listed (at 1000 files: 1.5 s of CPU and 4.4 MB of Python objects per split, freed to an
    allocator that keeps them: the node's RSS grew with the bag). Here each file's
    ``relative_file_paths`` line and ``files`` entry are rendered once, when the file is
    added, and only the head (counts, time span, topics) is rendered again; the two lists
    come last in the mapping, which readers take by key (rosbag2, rosbags). Retention
    removes the oldest files again (:meth:`remove`), from the recorder's own metadata or
    from one read back (:meth:`from_mapping`).

    Parameters
    ----------
    custom_data : mapping, optional
        rosbag2 ``custom_data``.
    ros_distro : str
        The distribution named in the document.
    """

    def __init__(self, custom_data=None, ros_distro=ROS_DISTRO):
        self._custom_data = dict(custom_data) if custom_data else None
        self._ros_distro = ros_distro
        self._topics = {}
        self._message_count = 0
        self._start = self._end = None
        # Per file: (path, start, duration, message count) and its rendered lines in both
        # lists (a few hundred bytes a file in all).
        self._files = []
        self._rendered = {'relative_file_paths': [], 'files': []}

    @classmethod
    def from_mapping(cls, information):
        """
        Return the metadata a ``metadata.yaml`` holds (its ``rosbag2_bagfile_information``).

        Parameters
        ----------
        information : mapping
            The document's ``rosbag2_bagfile_information``, as ``yaml.safe_load`` gives it.

        Returns
        -------
        BagMetadata
            Its files (with their rendered lines), topics and counts, to remove files from.

        Raises
        ------
        ValueError
            It is not rosbag2 bag metadata as :meth:`text` writes it (a field missing or of
            another type, ``files`` and ``relative_file_paths`` not alike).
        """
        try:
            metadata = cls(information['custom_data'], str(information['ros_distro']))
            files = [(str(entry['path']), int(entry['starting_time']['nanoseconds_since_epoch']),
                      int(entry['duration']['nanoseconds']), int(entry['message_count']))
                     for entry in information['files']]
            topics = [(dict(item['topic_metadata']), int(item['message_count']))
                      for item in information['topics_with_message_count']]
            listed = [str(path) for path in information['relative_file_paths']]
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise ValueError(f'not rosbag2 bag metadata ({type(error).__name__}: {error})') \
                from None
        if listed != [path for path, _, _, _ in files]:
            raise ValueError('relative_file_paths and files differ')
        for path, start, duration, count in files:
            metadata.add({'files': [file_entry(path, start, duration, count)],
                          'topics_with_message_count': []})
        for topic_metadata, count in topics:
            metadata._topics[str(topic_metadata.get('name'))] = {
                'topic_metadata': topic_metadata, 'message_count': count}
        return metadata

    @property
    def file_names(self):
        """Return the names of the files added, in order."""
        return [path for path, _, _, _ in self._files]

    @property
    def files(self):
        """Return ``(name, start [ns], duration [ns], message count)`` of each file, in order."""
        return list(self._files)

    def add(self, file_metadata):
        """Add a finished file: its own metadata (:meth:`McapBagWriter.bag_metadata`)."""
        for entry in file_metadata['files']:
            start = entry['starting_time']['nanoseconds_since_epoch']
            duration = entry['duration']['nanoseconds']
            self._files.append((entry['path'], start, duration, entry['message_count']))
            self._message_count += entry['message_count']
            if entry['message_count']:
                self._start = start if self._start is None else min(self._start, start)
                self._end = start + duration if self._end is None \
                    else max(self._end, start + duration)
            # Indented as PyYAML indents a block sequence under a key of a mapping.
            self._rendered['relative_file_paths'].append(_indent(dump_yaml([entry['path']])))
            self._rendered['files'].append(_indent(dump_yaml([file_entry(*self._files[-1])])))
        for item in file_metadata['topics_with_message_count']:
            self._topics.setdefault(item['topic_metadata']['name'], {
                'topic_metadata': dict(item['topic_metadata']), 'message_count': 0,
            })['message_count'] += item['message_count']

    def remove(self, name, file_metadata):
        """
        Remove the file ``name``: its entry, its messages and its topics' counts.

        Parameters
        ----------
        name : str
            A file listed.
        file_metadata : mapping
            The file's own metadata (:meth:`McapBagWriter.bag_metadata`, or its summary's:
            ``part_repair.finished_file_metadata``): what its topics count is subtracted;
            a topic left with no message is no longer listed.

        Raises
        ------
        ValueError
            ``name`` is not listed.
        """
        index = self.file_names.index(name)
        del self._files[index]
        for rendered in self._rendered.values():
            del rendered[index]
        self._message_count = sum(count for _, _, _, count in self._files)
        spans = [(start, start + duration) for _, start, duration, count in self._files
                 if count]
        self._start = min(start for start, _ in spans) if spans else None
        self._end = max(end for _, end in spans) if spans else None
        for item in file_metadata['topics_with_message_count']:
            topic = item['topic_metadata']['name']
            if topic in self._topics:
                self._topics[topic]['message_count'] -= item['message_count']
                if self._topics[topic]['message_count'] <= 0:
                    del self._topics[topic]

    def _head(self):
        start = self._start or 0
        return {
            **bag_metadata_head(start, (self._end or 0) - start, self._message_count,
                                [dict(item) for item in self._topics.values()]),
            'custom_data': dict(self._custom_data) if self._custom_data else None,
            'ros_distro': self._ros_distro,
        }

    def as_dict(self):
        """Return the rosbag2 ``BagMetadata`` mapping."""
        return {**self._head(), 'relative_file_paths': self.file_names,
                'files': [file_entry(*item) for item in self._files]}

    def _parts(self):
        """Return ``metadata.yaml``'s text in parts: the head rendered now, each file's lines."""
        parts = [dump_yaml({'rosbag2_bagfile_information': self._head()}), '\n']
        for key, rendered in self._rendered.items():
            parts += [f'  {key}:\n', *rendered] if rendered else [f'  {key}: []\n']
        return parts

    def text(self):
        """Return the text of ``metadata.yaml``."""
        return ''.join(self._parts())

    def write(self, directory):
        """Write ``directory/metadata.yaml`` atomically, part by part; return its path."""
        path = directory / METADATA_FILE
        write_text_atomically(path, self._parts())
        return path


def _indent(text):
    return ''.join(f'  {line}\n' for line in text.split('\n'))


def write_bag_metadata(directory, metadata):
    """Write ``directory/metadata.yaml`` atomically; return its path."""
    path = directory / METADATA_FILE
    write_text_atomically(path, dump_yaml({'rosbag2_bagfile_information': metadata}) + '\n')
    return path
