"""
The exciter through a ros2_control forward command controller (issue 32).

A stand-in of the controller subscribes to the Float64MultiArray commands, drives a
first-order motor with the command at the exciter's joint index and publishes the joints'
velocities on ``joint_states``; the exciter watches its joint's velocity there. Every stop
(over-speed, a non-finite velocity, stale joint states, ``~/stop``, the end of the routine)
commands 0 at the joint's index, and the time from the fault to that zero is measured.
"""

import threading
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from support import remove_nodes, wait_for

from dcmotor_id.nodes.exciter import Exciter

pytestmark = pytest.mark.ros

TICK_S = 1.0 / 200.0   # the exciter's command period (rate_hz 200)


class ForwardController:
    """A forward command controller stand-in driving a motor: speed' = (10 u - speed) / 0.1."""

    def __init__(self, namespace):
        self.node = rclpy.create_node('forward_controller', namespace=namespace)
        self.commands = []         # (monotonic time, data) of every command received
        self.fault = None          # None, 'overspeed', 'nan' or 'silent'
        self.fault_s = None        # when the first faulty message went out (monotonic)
        self.speed = 0.0
        self.command = 0.0
        self.node.create_subscription(Float64MultiArray, 'forward_controller/commands',
                                      self._on_command, 100)
        self.publisher = self.node.create_publisher(JointState, 'joint_states', 100)
        self.node.create_timer(0.004, self._step)

    def _on_command(self, message):
        self.commands.append((time.monotonic(), list(message.data)))
        self.command = message.data[1]

    def _step(self):
        self.speed += 0.004 * (10.0 * self.command - self.speed) / 0.1
        if self.fault == 'silent':
            self.fault_s = self.fault_s or time.monotonic()
            return
        velocity = self.speed
        if self.fault == 'overspeed':
            velocity = 1000.0
        elif self.fault == 'nan':
            velocity = float('nan')
        message = JointState(name=['left', 'armature', 'right'], velocity=[0.0, velocity, 0.0],
                             position=[0.0, 0.0, 0.0], effort=[0.0, 0.0, 0.0])
        message.header.stamp = self.node.get_clock().now().to_msg()
        self.publisher.publish(message)
        if self.fault is not None and self.fault_s is None:
            self.fault_s = time.monotonic()

    def zero_after_fault_s(self):
        """Return the time from the fault to the first all-zero command after it (or None)."""
        for received, data in self.commands:
            if received >= self.fault_s and all(value == 0.0 for value in data):
                return received - self.fault_s
        return None


@pytest.fixture
def rig(ros_env):
    rclpy.init()
    namespace = 'robot'
    exciter = Exciter(namespace=namespace, parameter_overrides=[
        Parameter('command_type', value='forward_command_controller'),
        Parameter('command_topic', value='forward_controller/commands'),
        Parameter('joint_count', value=3), Parameter('joint_index', value=1),
        Parameter('input', value='joint_state'), Parameter('joint_name', value='armature'),
        Parameter('amplitude_v', value=5.0), Parameter('duration_s', value=3.0),
        Parameter('ramp_in_s', value=0.2), Parameter('speed_limit_rad_s', value=100.0),
        Parameter('stale_timeout_s', value=0.3)])
    controller = ForwardController(namespace)
    # One thread spins both nodes. rclpy's MultiThreadedExecutor held the GIL for up to 2 s at
    # a time while it polled its futures (four 200-250 Hz callbacks): the stand-in's joint
    # states then went out late and the exciter rightly called them stale.
    executor = SingleThreadedExecutor()
    for node in (exciter, controller.node):
        executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        assert wait_for(lambda: controller.publisher.get_subscription_count() > 0 and
                        exciter.command_publisher.get_subscription_count() > 0, 30.0)
        yield exciter, controller
    finally:
        executor.shutdown(timeout_sec=10)
        thread.join(timeout=10)
        remove_nodes(executor, exciter, controller.node)
        rclpy.try_shutdown()


def start(exciter, controller):
    """Start the routine once joint states flow; wait until the motor is commanded."""
    deadline = time.monotonic() + 20.0
    while True:
        response = exciter._on_start(Trigger.Request(), Trigger.Response())
        if response.success or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert response.success, response.message
    seen = len(controller.commands)
    assert wait_for(lambda: any(data[1] != 0.0 for _, data in controller.commands[seen:]),
                    30.0), exciter.session.status()
    data = next(data for _, data in controller.commands[seen:] if data[1] != 0.0)
    assert len(data) == 3 and data[0] == data[2] == 0.0  # the other joints get 0


@pytest.mark.parametrize('fault, state, reason', [
    ('overspeed', 'stopped-by-limit', 'speed'),
    ('nan', 'stopped-by-limit', 'speed is not finite'),
    ('silent', 'stale', 'no measurement on speed')])
def test_every_fault_commands_zero_at_the_joint_through_the_controller(rig, fault, state,
                                                                       reason):
    exciter, controller = rig
    start(exciter, controller)
    controller.fault = fault
    assert wait_for(lambda: exciter.session.state == state, 10.0), exciter.session.status()
    assert reason in exciter.session.reason
    assert wait_for(lambda: controller.zero_after_fault_s() is not None, 5.0)
    delay = controller.zero_after_fault_s()
    print(f'{fault}: zero command {delay * 1e3:.1f} ms after the fault')
    # a limit or NaN stops on the next take of the measurements (one command tick); stale
    # after stale_timeout_s and a tick; both with the delivery of the messages (0.25 s)
    budget = (exciter.session.stale_timeout_s if fault == 'silent' else 0.0) + 2 * TICK_S
    assert delay < budget + 0.25, delay
    time.sleep(0.3)
    after = [data for received, data in controller.commands
             if received > controller.fault_s + delay]
    assert after and all(all(value == 0.0 for value in data) for data in after)


def test_stop_and_the_end_of_the_routine_command_zero(rig):
    exciter, controller = rig
    start(exciter, controller)
    response = exciter._on_stop(Trigger.Request(), Trigger.Response())
    assert response.success
    stopped = time.monotonic()
    time.sleep(0.3)
    assert controller.commands[-1][1] == [0.0, 0.0, 0.0]
    assert all(data == [0.0, 0.0, 0.0] for received, data in controller.commands
               if received > stopped + 0.25)
    start(exciter, controller)  # to the end: 3 s
    assert wait_for(lambda: exciter.session.state == 'done', 10.0)
    time.sleep(0.3)
    assert controller.commands[-1][1] == [0.0, 0.0, 0.0]


def test_a_joint_index_beyond_the_joints_is_refused_naming_it(ros_env):
    rclpy.init()
    try:
        with pytest.raises(ValueError, match='joint_index 3 is not below joint_count 3'):
            Exciter(parameter_overrides=[
                Parameter('command_type', value='forward_command_controller'),
                Parameter('joint_count', value=3), Parameter('joint_index', value=3)])
    finally:
        rclpy.try_shutdown()
