"""
Start the simulated drive and the identifier with their parameter files.

    ros2 launch dcmotor_id dcmotor_id.launch.py [record_dir:=DIR] [transport:=batch]
        [exciter:=true]

``transport:=batch`` switches both nodes to the batched Float64MultiArray transport.
``exciter:=true`` also starts the ``exciter`` node and lets ``sim_motor`` follow its
``voltage_command`` (start it with ``/exciter/start``, a std_srvs/Trigger).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node


def generate_launch_description():
    """Describe sim_motor, identifier and (with exciter:=true) the exciter."""
    config = os.path.join(get_package_share_directory('dcmotor_id'), 'config')
    transport = LaunchConfiguration('transport')
    identifier_input = PythonExpression(["'batch' if '", transport,
                                         "' == 'batch' else 'float64'"])
    return LaunchDescription([
        DeclareLaunchArgument('transport', default_value='float64',
                              description='float64 or batch'),
        DeclareLaunchArgument('record_dir', default_value='~/.ros/dcmotor_id/windows',
                              description='where the identifier writes its window bags'),
        DeclareLaunchArgument('exciter', default_value='false',
                              description='true: start the exciter; sim_motor follows it'),
        Node(package='dcmotor_id', executable='sim_motor', name='sim_motor',
             parameters=[os.path.join(config, 'sim_motor.yaml'),
                         {'transport': transport,
                          'use_voltage_command': LaunchConfiguration('exciter')}],
             output='screen'),
        Node(package='dcmotor_id', executable='exciter', name='exciter',
             parameters=[os.path.join(config, 'exciter.yaml'),
                         {'input': identifier_input}],
             condition=IfCondition(LaunchConfiguration('exciter')), output='screen'),
        Node(package='dcmotor_id', executable='identifier', name='identifier',
             parameters=[os.path.join(config, 'identifier.yaml'),
                         {'input': identifier_input,
                          'record_dir': LaunchConfiguration('record_dir')}],
             output='screen'),
    ])
