"""
The robot launch files, loaded with a stand-in of launch and launch_ros (issue 32).

``launch`` and ``launch_ros`` have no wheels here: the files are executed against stand-in
modules that record the actions they describe, and the parameter files they load by
default are given to real nodes (rclpy is real) in a namespace.
"""

import importlib.util
import os
import sys
import types

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class Recorded:
    """An action or substitution of the stand-in: its class name and its arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs

    def __repr__(self):
        return f'{type(self).__name__}({self.args}, {self.kwargs})'


def stand_in_modules():
    """Return stand-in modules for launch, launch_ros and ament_index_python."""
    def module(name, **names):
        made = types.ModuleType(name)
        made.__dict__.update(names)
        return made

    def kind(name):
        return type(name, (Recorded,), {})

    share = os.path.join('/opt/share', 'dcmotor_id')
    return {
        'launch': module('launch', LaunchDescription=kind('LaunchDescription')),
        'launch.actions': module('launch.actions',
                                 DeclareLaunchArgument=kind('DeclareLaunchArgument')),
        'launch.conditions': module('launch.conditions', IfCondition=kind('IfCondition')),
        'launch.substitutions': module('launch.substitutions',
                                       LaunchConfiguration=kind('LaunchConfiguration'),
                                       PythonExpression=kind('PythonExpression')),
        'launch_ros': module('launch_ros'),
        'launch_ros.actions': module('launch_ros.actions', Node=kind('Node')),
        'ament_index_python': module('ament_index_python'),
        'ament_index_python.packages': module(
            'ament_index_python.packages', get_package_share_directory=lambda name: share),
    }


def describe(name, monkeypatch):
    """Load ``launch/<name>`` against the stand-ins; return (arguments, nodes)."""
    for module_name, module in stand_in_modules().items():
        monkeypatch.setitem(sys.modules, module_name, module)
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, 'launch', name))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    actions = description.args[0]
    arguments = {action.args[0]: action.kwargs['default_value'] for action in actions
                 if type(action).__name__ == 'DeclareLaunchArgument'}
    nodes = [action for action in actions if type(action).__name__ == 'Node']
    return arguments, nodes


def configuration(value):
    """Return the launch argument a LaunchConfiguration stands for (else the value)."""
    return value.args[0] if type(value).__name__ == 'LaunchConfiguration' else value


@pytest.mark.parametrize('name, executable, remapped', [
    ('identifier.launch.py', 'identifier', {'joint_states', 'voltage', 'dynamic_joint_states'}),
    ('exciter.launch.py', 'exciter', {'voltage_command', 'current', 'speed', 'samples',
                                      'joint_states'})])
def test_a_robot_launch_file_takes_namespace_params_input_sim_time_and_remaps(
        name, executable, remapped, monkeypatch):
    arguments, nodes = describe(name, monkeypatch)
    assert {'namespace', 'params_file', 'input', 'use_sim_time'} <= set(arguments)
    assert arguments['use_sim_time'] == 'false'
    assert arguments['params_file'].endswith(f'config/{executable}_robot.yaml')
    assert os.path.isfile(os.path.join(ROOT, 'config', f'{executable}_robot.yaml'))
    (node,) = nodes
    assert node.kwargs['executable'] == executable and node.kwargs['package'] == 'dcmotor_id'
    assert configuration(node.kwargs['namespace']) == 'namespace'
    params_file, overrides = node.kwargs['parameters']
    assert configuration(params_file) == 'params_file'
    assert {key: configuration(value) for key, value in overrides.items()}.items() >= {
        'input': 'input', 'use_sim_time': 'use_sim_time'}.items()
    remaps = {source: configuration(target) for source, target in node.kwargs['remappings']}
    assert set(remaps) == remapped
    for source, argument in remaps.items():
        assert argument == f'{source}_topic' and argument in arguments


def test_the_simulated_demo_launch_still_starts_sim_motor(monkeypatch):
    _, nodes = describe('dcmotor_id.launch.py', monkeypatch)
    assert {node.kwargs['executable'] for node in nodes} == {
        'sim_motor', 'identifier', 'exciter'}


@pytest.mark.ros
def test_the_robot_params_file_reaches_an_identifier_in_a_namespace(ros_env):
    import rclpy

    from dcmotor_id.nodes.identifier import Identifier

    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file',
                                      os.path.join(ROOT, 'config', 'identifier_robot.yaml')])
    try:
        node = Identifier(namespace='left_wheel', context=context, parameter_overrides=[
            rclpy.parameter.Parameter('record', value=False)])
        try:
            assert node.settings.input == 'joint_state'
            assert node.settings.sample_rate_hz == 500.0
        finally:
            node.close()
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def test_the_exciter_launch_takes_the_forward_command_controller_settings(monkeypatch):
    arguments, (node,) = describe('exciter.launch.py', monkeypatch)
    _, overrides = node.kwargs['parameters']
    for name in ('command_type', 'command_topic', 'joint_index', 'joint_count', 'joint_name'):
        assert name in arguments and configuration(overrides[name]) == name
