"""
Start the exciter for a robot's motor: a namespace, a params file, sim time, its topics.

    ros2 launch dcmotor_id exciter.launch.py [namespace:=NS] [params_file:=FILE]
        [input:=float64] [use_sim_time:=false] [voltage_command_topic:=voltage_command]
        [current_topic:=current] [speed_topic:=speed] [samples_topic:=samples]

Start and stop the routine with ``~/start`` and ``~/stop`` (std_srvs/Trigger). The topics
are remapped for the whole process (the exciter reads its measurements through a helper
node). The default params file, ``config/exciter_robot.yaml``, applies to an exciter in
any namespace.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    """Describe the exciter with its arguments."""
    config = os.path.join(get_package_share_directory('dcmotor_id'), 'config')
    arguments = [
        ('namespace', '', 'namespace of the exciter (the joint, say)'),
        ('params_file', os.path.join(config, 'exciter_robot.yaml'),
         'parameter file of the exciter'),
        ('input', 'float64', 'float64 (current, speed) or batch (samples)'),
        ('use_sim_time', 'false', 'true: the node runs on /clock'),
        ('voltage_command_topic', 'voltage_command', 'where the routine is commanded'),
        ('current_topic', 'current', 'the measured current (std_msgs/Float64)'),
        ('speed_topic', 'speed', 'the measured speed (std_msgs/Float64)'),
        ('samples_topic', 'samples', 'batch input: the batches'),
    ]
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text)
          for name, default, text in arguments],
        Node(package='dcmotor_id', executable='exciter', name='exciter',
             namespace=LaunchConfiguration('namespace'),
             parameters=[LaunchConfiguration('params_file'),
                         {'input': LaunchConfiguration('input'),
                          'use_sim_time': LaunchConfiguration('use_sim_time')}],
             remappings=[(topic, LaunchConfiguration(f'{topic}_topic'))
                         for topic in ('voltage_command', 'current', 'speed', 'samples')],
             output='screen'),
    ])
