"""ament_python package definition of mvbb_ros."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'mvbb_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    package_data={package_name: ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml', 'LICENSE']),
        (
            'share/' + package_name + '/config',
            glob('config/*.yaml') + glob('config/*.rviz') + glob('config/*.xml'),
        ),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    python_requires='>=3.10',
    zip_safe=True,
    maintainer='mvbb_ros developers',
    maintainer_email='mvbb_ros@example.com',
    description='Minimum-volume bounding box decomposition and grasp hypotheses for ROS 2.',
    license='Apache-2.0',
    license_files=['LICENSE'],
    extras_require={'test': ['pytest', 'hypothesis']},
    entry_points={
        'console_scripts': [
            'decomposer = mvbb_ros.ros.decomposer:main',
            'mvbb = mvbb_ros.cli.main:main',
        ],
    },
)
