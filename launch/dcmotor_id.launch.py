"""
Start the simulated drive and the identifier with their parameter files.

    ros2 launch dcmotor_id dcmotor_id.launch.py [record_dir:=DIR] [transport:=batch]

``transport:=batch`` switches both nodes to the batched Float64MultiArray transport.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node


def generate_launch_description():
    """Describe sim_motor and identifier, sharing the sample topics."""
    config = os.path.join(get_package_share_directory('dcmotor_id'), 'config')
    transport = LaunchConfiguration('transport')
    identifier_input = PythonExpression(["'batch' if '", transport,
                                         "' == 'batch' else 'float64'"])
    return LaunchDescription([
        DeclareLaunchArgument('transport', default_value='float64',
                              description='float64 or batch'),
        DeclareLaunchArgument('record_dir', default_value='~/.ros/dcmotor_id/windows',
                              description='where the identifier writes its window bags'),
        Node(package='dcmotor_id', executable='sim_motor', name='sim_motor',
             parameters=[os.path.join(config, 'sim_motor.yaml'),
                         {'transport': transport}],
             output='screen'),
        Node(package='dcmotor_id', executable='identifier', name='identifier',
             parameters=[os.path.join(config, 'identifier.yaml'),
                         {'input': identifier_input,
                          'record_dir': LaunchConfiguration('record_dir')}],
             output='screen'),
    ])
