from glob import glob
from pathlib import Path
import xml.etree.ElementTree as ET

from setuptools import find_packages, setup

package_name = 'qfa_ros'
# The one version of the release: package.xml's (qfa_ros.__version__ and CHANGELOG.rst
# follow it; test/test_package.py checks them).
version = ET.parse(Path(__file__).with_name('package.xml')).getroot().findtext('version')

setup(
    name=package_name,
    version=version,
    packages=find_packages(exclude=['test']),
    # Kilted's .msg texts the recorder embeds in every bag (qfa_ros/bag/msgdefs.py).
    package_data={'qfa_ros.bag': ['definitions/*/msg/*.msg']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='qfa_ros developers',
    maintainer_email='qfa-ros@example.com',
    description='Emulated self-calibrating IMU of digital closed-loop quartz flexible '
                'accelerometers (QFA) for ROS 2.',
    license='Apache-2.0',
    # requirements/*.txt pin them; `make run` installs base.txt only, `make setup` all.
    extras_require={'tools': ['matplotlib', 'dask', 'distributed', 'pyarrow'],
                    'test': ['pytest', 'pytest-timeout', 'ruff', 'import-linter', 'allantools',
                             'hypothesis']},
    entry_points={
        'console_scripts': [
            'qfa-sim = qfa_ros.cli.sim:main',
            # One name per program in lib/qfa_ros: the node with ROS's underscore
            # (ros2 run qfa_ros qfa_node), the offline tools with their documented names.
            'qfa_node = qfa_ros.cli.node:main',
            'qfa_lifecycle_node = qfa_ros.cli.node:lifecycle_main',
            'qfa-replay = qfa_ros.cli.replay:main',
            'qfa-report = qfa_ros.cli.report:main',
            'qfa-fleet = qfa_ros.cli.fleet:main',
        ],
    },
)
