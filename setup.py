"""ament_python package cvt_ros (also pip-installable for venv use)."""
from glob import glob

from setuptools import find_packages, setup

package_name = 'cvt_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config/scenes', glob('config/scenes/*.yaml')),
        ('share/' + package_name + '/config/scenarios', glob('config/scenarios/*.yaml')),
        ('share/' + package_name + '/config/campaigns', glob('config/campaigns/*.yaml')),
        ('share/' + package_name + '/config/foxglove', glob('config/foxglove/*.json')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'PyYAML'],
    zip_safe=True,
    maintainer='cvt_ros developers',
    maintainer_email='dev@cvt-ros.invalid',
    description='Real-time virtual device of a mechanical pulse CVT for ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'cvt-sim = cvt_ros.cli:main',
            'cvt_node = cvt_ros.device.main:main',
            'cvt_speed_controller = cvt_ros.control.node:main',
            'cvt_linkage_markers = cvt_ros.control.markers:main',
        ],
        # the cvt_device fixture for users' controller tests (cvt_ros.testing)
        'pytest11': ['cvt_ros = cvt_ros.testing.plugin'],
    },
)
