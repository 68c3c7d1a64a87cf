"""
Start the identifier on a robot's joint: its topics, a namespace, a params file, sim time.

    ros2 launch dcmotor_id identifier.launch.py [namespace:=NS] [params_file:=FILE]
        [input:=joint_state] [joint_name:=NAME] [use_sim_time:=false]
        [joint_states_topic:=/joint_states] [voltage_topic:=voltage]
        [dynamic_joint_states_topic:=/dynamic_joint_states]

``input`` is ``joint_state`` (sensor_msgs/JointState: speed from velocity, current from
effort; the voltage as std_msgs/Float64), ``dynamic_joint_state`` (control_msgs/
DynamicJointState: the joint's interfaces ``current_interface``, ``voltage_interface``,
``speed_interface`` of the params file), ``float64`` or ``batch``. The joint-state and voltage
topics are remapped for the whole process (the identifier takes its samples through a
helper node that the remaps must reach too). The default params file,
``config/identifier_robot.yaml``, applies to an identifier in any namespace.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description():
    """Describe the identifier with its arguments."""
    config = os.path.join(get_package_share_directory('dcmotor_id'), 'config')
    arguments = [
        ('namespace', '', 'namespace of the identifier (the joint, say)'),
        ('params_file', os.path.join(config, 'identifier_robot.yaml'),
         'parameter file of the identifier'),
        ('input', 'joint_state', 'joint_state, dynamic_joint_state, float64 or batch'),
        ('joint_name', '', 'joint_state and dynamic_joint_state input: the joint ("" = the '
         'first)'),
        ('use_sim_time', 'false', 'true: the node runs on /clock (a replayed bag)'),
        ('joint_states_topic', '/joint_states', 'the sensor_msgs/JointState topic'),
        ('voltage_topic', 'voltage', 'the armature voltage (std_msgs/Float64)'),
        ('dynamic_joint_states_topic', '/dynamic_joint_states',
         'the control_msgs/DynamicJointState topic'),
    ]
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text)
          for name, default, text in arguments],
        Node(package='dcmotor_id', executable='identifier', name='identifier',
             namespace=LaunchConfiguration('namespace'),
             parameters=[LaunchConfiguration('params_file'),
                         {'input': LaunchConfiguration('input'),
                          'joint_name': LaunchConfiguration('joint_name'),
                          'use_sim_time': LaunchConfiguration('use_sim_time')}],
             remappings=[('joint_states', LaunchConfiguration('joint_states_topic')),
                         ('voltage', LaunchConfiguration('voltage_topic')),
                         ('dynamic_joint_states',
                          LaunchConfiguration('dynamic_joint_states_topic'))],
             output='screen'),
    ])
