"""
``replay``: republish a bag's topics with their recorded timing, and /clock.

A stand-in for ``ros2 bag play --clock`` (not installable from the wheels). Every message is
published as recorded (serialized CDR, no decoding) at ``start + (stamp - first) / rate``;
``/clock`` carries the message timestamp and is published before the first message of every
timestamp, so a node with ``use_sim_time`` sees the bag's own time. Topics keep their
recorded names (give ``topic_prefix`` to publish under another namespace). The node exits
when the bag is done (unless ``loop``).
"""

import importlib
import threading
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock

from dcmotor_id.nodes.common import declare, run


def message_class(msgtype):
    """Return the rclpy message class of a type name like ``std_msgs/msg/Float64``."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def load_bag(path):
    """Read a whole bag: ``(topics {name: msgtype}, [(stamp_ns, topic, bytes), ...])``."""
    from rosbags.rosbag2 import Reader

    with Reader(path) as reader:
        topics = {conn.topic: conn.msgtype for conn in reader.connections}
        messages = [(stamp, conn.topic, bytes(data))
                    for conn, stamp, data in reader.messages()]
    messages.sort(key=lambda item: item[0])
    return topics, messages


class Replay(Node):
    """Publish a bag's messages with their recorded timing."""

    def __init__(self, **kwargs):
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
        except Exception as error:  # noqa: BLE001  (rosbags raises several types)
            raise ValueError(f'cannot read the bag {self.bag}: {error}') from None
        if not self.messages:
            raise ValueError(f'the bag {self.bag} holds no messages')
        qos = QoSProfile(depth=depth)
        self._topic_publishers = {
            topic: self.create_publisher(message_class(msgtype),
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


def main(args=None):
    """Run the ``replay`` node until the bag is played."""
    return run(Replay, args, until=lambda node: node.done.is_set())


if __name__ == '__main__':
    raise SystemExit(main())
