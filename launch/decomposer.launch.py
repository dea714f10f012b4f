"""
Launch the decomposer on a cloud topic, with a parameter file and, optionally, RViz.

Usage (after ``colcon build`` and ``. install/setup.bash``)::

    ros2 launch mvbb_ros decomposer.launch.py cloud_in:=/camera/points
    ros2 launch mvbb_ros decomposer.launch.py cloud_in:=/segmented_object rviz:=true
    ros2 launch mvbb_ros decomposer.launch.py params_file:=/path/to/my_decomposer.yaml

Arguments: ``cloud_in`` (the input topic, remapped onto the node's ``cloud_in``),
``params_file`` (default: the package's ``config/decomposer.yaml``), ``use_sim_time``,
``rviz`` (start RViz with ``config/mvbb.rviz``; needs the ``rviz2`` package) and
``fixed_frame`` (RViz's fixed frame: the frame of your clouds).
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare


def generate_launch_description() -> LaunchDescription:
    """Return the decomposer node (and RViz when rviz:=true) with the launch arguments."""
    config = PathJoinSubstitution([FindPackageShare('mvbb_ros'), 'config'])
    arguments = [
        DeclareLaunchArgument(
            'cloud_in',
            default_value='/cloud_in',
            description='PointCloud2 topic of the segmented object (remapped onto cloud_in)',
        ),
        DeclareLaunchArgument(
            'params_file',
            default_value=PathJoinSubstitution([config, 'decomposer.yaml']),
            description='ROS parameter file of the decomposer (config/paper.yaml: the paper)',
        ),
        DeclareLaunchArgument(
            'use_sim_time', default_value='false', description='use /clock (bag replay)'
        ),
        DeclareLaunchArgument(
            'rviz', default_value='false', description='also start RViz with config/mvbb.rviz'
        ),
        DeclareLaunchArgument(
            'fixed_frame',
            default_value='camera_optical_frame',
            description="RViz's fixed frame: the frame_id of your clouds",
        ),
    ]
    decomposer = Node(
        package='mvbb_ros',
        executable='decomposer',
        name='decomposer',
        output='screen',
        parameters=[
            LaunchConfiguration('params_file'),
            {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)},
        ],
        remappings=[('cloud_in', LaunchConfiguration('cloud_in'))],
    )
    rviz = Node(
        package='rviz2',
        executable='rviz2',
        name='rviz2',
        output='screen',
        arguments=[
            '-d',
            PathJoinSubstitution([config, 'mvbb.rviz']),
            '--fixed-frame',
            LaunchConfiguration('fixed_frame'),
        ],
        parameters=[
            {'use_sim_time': ParameterValue(LaunchConfiguration('use_sim_time'), value_type=bool)}
        ],
        condition=IfCondition(LaunchConfiguration('rviz')),
    )
    return LaunchDescription([*arguments, decomposer, rviz])
