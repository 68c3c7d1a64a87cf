"""
``replay``: the node that republishes a bag's topics with their recorded timing, and /clock.

A stand-in for ``ros2 bag play --clock`` (not installable from the wheels). Every message is
published as recorded (serialized CDR, no decoding) at ``start + (stamp - first) / rate``;
``/clock`` carries the message timestamp and is published before the first message of every
timestamp, so a node with ``use_sim_time`` sees the bag's own time. Topics keep their
recorded names (give ``topic_prefix`` to publish under another namespace). The node exits
when the bag is done (unless ``loop``).

Only the message types of :data:`MESSAGE_TYPES` are played: a bag names its types itself, and
an untrusted bag must not choose what is imported; any other type is refused by name.
"""

from __future__ import annotations

from collections.abc import Mapping
import threading
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log, ParameterEvent
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from dcmotor_id.formats.bag import load_messages
from dcmotor_id.nodes.common import declare, run

#: The message types a bag may declare -> their rclpy classes: the identifier's inputs, the
#: simulator's outputs and what ``ros2 bag record -a`` adds beside them. Nothing else is played.
MESSAGE_TYPES: dict[str, type] = {
    'std_msgs/msg/Float64': Float64,
    'std_msgs/msg/Float64MultiArray': Float64MultiArray,
    'sensor_msgs/msg/JointState': JointState,
    'diagnostic_msgs/msg/DiagnosticArray': DiagnosticArray,
    'rosgraph_msgs/msg/Clock': Clock,
    'rcl_interfaces/msg/Log': Log,
    'rcl_interfaces/msg/ParameterEvent': ParameterEvent,
}


class UnsupportedMessageType(ValueError):
    """A bag declares a message type that replay does not play."""


def message_class(msgtype: str, topic: str = '') -> type:
    """
    Return the rclpy message class of a type name like ``std_msgs/msg/Float64``.

    Raises
    ------
    UnsupportedMessageType
        When the type is not one of :data:`MESSAGE_TYPES` (nothing is imported for it).

    """
    try:
        return MESSAGE_TYPES[msgtype]
    except (KeyError, TypeError):
        where = f' (topic {topic})' if topic else ''
        raise UnsupportedMessageType(
            f'message type {msgtype!r}{where} is not played; replay plays only '
            f'{", ".join(MESSAGE_TYPES)}: remove that topic from the bag '
            '(e.g. ros2 bag convert) or play it with ros2 bag play') from None


def load_bag(path: str) -> tuple[dict[str, str], list[tuple[int, str, bytes]]]:
    """
    Read a whole bag: ``(topics {name: msgtype}, [(stamp_ns, topic, bytes), ...])``.

    Every declared type is checked against :data:`MESSAGE_TYPES` before any message is read.

    Raises
    ------
    UnsupportedMessageType
        When a topic has a type that replay does not play.
    InputDataError
        When the path is not a readable bag.

    """
    def check(topics: Mapping[str, str]) -> None:
        for topic, msgtype in topics.items():
            message_class(msgtype, topic)
    return load_messages(path, check=check)


class Replay(Node):
    """Publish a bag's messages with their recorded timing."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('replay', **kwargs)
        self.bag = declare(self, 'bag', '', 'bag directory or .mcap/.db3 file to play')
        self.rate = declare(self, 'rate', 1.0, 'playback speed factor', low=1e-3, high=1e3)
        self.loop = declare(self, 'loop', False, 'start again at the end')
        self.publish_clock = declare(self, 'publish_clock', True,
                                     'publish /clock with the recorded timestamps')
        self.topic_prefix = declare(self, 'topic_prefix', '',
                                    'namespace put before every recorded topic name')
        self.start_delay_s = declare(self, 'start_delay_s', 1.0,
                                     'wait this long for subscribers before playing [s]',
                                     low=0.0)
        depth = declare(self, 'qos_depth', 1000, 'history depth of the publishers', low=1)
        if not self.bag:
            raise ValueError('parameter bag is empty: give the bag to play, e.g. '
                             '--ros-args -p bag:=/path/to/window_000001_...')
        try:
            self.topics, self.messages = load_bag(self.bag)
        except UnsupportedMessageType as error:
            raise ValueError(f'cannot play the bag {self.bag}: {error}') from None
        except Exception as error:  # noqa: BLE001  (rosbags raises several types)
            raise ValueError(f'cannot read the bag {self.bag}: {error}') from None
        if not self.messages:
            raise ValueError(f'the bag {self.bag} holds no messages')
        qos = QoSProfile(depth=depth)
        self._topic_publishers = {
            topic: self.create_publisher(message_class(msgtype, topic),
                                         self.topic_prefix.rstrip('/') + topic
                                         if self.topic_prefix else topic, qos)
            for topic, msgtype in self.topics.items()}
        self._clock_publisher = self.create_publisher(Clock, '/clock', 10) if self.publish_clock \
            else None
        self.done = threading.Event()
        self.published = 0
        self._thread = threading.Thread(target=self._play, name='replay', daemon=True)
        self._thread.start()
        self.get_logger().info(f'playing {len(self.messages)} messages of '
                               f'{", ".join(self.topics)} from {self.bag}')

    def _play(self):
        time.sleep(self.start_delay_s)
        while rclpy.ok():
            first = self.messages[0][0]
            start = time.monotonic()
            last_stamp = None
            for stamp, topic, data in self.messages:
                due = start + (stamp - first) * 1e-9 / self.rate
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                if not rclpy.ok():
                    return
                try:
                    if self._clock_publisher is not None and stamp != last_stamp:
                        clock = Clock()
                        clock.clock.sec, clock.clock.nanosec = divmod(stamp, 1_000_000_000)
                        self._clock_publisher.publish(clock)
                        last_stamp = stamp
                    self._topic_publishers[topic].publish(data)
                except Exception:  # noqa: BLE001  (context shut down while playing)
                    return
                self.published += 1
            if not self.loop:
                break
        self.get_logger().info(f'done: {self.published} messages played')
        self.done.set()


def main(args: Optional[list[str]] = None) -> int:
    """Run the ``replay`` node until the bag is played."""
    return run(Replay, args, until=lambda node: node.done.is_set())


if __name__ == '__main__':
    raise SystemExit(main())
