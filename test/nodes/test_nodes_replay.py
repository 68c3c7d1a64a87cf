"""Parameter files, the launch file, and replay of a bag into the identifier."""

import ast
import math
import os
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger
import yaml

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.bag import write_bag
from dcmotor_id.nodes.identifier import Identifier, RESULT_KEYS
from dcmotor_id.nodes.replay import Replay
from dcmotor_id.nodes.sim_motor import SimMotor
from dcmotor_id.streaming.summary import format_line

pytestmark = pytest.mark.ros

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope='module')
def ros(ros_env):
    rclpy.init()
    yield
    rclpy.try_shutdown()


@pytest.mark.parametrize('node_class, name', [(SimMotor, 'sim_motor'),
                                              (Identifier, 'identifier')])
def test_parameter_file_documents_every_parameter_with_its_type(ros, node_class, name):
    path = os.path.join(ROOT, 'config', f'{name}.yaml')
    with open(path) as stream:
        text = stream.read()
    in_file = yaml.safe_load(text)[name]['ros__parameters']
    node = node_class(parameter_overrides=[Parameter('record_dir', value='/tmp/unused')]
                      if name == 'identifier' else [])
    try:
        declared = {key: parameter.value for key, parameter in node._parameters.items()
                    if key not in ('use_sim_time', 'start_type_description_service')
                    and not key.startswith('identified.')}
    finally:
        if hasattr(node, 'close'):
            node.close()
        node.destroy_node()
    assert set(in_file) == set(declared)
    for key, value in in_file.items():
        if key != 'record_dir':
            assert type(value) is type(declared[key]), key  # 2 vs 2.0 matters to ROS
            assert value == declared[key], key  # the file holds the defaults
        lines = text.splitlines()
        row = next(n for n, line in enumerate(lines) if line.strip().startswith(key + ':'))
        assert '#' in lines[row] or lines[row - 1].strip().startswith('#'), \
            f'{key} has no comment in {path}'


def test_launch_file_starts_the_nodes_with_their_parameter_files():
    path = os.path.join(ROOT, 'launch', 'dcmotor_id.launch.py')
    with open(path) as stream:
        tree = ast.parse(stream.read())
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call)
             and getattr(node.func, 'id', '') == 'Node']
    executables = {kw.value.value for call in calls for kw in call.keywords
                   if kw.arg == 'executable'}
    assert executables == {'sim_motor', 'identifier', 'exciter'}
    # The exciter (issue 13) starts only with exciter:=true; the other two always.
    conditional = {kw.value.value for call in calls for kw in call.keywords
                   if kw.arg == 'executable'
                   and any(other.arg == 'condition' for other in call.keywords)}
    assert conditional == {'exciter'}
    strings = {node.value for node in ast.walk(tree) if isinstance(node, ast.Constant)}
    assert {'sim_motor.yaml', 'identifier.yaml', 'exciter.yaml', 'dcmotor_id'} <= strings
    assert any(name == 'generate_launch_description' for name in
               (node.name for node in tree.body if isinstance(node, ast.FunctionDef)))


@pytest.mark.slow
def test_replayed_bag_is_identified_on_its_own_clock(ros, tmp_path):
    from dcmotor_id.simulation import simulate_motor
    from dcmotor_id.simulation.excitation import make_excitation

    dt = 1e-3
    _, voltage = make_excitation('paper', 8.0, dt)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, dt)
    stamps = 1_000_000_000_000 + np.arange(voltage.size) * 1_000_000
    bag = tmp_path / 'drive'
    write_bag(bag, stamps, {'voltage': voltage, 'current': current, 'speed': speed},
              topics={name: f'/replayed/{name}' for name in ('voltage', 'current', 'speed')})
    executor = SingleThreadedExecutor()
    ident = Identifier(namespace='replayed', parameter_overrides=[
        Parameter('use_sim_time', value=True), Parameter('window_s', value=8.0),
        Parameter('record_dir', value=str(tmp_path / 'windows'))])
    replay = Replay(parameter_overrides=[Parameter('bag', value=str(bag)),
                                         Parameter('start_delay_s', value=2.0)])
    client_node = rclpy.create_node('replay_client')
    for node in (ident, replay, client_node):
        executor.add_node(node)
    running = threading.Event()
    running.set()

    def spin():
        while running.is_set():
            executor.spin_once(timeout_sec=0.1)
    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        assert replay.done.wait(timeout=120.0)
        time.sleep(1.5)
        assert ident.aligner.stats.emitted == voltage.size, ident.aligner.stats
        # the identifier's clock followed /clock: its samples carry the bag's time
        assert abs(ident.cutter.anchor_ns - stamps[0]) < 0.2e9
        client = client_node.create_client(Trigger, '/replayed/identifier/identify')
        future = client.call_async(Trigger.Request())
        deadline = time.monotonic() + 120
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.05)
        response = future.result()
        assert response.success, response.message
        truth = PAPER_MOTORS['paper2'].as_dict()
        for key in RESULT_KEYS:
            value = ident.get_parameter(f'identified.{key}').value
            assert math.isclose(value, truth[key], rel_tol=1e-3), key
    finally:
        running.clear()
        thread.join(timeout=5)
        ident.close()
        for node in (ident, replay, client_node):
            executor.remove_node(node)
            node.destroy_node()


def test_joint_states_identify_the_mechanical_part(ros, tmp_path):
    """A drive that only publishes sensor_msgs/JointState (velocity, effort = current)."""
    from sensor_msgs.msg import JointState

    from dcmotor_id.simulation import simulate_motor
    from dcmotor_id.simulation.excitation import make_excitation

    dt = 1e-3
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('paper', 8.0, dt)
    current, speed = simulate_motor(params, voltage, dt)
    executor = SingleThreadedExecutor()
    ident = Identifier(namespace='drive', parameter_overrides=[
        Parameter('input', value='joint_state'), Parameter('torque_constant', value=params.CPhi),
        Parameter('joint_name', value='axis'), Parameter('window_s', value=8.0),
        Parameter('record_dir', value=str(tmp_path / 'windows'))])
    drive = rclpy.create_node('drive', namespace='drive')
    publisher = drive.create_publisher(JointState, 'joint_states', 5000)
    for node in (ident, drive):
        executor.add_node(node)
    try:
        deadline = time.monotonic() + 10
        while publisher.get_subscription_count() == 0 and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        start_ns = 1_000_000_000_000
        for k in range(voltage.size):
            message = JointState(name=['other', 'axis'], velocity=[0.0, float(speed[k])],
                                 effort=[0.0, float(current[k])], position=[0.0, 0.0])
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(
                start_ns + k * 1_000_000, 1_000_000_000)
            publisher.publish(message)
            if k % 500 == 499:
                executor.spin_once(timeout_sec=0.0)
                for _ in range(5):
                    executor.spin_once(timeout_sec=0.02)
        deadline = time.monotonic() + 20
        while ident.aligner.stats.emitted < voltage.size and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert ident.aligner.stats.emitted == voltage.size, ident.aligner.stats
        client = drive.create_client(Trigger, 'identifier/identify')
        future = client.call_async(Trigger.Request())
        deadline = time.monotonic() + 120
        while not future.done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert future.result().success, future.result().message
        for key in ('J', 'b', 'Mc'):
            value = ident.get_parameter(f'identified.{key}').value
            assert math.isclose(value, getattr(params, key), rel_tol=1e-3), key
        assert math.isnan(ident.get_parameter('identified.Ra').value)
    finally:
        ident.close()
        for node in (ident, drive):
            executor.remove_node(node)
            node.destroy_node()


def test_voltage_command_drives_the_motor_and_no_excitation_is_refused(ros, tmp_path):
    from std_msgs.msg import Float64

    executor = SingleThreadedExecutor()
    sim = SimMotor(namespace='cmd', parameter_overrides=[
        Parameter('use_voltage_command', value=True)])
    ident = Identifier(namespace='cmd', parameter_overrides=[
        Parameter('window_s', value=1.0), Parameter('record', value=False)])
    helper = rclpy.create_node('commander', namespace='cmd')
    command = helper.create_publisher(Float64, 'voltage_command', 10)
    voltages = []
    helper.create_subscription(Float64, 'voltage', lambda m: voltages.append(m.data), 5000)
    for node in (sim, ident, helper):
        executor.add_node(node)

    def spin_until(condition, timeout_s):
        deadline = time.monotonic() + timeout_s
        while not condition() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        return condition()
    try:
        # no command yet: 0 V, the motor stands still, identification is refused with why
        assert spin_until(lambda: ident.aligner.stats.emitted > 1500, 30.0)
        client = helper.create_client(Trigger, 'identifier/identify')
        future = client.call_async(Trigger.Request())
        assert spin_until(future.done, 120.0)
        assert not future.result().success
        assert 'never moves' in future.result().message
        assert set(voltages) == {0.0}
        assert spin_until(lambda: command.get_subscription_count() > 0, 10.0)
        command.publish(Float64(data=12.5))
        assert spin_until(lambda: voltages and voltages[-1] == 12.5, 10.0)
        assert sim.published > 0 and ident.aligner.stats.lost == 0
    finally:
        ident.close()
        for node in (sim, ident, helper):
            executor.remove_node(node)
            node.destroy_node()


def test_effects_are_reported_as_effect_keys_and_in_the_summary(ros, tmp_path):
    ident = Identifier(namespace='fx', parameter_overrides=[
        Parameter('record', value=False)])
    try:
        truth = PAPER_MOTORS['paper2'].as_dict()
        result = {'parameters': truth, 'stderr': dict.fromkeys(truth, 0.01),
                  'method': 'refined', 'n_samples': 1000, 'records': ['w'],
                  'error_after': {'current_nrmse_pct': 1.0, 'speed_nrmse_pct': 2.0},
                  'effects': [{'name': 'load_torque', 'parameters': {'torque_Nm': 0.25}},
                              {'name': 'backlash', 'parameters': {'side': 'both'}}],
                  'paper': None, 'bags': [], 'record_errors': []}
        result['summary'] = format_line(result)
        status = ident.result_status(result)
        values = {kv.key: kv.value for kv in status.values}
        assert values['effect.load_torque.torque_Nm'] == '0.25'
        assert values['effect.backlash.side'] == 'both'
        assert 'effects: load_torque torque_Nm=0.25; backlash side=both' in result['summary']
        assert [kv.key for kv in status.values][:16] == \
            list(RESULT_KEYS) + [f'{key}_stderr' for key in RESULT_KEYS]
    finally:
        ident.close()
        ident.destroy_node()


def hostile_bag(path, msgtype='unittest/__main__/Float64'):
    """Write a bag whose /voltage topic declares ``msgtype`` (a Float64 payload)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    connection = writer.add_connection('/voltage', msgtype, msgdef='float64 data',
                                       rihs01='RIHS01_' + '0' * 64)
    for k in range(10):
        writer.write(connection, 10 ** 9 + k * 10 ** 6,
                     b'\x00\x01\x00\x00' + struct.pack('<d', float(k)))
    writer.close()
    return path


def test_replay_refuses_a_bag_declaring_an_unknown_message_type(ros, tmp_path):
    """A bag chooses its type names: they are looked up, never imported."""
    bag = hostile_bag(tmp_path / 'hostile')
    before = set(sys.modules)
    with pytest.raises(ValueError) as caught:
        Replay(parameter_overrides=[Parameter('bag', value=str(bag))])
    message = str(caught.value)
    assert "'unittest/__main__/Float64' (topic /voltage) is not played" in message
    assert 'std_msgs/msg/Float64' in message and 'sensor_msgs/msg/JointState' in message
    assert not [name for name in set(sys.modules) - before if name.startswith('unittest')]
    assert 'unittest.__main__' not in sys.modules


def test_replay_executable_refuses_a_hostile_bag_without_running_it(ros_env, tmp_path):
    bag = hostile_bag(tmp_path / 'hostile')
    result = subprocess.run(
        [sys.executable, '-m', 'dcmotor_id.nodes.replay', '--ros-args', '-p', f'bag:={bag}'],
        env=ros_env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert "'unittest/__main__/Float64' (topic /voltage) is not played" in result.stderr
    assert 'Ran 0 tests' not in result.stdout + result.stderr  # unittest's CLI never ran


def mixed_bag(path, samples=50, broken=()):
    """
    Write a drive's bag as recorded with ``-a``: measurements and a 200 V voltage_command.

    Also a topic with an invalid name, and ``/current`` payloads truncated at ``broken``.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    connections = {topic: writer.add_connection(topic, 'std_msgs/msg/Float64',
                                                msgdef='float64 data',
                                                rihs01='RIHS01_' + '0' * 64)
                   for topic in ('/voltage', '/current', '/speed', '/voltage_command',
                                 '/bad topic name!!')}
    for k in range(samples):
        for topic, connection in connections.items():
            value = 200.0 if topic == '/voltage_command' else float(k)
            data = b'\x00\x01\x00\x00' + struct.pack('<d', value)
            if topic == '/current' and k in broken:
                data = data[:7]
            writer.write(connection, 10 ** 9 + k * 10 ** 6, data)
    writer.close()
    return path


def play(bag, *parameters):
    """Replay ``bag`` in-process; return what arrived on each topic (Float64 values)."""
    from std_msgs.msg import Float64

    executor = SingleThreadedExecutor()
    listener = rclpy.create_node('listener')
    seen = {topic: [] for topic in ('/voltage', '/current', '/speed', '/voltage_command')}
    for topic, values in seen.items():
        listener.create_subscription(Float64, topic, lambda m, v=values: v.append(m.data), 500)
    executor.add_node(listener)
    replay = Replay(parameter_overrides=[Parameter('bag', value=str(bag)),
                                         Parameter('start_delay_s', value=1.0), *parameters])
    executor.add_node(replay)
    try:
        deadline = time.monotonic() + 60
        while not replay.done.is_set() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        assert replay.done.is_set()
        quiet = time.monotonic() + 1.0  # take what is queued, until 1 s without any
        while time.monotonic() < quiet:
            count = sum(map(len, seen.values()))
            executor.spin_once(timeout_sec=0.05)
            if sum(map(len, seen.values())) > count:
                quiet = time.monotonic() + 1.0
        return replay, seen
    finally:
        for node in (replay, listener):
            executor.remove_node(node)
            node.destroy_node()


def test_replay_plays_only_the_measurements_unless_a_topic_is_named(ros, tmp_path):
    """Issue 21: a bag's voltage_command drove sim_motor at 200 V."""
    bag = mixed_bag(tmp_path / 'recorded')
    replay, seen = play(bag)
    assert set(replay._topic_publishers) == {'/voltage', '/current', '/speed'}
    assert seen['/voltage_command'] == []
    assert len(seen['/voltage']) == len(seen['/speed']) == 50
    replay, seen = play(bag, Parameter('extra_topics', value=['/voltage_command',
                                                              '/bad topic name!!']))
    assert set(replay._topic_publishers) == {'/voltage', '/current', '/speed',
                                             '/voltage_command'}
    assert seen['/voltage_command'] == [200.0] * 50


def test_replay_skips_malformed_payloads_and_counts_them(ros, tmp_path):
    bag = mixed_bag(tmp_path / 'damaged', broken=(3, 4, 40))
    replay, seen = play(bag)
    assert seen['/current'] == [float(k) for k in range(50) if k not in (3, 4, 40)]
    assert replay.published == 147


def test_replay_executable_skips_a_bad_topic_name_with_a_warning(ros_env, tmp_path):
    """Issue 21: a topic named '/bad topic name!!' crashed replay with a traceback."""
    bag = mixed_bag(tmp_path / 'recorded', broken=(7,))
    for extra in ([], ['--ros-args', '-p', 'extra_topics:=["/bad topic name!!"]']):
        result = subprocess.run(
            [sys.executable, '-m', 'dcmotor_id.nodes.replay', '--ros-args', '-p',
             f'bag:={bag}', '-p', 'start_delay_s:=0.0', *extra[1:]],
            env=ros_env, capture_output=True, text=True, timeout=120)
        output = result.stdout + result.stderr
        assert result.returncode == 0, output
        assert 'Traceback' not in output
        assert "topic '/bad topic name!!' skipped: not a valid ROS topic name" in output
        assert 'not played' in output or extra
        assert 'topic /current: 1 message(s) skipped, their payload is not a valid ' \
            'std_msgs/msg/Float64 (first at stamp 1007000000 ns)' in output, output
        assert 'done: 149 messages played' in output


def test_replay_says_why_nothing_can_be_played(ros, tmp_path):
    """Issue 30: undecodable payloads were "no message to play"; a bad prefix blamed the bag."""
    bag = mixed_bag(tmp_path / 'broken', samples=5)
    with pytest.raises(ValueError) as caught:
        Replay(parameter_overrides=[Parameter('bag', value=str(bag)),
                                    Parameter('topic_prefix', value='../bad name')])
    assert "parameter topic_prefix = '../bad name'" in str(caught.value)
    assert 'not a valid ROS topic name' in str(caught.value)
    from rosbags.rosbag2 import StoragePlugin, Writer
    path = tmp_path / 'undecodable'
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    connection = writer.add_connection('/voltage', 'std_msgs/msg/Float64',
                                       msgdef='float64 data', rihs01='RIHS01_' + '0' * 64)
    for k in range(5):
        writer.write(connection, 10 ** 9 + k * 10 ** 6, b'\x00\x01\x00')
    writer.close()
    with pytest.raises(ValueError) as caught:
        Replay(parameter_overrides=[Parameter('bag', value=str(path))])
    assert 'nothing of the bag' in str(caught.value)
    assert 'topic /voltage: 5 message(s) skipped, their payload is not a valid' \
        in str(caught.value)
