"""
``replay``: the node that republishes a bag's topics with their recorded timing, and /clock.

A stand-in for ``ros2 bag play --clock`` (not installable from the wheels). Every message is
published as recorded (serialized CDR, no decoding) at ``start + (stamp - first) / rate``;
``/clock`` carries the message timestamp and is published before the first message of every
timestamp, so a node with ``use_sim_time`` sees the bag's own time. Topics keep their
recorded names (give ``topic_prefix`` to publish under another namespace). The node exits
when the bag is done (unless ``loop``). A gap between two messages longer than ``max_gap_s``
(default 10 s of wall time) is shortened to it, with a warning naming the gap.

Only the measurement topics are played: those named ``voltage``, ``current``, ``speed``,
``samples`` or ``joint_states`` (in any namespace, :data:`MEASUREMENTS`). Anything else a bag
holds (``voltage_command`` above all: a recorded command must not drive a motor again,
``/diagnostics``, ``/clock``, ...) is played only when ``extra_topics`` names it exactly.
Every message is checked before playing: a topic whose name is not a valid ROS name is
skipped with a warning naming it, and a payload that does not decode as its declared type is
skipped and counted.

Only the message types of :data:`MESSAGE_TYPES` are played: a bag names its types itself, and
an untrusted bag must not choose what is imported; any other type is refused by name.
"""

from __future__ import annotations

from collections.abc import Mapping
import threading
import time
from typing import Any, Callable, Optional

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Log, ParameterDescriptor, ParameterEvent
import rclpy
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.validate_full_topic_name import validate_full_topic_name
from rclpy.validate_topic_name import validate_topic_name
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from dcmotor_id.formats.bag import load_messages
from dcmotor_id.nodes.common import declare, guard_parameters, own_parameters, run

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


#: Base names of the topics played by default: the measurements of a drive.
MEASUREMENTS = ('voltage', 'current', 'speed', 'samples', 'joint_states')


def is_measurement(topic: str) -> bool:
    """Whether a recorded topic is a measurement (its last name is one of MEASUREMENTS)."""
    return isinstance(topic, str) and topic.rstrip('/').rsplit('/', 1)[-1] in MEASUREMENTS


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


def load_bag(path: str, selected: Optional[Callable[[str], bool]] = None,
             ) -> tuple[dict[str, str], list[tuple[int, str, bytes]]]:
    """
    Read a whole bag: ``(topics {name: msgtype}, [(stamp_ns, topic, bytes), ...])``.

    The type of every topic that ``selected`` accepts (all without it) is checked against
    :data:`MESSAGE_TYPES` before any message is read; only those topics are returned.

    Raises
    ------
    UnsupportedMessageType
        When a topic has a type that replay does not play.
    InputDataError
        When the path is not a readable bag.

    """
    def check(topics: Mapping[str, str]) -> None:
        for topic, msgtype in topics.items():
            if selected is None or selected(topic):
                message_class(msgtype, topic)
    topics, messages = load_messages(path, check=check)
    if selected is None:
        return topics, messages
    keep = {topic: msgtype for topic, msgtype in topics.items() if selected(topic)}
    return keep, [item for item in messages if item[1] in keep]


def name_problem(name: str) -> Optional[str]:
    """Say why ``name`` is not a valid ROS topic name (None when it is)."""
    try:
        if name.startswith('/'):
            validate_full_topic_name(name)
        else:
            validate_topic_name(name)
    except (NameValidationException, AttributeError, TypeError, ValueError) as error:
        return f'not a valid ROS topic name ({str(error).splitlines()[0].rstrip(":")})'
    return None


def playable(topics: Mapping[str, str], messages: list[tuple[int, str, bytes]],
             prefix: str = '') -> tuple[dict[str, str], list[tuple[int, str, bytes]], list[str]]:
    """
    Drop what cannot be played: topics with invalid names, payloads that do not decode.

    Returns the topics (recorded name -> published name), the messages left and one warning
    per problem (naming the topic, and how many messages were skipped and from when).
    """
    warnings, names = [], {}
    for topic in topics:
        name = prefix.rstrip('/') + topic if prefix else topic
        invalid = name_problem(name)
        if invalid:
            warnings.append(f'topic {topic!r} skipped: {invalid}')
        else:
            names[topic] = name
    bad: dict[str, list[int]] = {}
    kept = []
    for stamp, topic, data in messages:
        if topic not in names:
            continue
        try:
            deserialize_message(bytes(data), message_class(topics[topic], topic))
        except Exception:  # noqa: BLE001  (rmw raises RMWError on any malformed CDR)
            bad.setdefault(topic, []).append(stamp)
            continue
        kept.append((stamp, topic, data))
    for topic, stamps in bad.items():
        warnings.append(f'topic {topic}: {len(stamps)} message(s) skipped, their payload is '
                        f'not a valid {topics[topic]} (first at stamp {stamps[0]} ns)')
    return names, kept, warnings


def schedule(stamps: list[int], rate: float, max_gap_s: float
             ) -> tuple[list[float], list[tuple[int, float]]]:
    """
    Return when each message is due [s after the start] and the gaps that were shortened.

    A message is due ``(stamp - previous stamp) / rate`` after the previous one, but never
    more than ``max_gap_s`` after it: a bag with a gap of years (a clock set wrong, two
    recordings merged) is played on instead of sleeping it out.  Each shortened gap is
    ``(index of the message after it, the gap as recorded [s])``.
    """
    due, shortened, at = [], [], 0.0
    for index, stamp in enumerate(stamps):
        if index:
            gap = (stamp - stamps[index - 1]) * 1e-9
            wait = gap / rate
            if wait > max_gap_s:
                shortened.append((index, gap))
                wait = max_gap_s
            at += max(wait, 0.0)
        due.append(at)
    return due, shortened


def check_prefix(prefix: str) -> None:
    """Refuse a ``topic_prefix`` that makes no valid ROS name (naming the parameter)."""
    if not prefix:
        return
    invalid = name_problem(prefix.rstrip('/') + '/voltage')
    if invalid:
        raise ValueError(f'parameter topic_prefix = {prefix!r}: {invalid}; give a namespace '
                         'like /replayed')


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
        self.max_gap_s = declare(self, 'max_gap_s', 10.0,
                                 'longest wait between two messages [s]: a longer gap in the '
                                 'bag is shortened to this, with a warning', low=0.0)
        check_prefix(self.topic_prefix)
        self.start_delay_s = declare(self, 'start_delay_s', 1.0,
                                     'wait this long for subscribers before playing [s]',
                                     low=0.0)
        depth = declare(self, 'qos_depth', 1000, 'history depth of the publishers', low=1)
        extra = self.declare_parameter(
            'extra_topics', Parameter.Type.STRING_ARRAY, ParameterDescriptor(
                description='recorded topics played besides the measurements (exact names, '
                            'e.g. [/voltage_command])')).value or []
        self.extra_topics = [topic for topic in extra if topic]
        if not self.bag:
            raise ValueError('parameter bag is empty: give the bag to play, e.g. '
                             '--ros-args -p bag:=/path/to/window_000001_...')
        every: list[str] = []  # every topic of the bag, in its order

        def wanted(topic: str) -> bool:
            if topic not in every:
                every.append(topic)
            return is_measurement(topic) or topic in self.extra_topics
        try:
            self.topics, self.messages = load_bag(self.bag, wanted)
        except UnsupportedMessageType as error:
            raise ValueError(f'cannot play the bag {self.bag}: {error}') from None
        except Exception as error:  # noqa: BLE001  (rosbags raises several types)
            raise ValueError(f'cannot read the bag {self.bag}: {error}') from None
        self._say_what_is_left_out(every)
        names, self.messages, warnings = playable(self.topics, self.messages, self.topic_prefix)
        for warning in warnings:
            self.get_logger().warning(warning)
        self.topics = {topic: self.topics[topic] for topic in names}
        self._refuse_nothing_to_play(warnings, every)
        self.due = self._schedule()
        qos = QoSProfile(depth=depth)
        self._topic_publishers = {
            topic: self.create_publisher(message_class(self.topics[topic], topic), name, qos)
            for topic, name in names.items()}
        self._clock_publisher = self.create_publisher(Clock, '/clock', 10) if self.publish_clock \
            else None
        guard_parameters(self, own_parameters(self))  # all read here, at start-up
        self.done = threading.Event()
        self.published = 0
        self._thread = threading.Thread(target=self._play, name='replay', daemon=True)
        self._thread.start()
        self.get_logger().info(f'playing {len(self.messages)} messages of '
                               f'{", ".join(self.topics)} from {self.bag}')

    def _refuse_nothing_to_play(self, warnings: list[str], every: list[str]) -> None:
        """Raise ValueError saying why no message is left to play (if none is)."""
        if not self.messages and warnings:
            raise ValueError(f'nothing of the bag {self.bag} can be played: '
                             + '; '.join(warnings))
        if not self.messages:
            raise ValueError(f'the bag {self.bag} holds no message to play (measurement '
                             f'topics: any named {", ".join(MEASUREMENTS)}; its topics: '
                             f'{", ".join(map(str, every)) or "none"}); name others in '
                             'extra_topics')

    def _schedule(self) -> list[float]:
        """Return when each message is due [s]; warn about the gaps shortened to max_gap_s."""
        due, shortened = schedule([item[0] for item in self.messages], self.rate,
                                  self.max_gap_s)
        for index, gap in shortened[:5]:
            self.get_logger().warning(
                f'a gap of {gap:.3g} s in the bag before message {index} (stamp '
                f'{self.messages[index][0]} ns) is played as max_gap_s = {self.max_gap_s:g} s')
        if len(shortened) > 5:
            self.get_logger().warning(f'{len(shortened)} gaps longer than max_gap_s shortened')
        return due

    def _say_what_is_left_out(self, every: list[str]) -> None:
        skipped = [topic for topic in every if topic not in self.topics]
        for topic in skipped:
            invalid = name_problem(topic)
            if invalid:
                self.get_logger().warning(f'topic {topic!r} skipped: {invalid}')
        if skipped:
            self.get_logger().info(f'not played (not measurements; name them in extra_topics '
                                   f'to play them): {", ".join(map(str, skipped))}')
        missing = [topic for topic in self.extra_topics if topic not in every]
        if missing:
            self.get_logger().warning(f'extra_topics not in the bag: {", ".join(missing)}')

    def _play(self):
        time.sleep(self.start_delay_s)
        while rclpy.ok():
            start = time.monotonic()
            last_stamp = None
            for (stamp, topic, data), offset in zip(self.messages, self.due):
                delay = start + offset - time.monotonic()
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
