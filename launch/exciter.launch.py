"""
Start the exciter for a robot's motor: a namespace, a params file, sim time, its topics.

    ros2 launch dcmotor_id exciter.launch.py [namespace:=NS] [params_file:=FILE]
        [input:=float64] [use_sim_time:=false] [voltage_command_topic:=voltage_command]
        [current_topic:=current] [speed_topic:=speed] [samples_topic:=samples]
        [joint_states_topic:=/joint_states] [joint_name:=NAME]
        [command_type:=float64] [command_topic:=voltage_command]
        [joint_index:=0] [joint_count:=1]

On a ros2_control robot: ``input:=joint_state joint_name:=J
command_type:=forward_command_controller command_topic:=/<controller>/commands
joint_index:=I joint_count:=N`` (the voltage at index I of the controller's N values).

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
        ('input', 'float64', 'float64 (current, speed), batch (samples) or joint_state'),
        ('joint_name', '', 'joint_state input: the joint watched ("" = the first)'),
        ('command_type', 'float64', 'float64 or forward_command_controller'),
        ('command_topic', 'voltage_command', 'where the commands go'),
        ('joint_index', '0', 'forward_command_controller: the motor among its joints'),
        ('joint_count', '1', 'forward_command_controller: the joints it commands'),
        ('use_sim_time', 'false', 'true: the node runs on /clock'),
        ('voltage_command_topic', 'voltage_command', 'where the routine is commanded'),
        ('current_topic', 'current', 'the measured current (std_msgs/Float64)'),
        ('speed_topic', 'speed', 'the measured speed (std_msgs/Float64)'),
        ('samples_topic', 'samples', 'batch input: the batches'),
        ('joint_states_topic', '/joint_states', 'joint_state input: sensor_msgs/JointState'),
    ]
    return LaunchDescription([
        *[DeclareLaunchArgument(name, default_value=default, description=text)
          for name, default, text in arguments],
        Node(package='dcmotor_id', executable='exciter', name='exciter',
             namespace=LaunchConfiguration('namespace'),
             parameters=[LaunchConfiguration('params_file'),
                         {name: LaunchConfiguration(name) for name in (
                             'input', 'use_sim_time', 'joint_name', 'command_type',
                             'command_topic', 'joint_index', 'joint_count')}],
             remappings=[(topic, LaunchConfiguration(f'{topic}_topic'))
                         for topic in ('voltage_command', 'current', 'speed', 'samples',
                                       'joint_states')],
             output='screen'),
    ])
