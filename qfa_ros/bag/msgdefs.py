"""Embedded ROS 2 message definitions (ros2msg) and type hashes for the recorder.

The own text of every Kilted ``.msg`` file the recorder needs (from the ``ros-*-msgs``
wheels), composed into the full definitions the way rosbag2's local message
definition source does it: the root text, then for every dependency, depth first in
sorted order and each only once, a line of 80 ``=``, ``MSG: pkg/Name`` and its text,
the blocks joined by newlines. The recorder therefore needs no ROS installation to
write self-describing bags. ``test/test_recorder.py`` checks the composed texts
against the installed files when those are present.
"""

import re

_JOIN = '\n' + '=' * 80 + '\n'
PRIMITIVE_TYPES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8',
                         'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string',
                         'wstring'})

MESSAGE_TEXTS = {
    'builtin_interfaces/msg/Time': (
        '# This message communicates ROS Time defined here:\n'
        '# https://design.ros2.org/articles/clock_and_time.html\n'
        '\n'
        '# The seconds component, valid over all int32 values.\n'
        'int32 sec\n'
        '\n'
        '# The nanoseconds component, valid in the range [0, 1e9).\n'
        'uint32 nanosec\n'
    ),
    'diagnostic_msgs/msg/DiagnosticArray': (
        '# This message is used to send diagnostic information about the state of the robot.\n'
        'std_msgs/Header header # for timestamp\n'
        'DiagnosticStatus[] status # an array of components being reported on\n'
    ),
    'diagnostic_msgs/msg/DiagnosticStatus': (
        '# This message holds the status of an individual component of the robot.\n'
        '\n'
        '# Possible levels of operations.\n'
        'byte OK=0\n'
        'byte WARN=1\n'
        'byte ERROR=2\n'
        'byte STALE=3\n'
        '\n'
        '# Level of operation enumerated above.\n'
        'byte level\n'
        '# A description of the test/component reporting.\n'
        'string name\n'
        '# A description of the status.\n'
        'string message\n'
        '# A hardware unique string.\n'
        'string hardware_id\n'
        '# An array of values associated with the status.\n'
        'KeyValue[] values\n'
        '\n'
    ),
    'diagnostic_msgs/msg/KeyValue': (
        '# What to label this value when viewing.\n'
        'string key\n'
        '# A value to track over time.\n'
        'string value\n'
    ),
    'geometry_msgs/msg/Accel': (
        '# This expresses acceleration in free space broken into its linear and angular parts.\n'
        'Vector3  linear\n'
        'Vector3  angular\n'
    ),
    'geometry_msgs/msg/AccelStamped': (
        '# An accel with reference coordinate frame and timestamp\n'
        'std_msgs/Header header\n'
        'Accel accel\n'
    ),
    'geometry_msgs/msg/Quaternion': (
        '# This represents an orientation in free space in quaternion form.\n'
        '\n'
        'float64 x 0\n'
        'float64 y 0\n'
        'float64 z 0\n'
        'float64 w 1\n'
    ),
    'geometry_msgs/msg/Vector3': (
        '# This represents a vector in free space.\n'
        '\n'
        '# This is semantically different than a point.\n'
        '# A vector is always anchored at the origin.\n'
        '# When a transform is applied to a vector, only the rotational component is applied.\n'
        '\n'
        'float64 x\n'
        'float64 y\n'
        'float64 z\n'
    ),
    'geometry_msgs/msg/Vector3Stamped': (
        '# This represents a Vector3 with reference coordinate frame and timestamp\n'
        '\n'
        '# Note that this follows vector semantics with it always anchored at the origin,\n'
        '# so the rotational elements of a transform are the only parts applied when'
        ' transforming.\n'
        '\n'
        'std_msgs/Header header\n'
        'Vector3 vector\n'
    ),
    'rosgraph_msgs/msg/Clock': (
        '# This message communicates the current time.\n'
        '#\n'
        '# For more information, see https://design.ros2.org/articles/clock_and_time.html.\n'
        'builtin_interfaces/Time clock\n'
    ),
    'sensor_msgs/msg/Imu': (
        '# This is a message to hold data from an IMU (Inertial Measurement Unit)\n'
        '#\n'
        "# Accelerations should be in m/s^2 (not in g's), and rotational velocity should"
        ' be in rad/sec\n'
        '#\n'
        '# If the covariance of the measurement is known, it should be filled in (if all'
        ' you know is the\n'
        '# variance of each measurement, e.g. from the datasheet, just put those along'
        ' the diagonal)\n'
        '# A covariance matrix of all zeros will be interpreted as "covariance unknown",'
        ' and to use the\n'
        '# data a covariance will have to be assumed or gotten from some other source\n'
        '#\n'
        "# If you have no estimate for one of the data elements (e.g. your IMU doesn't"
        ' produce an\n'
        '# orientation estimate), please set element 0 of the associated covariance matrix to -1\n'
        '# If you are interpreting this message, please check for a value of -1 in the'
        ' first element of each\n'
        '# covariance matrix, and disregard the associated estimate.\n'
        '\n'
        'std_msgs/Header header\n'
        '\n'
        'geometry_msgs/Quaternion orientation\n'
        'float64[9] orientation_covariance # Row major about x, y, z axes\n'
        '\n'
        'geometry_msgs/Vector3 angular_velocity\n'
        'float64[9] angular_velocity_covariance # Row major about x, y, z axes\n'
        '\n'
        'geometry_msgs/Vector3 linear_acceleration\n'
        'float64[9] linear_acceleration_covariance # Row major x, y z\n'
    ),
    'sensor_msgs/msg/NavSatFix': (
        '# Navigation Satellite fix for any Global Navigation Satellite System\n'
        '#\n'
        '# Specified using the WGS 84 reference ellipsoid\n'
        '\n'
        '# header.stamp specifies the ROS time for this measurement (the\n'
        '#        corresponding satellite time may be reported using the\n'
        '#        sensor_msgs/TimeReference message).\n'
        '#\n'
        '# header.frame_id is the frame of reference reported by the satellite\n'
        '#        receiver, usually the location of the antenna.  This is a\n'
        '#        Euclidean frame relative to the vehicle, not a reference\n'
        '#        ellipsoid.\n'
        'std_msgs/Header header\n'
        '\n'
        '# Satellite fix status information.\n'
        'NavSatStatus status\n'
        '\n'
        '# Latitude [degrees]. Positive is north of equator; negative is south.\n'
        'float64 latitude\n'
        '\n'
        '# Longitude [degrees]. Positive is east of prime meridian; negative is west.\n'
        'float64 longitude\n'
        '\n'
        '# Altitude [m]. Positive is above the WGS 84 ellipsoid\n'
        '# (quiet NaN if no altitude is available).\n'
        'float64 altitude\n'
        '\n'
        '# Position covariance [m^2] defined relative to a tangential plane\n'
        '# through the reported position. The components are East, North, and\n'
        '# Up (ENU), in row-major order.\n'
        '#\n'
        '# Beware: this coordinate system exhibits singularities at the poles.\n'
        'float64[9] position_covariance\n'
        '\n'
        '# If the covariance of the fix is known, fill it in completely. If the\n'
        '# GPS receiver provides the variance of each measurement, put them\n'
        '# along the diagonal. If only Dilution of Precision is available,\n'
        '# estimate an approximate covariance from that.\n'
        '\n'
        'uint8 COVARIANCE_TYPE_UNKNOWN = 0\n'
        'uint8 COVARIANCE_TYPE_APPROXIMATED = 1\n'
        'uint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2\n'
        'uint8 COVARIANCE_TYPE_KNOWN = 3\n'
        '\n'
        'uint8 position_covariance_type\n'
    ),
    'sensor_msgs/msg/NavSatStatus': (
        '# Navigation Satellite fix status for any Global Navigation Satellite System.\n'
        '#\n'
        '# Whether to output an augmented fix is determined by both the fix\n'
        '# type and the last time differential corrections were received.  A\n'
        '# fix is valid when status >= STATUS_FIX.\n'
        '\n'
        'int8 STATUS_UNKNOWN = -2        # status is not yet set\n'
        'int8 STATUS_NO_FIX =  -1        # unable to fix position\n'
        'int8 STATUS_FIX =      0        # unaugmented fix\n'
        'int8 STATUS_SBAS_FIX = 1        # with satellite-based augmentation\n'
        'int8 STATUS_GBAS_FIX = 2        # with ground-based augmentation\n'
        '\n'
        'int8 status -2 # STATUS_UNKNOWN\n'
        '\n'
        '# Bits defining which Global Navigation Satellite System signals were\n'
        '# used by the receiver.\n'
        '\n'
        'uint16 SERVICE_UNKNOWN = 0  # Remember service is a bitfield, so checking'
        ' (service & SERVICE_UNKNOWN) will not work. Use == instead.\n'
        'uint16 SERVICE_GPS =     1\n'
        'uint16 SERVICE_GLONASS = 2\n'
        'uint16 SERVICE_COMPASS = 4      # includes BeiDou.\n'
        'uint16 SERVICE_GALILEO = 8\n'
        '\n'
        'uint16 service\n'
    ),
    'sensor_msgs/msg/Temperature': (
        '# Single temperature reading.\n'
        '\n'
        'std_msgs/Header header # timestamp is the time the temperature was measured\n'
        '                             # frame_id is the location of the temperature reading\n'
        '\n'
        'float64 temperature          # Measurement of the Temperature in Degrees Celsius.\n'
        '\n'
        'float64 variance             # 0 is interpreted as variance unknown.\n'
    ),
    'std_msgs/msg/Bool': (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in'
        ' example_msgs.\n'
        '\n'
        'bool data\n'
    ),
    'std_msgs/msg/Float64': (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in'
        ' example_msgs.\n'
        '\n'
        'float64 data\n'
    ),
    'std_msgs/msg/Float64MultiArray': (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in'
        ' example_msgs.\n'
        '\n'
        '# Please look at the MultiArrayLayout message definition for\n'
        '# documentation on all multiarrays.\n'
        '\n'
        'MultiArrayLayout  layout        # specification of data layout\n'
        'float64[]         data          # array of data\n'
    ),
    'std_msgs/msg/Header': (
        '# Standard metadata for higher-level stamped data types.\n'
        '# This is generally used to communicate timestamped data\n'
        '# in a particular coordinate frame.\n'
        '\n'
        '# Two-integer timestamp that is expressed as seconds and nanoseconds.\n'
        'builtin_interfaces/Time stamp\n'
        '\n'
        '# Transform frame with which this data is associated.\n'
        'string frame_id\n'
    ),
    'std_msgs/msg/MultiArrayDimension': (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in'
        ' example_msgs.\n'
        '\n'
        'string label   # label of given dimension\n'
        'uint32 size    # size of given dimension (in type units)\n'
        'uint32 stride  # stride of given dimension\n'
    ),
    'std_msgs/msg/MultiArrayLayout': (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in'
        ' example_msgs.\n'
        '\n'
        '# The multiarray declares a generic multi-dimensional array of a\n'
        '# particular data type.  Dimensions are ordered from outer most\n'
        '# to inner most.\n'
        '#\n'
        '# Accessors should ALWAYS be written in terms of dimension stride\n'
        '# and specified outer-most dimension first.\n'
        '#\n'
        '# multiarray(i,j,k) = data[data_offset + dim_stride[1]*i + dim_stride[2]*j + k]\n'
        '#\n'
        '# A standard, 3-channel 640x480 image with interleaved color channels\n'
        '# would be specified as:\n'
        '#\n'
        '# dim[0].label  = "height"\n'
        '# dim[0].size   = 480\n'
        '# dim[0].stride = 3*640*480 = 921600  (note dim[0] stride is just size of image)\n'
        '# dim[1].label  = "width"\n'
        '# dim[1].size   = 640\n'
        '# dim[1].stride = 3*640 = 1920\n'
        '# dim[2].label  = "channel"\n'
        '# dim[2].size   = 3\n'
        '# dim[2].stride = 3\n'
        '#\n'
        '# multiarray(i,j,k) refers to the ith row, jth column, and kth channel.\n'
        '\n'
        'MultiArrayDimension[] dim # Array of dimension properties\n'
        'uint32 data_offset        # padding bytes at front of data\n'
    ),
    'std_msgs/msg/String': (
        '# This was originally provided as an example message.\n'
        '# It is deprecated as of Foxy\n'
        '# It is recommended to create your own semantically meaningful message.\n'
        '# However if you would like to continue using this please use the equivalent in'
        ' example_msgs.\n'
        '\n'
        'string data\n'
    ),
    'geometry_msgs/msg/Point': (
        '# This contains the position of a point in free space\n'
        'float64 x\n'
        'float64 y\n'
        'float64 z\n'
    ),
    'geometry_msgs/msg/Pose': (
        '# A representation of pose in free space, composed of position and orientation.\n'
        '\n'
        'Point position\n'
        'Quaternion orientation\n'
    ),
    'geometry_msgs/msg/PoseWithCovariance': (
        '# This represents a pose in free space with uncertainty.\n'
        '\n'
        'Pose pose\n'
        '\n'
        '# Row-major representation of the 6x6 covariance matrix\n'
        '# The orientation parameters use a fixed-axis representation.\n'
        '# In order, the parameters are:\n'
        '# (x, y, z, rotation about X axis, rotation about Y axis, rotation about Z axis)\n'
        'float64[36] covariance\n'
    ),
    'geometry_msgs/msg/Twist': (
        '# This expresses velocity in free space broken into its linear and angular parts.\n'
        '\n'
        'Vector3  linear\n'
        'Vector3  angular\n'
    ),
    'geometry_msgs/msg/TwistWithCovariance': (
        '# This expresses velocity in free space with uncertainty.\n'
        '\n'
        'Twist twist\n'
        '\n'
        '# Row-major representation of the 6x6 covariance matrix\n'
        '# The orientation parameters use a fixed-axis representation.\n'
        '# In order, the parameters are:\n'
        '# (x, y, z, rotation about X axis, rotation about Y axis, rotation about Z axis)\n'
        'float64[36] covariance\n'
    ),
    'nav_msgs/msg/Odometry': (
        '# This represents an estimate of a position and velocity in free space.\n'
        '# The pose in this message should be specified in the coordinate frame given by'
        ' header.frame_id\n'
        '# The twist in this message should be specified in the coordinate frame given by the'
        ' child_frame_id\n'
        '\n'
        '# Includes the frame id of the pose parent.\n'
        'std_msgs/Header header\n'
        '\n'
        '# Frame id the pose points to. The twist is in this coordinate frame.\n'
        'string child_frame_id\n'
        '\n'
        '# Estimated pose that is typically relative to a fixed world frame.\n'
        'geometry_msgs/PoseWithCovariance pose\n'
        '\n'
        '# Estimated linear and angular velocity relative to child_frame_id.\n'
        'geometry_msgs/TwistWithCovariance twist\n'
    ),
}
"""Own text of each message definition, without its dependencies."""


def dependencies(msgtype):
    """Return the sorted message types the fields of ``msgtype`` use directly."""
    package = msgtype.split('/')[0]
    found = set()
    for line in MESSAGE_TEXTS[msgtype].splitlines():
        words = line.split('#')[0].split()
        if len(words) < 2 or '=' in words[1]:  # comment, blank or constant
            continue
        base = re.sub(r'(\[.*\]|<=\d+)$', '', words[0])
        if base in PRIMITIVE_TYPES:
            continue
        owner, short = base.split('/') if '/' in base else (package, base)
        found.add(f'{owner}/msg/{short}')
    return sorted(found)


def compose_definition(msgtype):
    """Return the full ros2msg definition of ``msgtype`` as rosbag2 writes it."""
    order = []

    def visit(name):
        for dependency in dependencies(name):
            if dependency not in order:
                order.append(dependency)
                visit(dependency)

    visit(msgtype)
    blocks = [f"MSG: {name.replace('/msg/', '/')}\n{MESSAGE_TEXTS[name]}" for name in order]
    return _JOIN.join([MESSAGE_TEXTS[msgtype]] + blocks)


MESSAGE_DEFINITIONS = {name: compose_definition(name) for name in (
    'builtin_interfaces/msg/Time',
    'diagnostic_msgs/msg/DiagnosticArray',
    'diagnostic_msgs/msg/DiagnosticStatus',
    'diagnostic_msgs/msg/KeyValue',
    'geometry_msgs/msg/AccelStamped',
    'geometry_msgs/msg/Vector3Stamped',
    'nav_msgs/msg/Odometry',
    'rosgraph_msgs/msg/Clock',
    'sensor_msgs/msg/Imu',
    'sensor_msgs/msg/NavSatFix',
    'sensor_msgs/msg/Temperature',
    'std_msgs/msg/Bool',
    'std_msgs/msg/Float64',
    'std_msgs/msg/Float64MultiArray',
    'std_msgs/msg/Header',
    'std_msgs/msg/String',
)}
"""Full definition of every type the recorder writes."""

TYPE_HASHES = {
    'builtin_interfaces/msg/Time':
        'RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197',
    'diagnostic_msgs/msg/DiagnosticArray':
        'RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e',
    'diagnostic_msgs/msg/DiagnosticStatus':
        'RIHS01_b0e3e692ea2d54a8af2f4ef1930e81556a2db55216b771f8a7d2724ed47bf0e4',
    'diagnostic_msgs/msg/KeyValue':
        'RIHS01_d68081eaa540288c5440753baecef0c4e16e81a5f78ad68902ded5100413bb42',
    'geometry_msgs/msg/AccelStamped':
        'RIHS01_ef1df9eabae0a708cc049a061ebcddc4e2a5f745730100ba680e086a9698b165',
    'geometry_msgs/msg/Vector3Stamped':
        'RIHS01_d4829622288cbb443886e7ea94ea5671a3b1be6bab4ad04224432a65f7d7887a',
    'nav_msgs/msg/Odometry':
        'RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0',
    'rosgraph_msgs/msg/Clock':
        'RIHS01_692f7a66e93a3c83e71765d033b60349ba68023a8c689a79e48078bcb5c58564',
    'sensor_msgs/msg/Imu':
        'RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b',
    'sensor_msgs/msg/NavSatFix':
        'RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404',
    'sensor_msgs/msg/NavSatStatus':
        'RIHS01_d1ed3befa628e09571bd273b888ba1c1fd187c9a5e0006b385d7e5e9095a3204',
    'sensor_msgs/msg/Temperature':
        'RIHS01_72514a14126ab9f8a9abec974c78e5610a367b59db5da355ff1fb982d5bad4b8',
    'std_msgs/msg/Bool':
        'RIHS01_feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9',
    'std_msgs/msg/Float64':
        'RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a',
    'std_msgs/msg/Float64MultiArray':
        'RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f',
    'std_msgs/msg/Header':
        'RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01',
    'std_msgs/msg/String':
        'RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18',
}
