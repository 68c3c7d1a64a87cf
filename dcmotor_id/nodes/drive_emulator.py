"""
Publish a simulated record as a robot's drive does: in real time, on its topics, in bursts.

:class:`DrivePlayer` takes the messages of
:func:`dcmotor_id.simulation.drive_publisher.drive_messages` (their stamps on the system
clock, starting a moment after :meth:`DrivePlayer.start`) and publishes each one when it is
due, from a thread of its own, with a publisher of the given node:

* ``transport='joint_state'``: ``sensor_msgs/JointState`` on ``joint_states`` (two joints,
  ``other`` and ``axis``: velocity = speed, effort = current, ``header.stamp`` the message's
  stamp, or with ``stamps='now'`` the system time when it is published) and the armature
  voltage as ``std_msgs/Float64`` on ``voltage`` (no header: the receiver sees its DDS
  source time, the real publication time);
* ``transport='dynamic_joint_state'``: ``control_msgs/DynamicJointState`` on
  ``dynamic_joint_states`` (joints ``other`` and ``axis``, the interfaces ``position``,
  ``velocity``, ``current`` and ``voltage`` of each, stamped as the joint states above), as
  ros2_control's joint_state_broadcaster publishes a drive's state interfaces; no separate
  voltage topic;
* ``transport='float64'``: ``voltage``, ``current`` and ``speed`` as ``std_msgs/Float64``
  (publication times only);
* ``transport='batch'``: the samples of each burst (or each sample) in one
  ``std_msgs/Float64MultiArray`` on ``samples`` (:mod:`dcmotor_id.formats.batch`), the time of
  each sample its joint-state stamp (with its jitter) from the first sample.

It is the drive of the node tests of the robot topics and of
``bench/bench_robot_topics.py``; the identifier takes its messages as it would a robot's.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Optional

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from dcmotor_id.nodes.identifier import dynamic_joint_state_type
from dcmotor_id.nodes.sim_motor import batch_message
from dcmotor_id.simulation.drive_publisher import drive_messages

__all__ = ['DrivePlayer', 'TRANSPORTS']

TRANSPORTS = ('joint_state', 'dynamic_joint_state', 'float64', 'batch')
#: The interfaces of each joint in the ``dynamic_joint_state`` transport.
DYNAMIC_INTERFACES = ('position', 'velocity', 'current', 'voltage')


class DrivePlayer:
    """
    Publish a record's messages in real time (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
        The node whose publishers are used (its executor need not spin).
    rate_hz : float
        The joint states' (and current's, speed's) rate [Hz].
    voltage, current, speed : numpy.ndarray
        The samples.
    transport : str
        ``'joint_state'`` or ``'float64'``.
    publish : dict
        Keyword arguments of :func:`~dcmotor_id.simulation.drive_publisher.drive_messages`
        (``stamps``, ``jitter``, ``burst_s``, ``voltage_rate``, ``voltage_stamp``, ``seed``).

    Attributes
    ----------
    published : dict
        Topic -> messages published so far.

    """

    def __init__(self, node: Node, rate_hz: float, voltage: np.ndarray, current: np.ndarray,
                 speed: np.ndarray, transport: str = 'joint_state',
                 qos_depth: int = 5000, **publish: Any) -> None:
        if transport not in TRANSPORTS:
            raise ValueError(f'transport {transport!r}: one of {TRANSPORTS}')
        self.rate_hz = float(rate_hz)
        self.samples = (np.asarray(voltage), np.asarray(current), np.asarray(speed))
        self.transport = transport
        self.options = publish
        topics = {'joint_state': ('voltage', 'joint_states'),
                  'dynamic_joint_state': ('dynamic_joint_states',),
                  'float64': ('voltage', 'current', 'speed'), 'batch': ('samples',)}[transport]
        kinds: dict[str, Any] = {'joint_states': JointState, 'samples': Float64MultiArray}
        if transport == 'dynamic_joint_state':
            kinds['dynamic_joint_states'] = dynamic_joint_state_type()
        self.publishers = {topic: node.create_publisher(kinds.get(topic, Float64), topic,
                                                        qos_depth)
                           for topic in topics}
        self.published = dict.fromkeys(topics, 0)
        self.done = threading.Event()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None

    def subscribed(self) -> bool:
        """Whether every topic has a subscriber."""
        return all(publisher.get_subscription_count() > 0
                   for publisher in self.publishers.values())

    def start(self, lead_s: float = 0.3) -> None:
        """Start publishing; the first sample is due ``lead_s`` from now."""
        start_ns = time.time_ns() + int(lead_s * 1e9)
        messages = drive_messages(*self.samples, self.rate_hz, start_ns=start_ns,
                                  **self.options)
        if self.transport == 'batch':
            messages = _batches(messages, start_ns)
        elif self.transport == 'dynamic_joint_state':  # the voltage is an interface
            messages = [message for message in messages if message.topic != 'voltage']
        self._thread = threading.Thread(target=self._play, args=(messages,), daemon=True,
                                        name='drive')
        self._thread.start()

    def stop(self) -> None:
        """Stop publishing (the thread ends within a few milliseconds)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)

    def _play(self, messages: list) -> None:
        """
        Publish each message when due, as a drive's loop does.

        On waking (late or not) the loop publishes every sample whose instant has passed,
        not only those it planned to: what a timer-driven loop that wakes late does.
        """
        try:
            position = 0
            while position < len(messages) and not self._stop.is_set():
                wait_s = (messages[position].publish_ns - time.time_ns()) * 1e-9
                if wait_s > 0:
                    time.sleep(wait_s)
                now = time.time_ns()
                self._publish(messages[position])
                position += 1
                while position < len(messages) and messages[position].sample_ns <= now:
                    self._publish(messages[position])
                    position += 1
        finally:
            self.done.set()

    def _publish(self, message: Any) -> None:
        """Publish one message of :func:`drive_messages` on its topic(s)."""
        if message.topic == 'samples':
            self.publishers['samples'].publish(batch_message(*message.values))
            self.published['samples'] += len(message.values[0])
        elif message.topic == 'voltage':
            self.publishers['voltage'].publish(Float64(data=message.values[0]))
            self.published['voltage'] += 1
        elif self.transport == 'float64':
            for topic, value in zip(('current', 'speed'), message.values):
                self.publishers[topic].publish(Float64(data=value))
                self.published[topic] += 1
        elif self.transport == 'dynamic_joint_state':
            current, speed = message.values
            voltage = float(self.samples[0][message.sequence - 1])
            state = dynamic_joint_state_type()(joint_names=['other', 'axis'])
            state.interface_values = [_interface_value((0.0, 0.0, 0.0, 0.0)),
                                      _interface_value((0.0, speed, current, voltage))]
            self._stamp(state, message)
            self.publishers['dynamic_joint_states'].publish(state)
            self.published['dynamic_joint_states'] += 1
        else:
            current, speed = message.values
            joint_state = JointState(name=['other', 'axis'], position=[0.0, 0.0],
                                     velocity=[0.0, speed], effort=[0.0, current])
            self._stamp(joint_state, message)
            self.publishers['joint_states'].publish(joint_state)
            self.published['joint_states'] += 1

    def _stamp(self, joint_state: Any, message: Any) -> None:
        """Stamp a joint state: ``now()`` when it is published, or the message's stamp."""
        # now(): the time it is published, as a drive's loop stamps it (also when late)
        stamp_ns = time.time_ns() if self.options.get('stamps') == 'now' else message.stamp_ns
        joint_state.header.stamp.sec, joint_state.header.stamp.nanosec = divmod(
            stamp_ns, 1_000_000_000)


def _interface_value(values: tuple) -> Any:
    """Return one joint's ``control_msgs/InterfaceValue`` of :data:`DYNAMIC_INTERFACES`."""
    from control_msgs.msg import InterfaceValue

    return InterfaceValue(interface_names=list(DYNAMIC_INTERFACES),
                          values=[float(value) for value in values])


def _batches(messages: list, start_ns: int) -> list:
    """
    Return the joint states' messages grouped by publication (one burst, one batch).

    Each group is one ``samples`` message whose values are the batch's columns: times [s]
    (the joint-state stamps from ``start_ns``), voltages (of the same samples), currents and
    speeds.
    """
    voltage = {message.sequence: message.values[0] for message in messages
               if message.topic == 'voltage'}
    joint = [message for message in messages if message.topic == 'joint_states']
    groups: list[list] = []
    for message in joint:
        if groups and message.publish_ns - groups[-1][-1].publish_ns < 100_000:
            groups[-1].append(message)
        else:
            groups.append([message])
    batches = []
    for group in groups:
        columns = (np.array([(message.stamp_ns - start_ns) * 1e-9 for message in group]),
                   np.array([voltage[message.sequence] for message in group]),
                   np.array([message.values[0] for message in group]),
                   np.array([message.values[1] for message in group]))
        batches.append(group[-1]._replace(topic='samples', values=columns))
    return batches


def noisy_record(rate_hz: float, duration_s: float, noise: float = 0.01,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Return the paper's motor 2 under the paper's excitation at ``rate_hz``, with noise.

    ``noise``: the standard deviation of the current's and the speed's noise as a fraction of
    each signal's own standard deviation (0.01: 1 %).
    """
    from dcmotor_id.core.model import PAPER_MOTORS
    from dcmotor_id.simulation import simulate_motor
    from dcmotor_id.simulation.excitation import make_excitation

    _, voltage = make_excitation('paper', duration_s, 1.0 / rate_hz)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, 1.0 / rate_hz)
    rng = np.random.default_rng(seed)
    current = current + noise * np.std(current) * rng.normal(size=current.size)
    speed = speed + noise * np.std(speed) * rng.normal(size=speed.size)
    return voltage, current, speed


def identify_published(executor: Any, namespace: str, rate_hz: float, duration_s: float,
                       transport: str = 'joint_state', noise: float = 0.01,
                       identifier: Optional[dict] = None, timeout_s: float = 120.0,
                       **publish: Any) -> dict[str, Any]:
    """
    Publish a record as a drive does to an identifier node and call its ``~/identify``.

    ``executor`` is spun by another thread; the identifier and the drive's node are added to
    it and removed afterwards. ``identifier``: parameter overrides of the identifier
    (defaults: ``input`` from ``transport``, ``align_by: timestamp``, ``joint_name: axis``,
    one window longer than the record, no recording, no online estimate, no discovery).
    ``publish``: the options of :func:`~dcmotor_id.simulation.drive_publisher.drive_messages`.

    Returns ``published`` (messages per topic), ``samples`` (published at ``rate_hz``),
    ``response`` (the Trigger response), ``result`` (the identifier's last result or None),
    ``stats`` (the aligner's counters), ``health`` (the key-values of the ``streams`` status
    on ``/diagnostics``) and ``regrid`` (the placement's counters).
    """
    import rclpy
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from dcmotor_id.nodes.identifier import Identifier

    overrides = {'input': transport, 'align_by': 'timestamp', 'sample_rate_hz': rate_hz,
                 'window_s': duration_s + 10.0, 'record': False, 'online': False,
                 'compare_paper': False, 'discover': False, 'joint_name': 'axis'}
    overrides.update(identifier or {})
    ident = Identifier(namespace=namespace, parameter_overrides=[
        Parameter(name, value=value) for name, value in overrides.items()])
    drive = rclpy.create_node('drive', namespace=namespace)
    player = DrivePlayer(drive, rate_hz, *noisy_record(rate_hz, duration_s, noise),
                         transport=transport, **publish)
    executor.add_node(ident)
    executor.add_node(drive)
    try:
        _wait(player.subscribed, 20.0)
        player.start()
        _wait(player.done.is_set, duration_s + 60.0)
        samples = len(player.samples[1])
        _wait(lambda: ident.aligner.stats.emitted >= samples, 5.0)
        client = drive.create_client(Trigger, 'identifier/identify')
        client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(Trigger.Request())
        _wait(future.done, timeout_s)
        return {'published': dict(player.published), 'samples': samples,
                'response': future.result(), 'result': ident.last_result,
                'stats': ident.aligner.stats.as_dict(), 'health': ident.health.key_values(),
                'regrid': {name: stats.as_dict() for name, stats in
                           (ident.regridder.stats.items() if ident.regridder else ())}}
    finally:
        player.stop()
        for node in (ident, drive):
            executor.remove_node(node)
        time.sleep(0.3)  # a callback the spinning thread had started ends first
        ident.close()
        ident.destroy_node()
        drive.destroy_node()


def _wait(condition: Any, timeout_s: float) -> bool:
    """Sleep until ``condition()`` holds or ``timeout_s`` passed; return whether it holds."""
    deadline = time.monotonic() + timeout_s
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.02)
    return bool(condition())
