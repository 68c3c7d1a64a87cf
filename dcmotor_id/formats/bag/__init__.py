"""
rosbag2 bags (MCAP or sqlite3 directories, bare ``.mcap``/``.db3`` files): reading and writing.

One module per step, each name importable from here:

- :mod:`.source`: opening a bag, its messages undecoded (:func:`open_bag`,
  :func:`load_messages`); a truncated MCAP file is read up to its last complete chunk, with
  a :class:`TruncatedBagWarning` saying how much was recovered.
- :mod:`.messages`: decoding (the Jazzy type store, topic names, ``std_msgs/msg/Float64``).
- :mod:`.joints`: ros2_control's joint states (``DynamicJointState``, ``JointState``).
- :mod:`.read`: a record from a bag (:func:`read_bag`), whatever topics it has.
- :mod:`.write`: a Jazzy (version 9) MCAP bag written atomically (:func:`write_bag`): a
  temporary name, then one rename.
"""

from dcmotor_id.formats.bag.joints import (DEFAULT_INTERFACES, DEFAULT_JOINT_STATE_FIELDS,
                                           DYNAMIC_JOINT_STATES_TOPIC, JOINT_STATE_FIELDS,
                                           joint_state_topic, JOINT_STATE_TYPE,
                                           JOINT_STATES_TOPIC, MAX_CLOCK_OFFSET_NS,
                                           read_dynamic_joint_states, read_joint_states)
from dcmotor_id.formats.bag.messages import (BAG_TOPICS, FLOAT64_TYPE, match_topic,
                                             register_from_bag)
from dcmotor_id.formats.bag.read import read_bag
from dcmotor_id.formats.bag.source import (DamagedBagWarning, load_messages, MCAP_MAGIC,
                                           MCAP_PEAK_FACTOR, MCAP_SMALL_MESSAGE_FACTOR,
                                           MessageSource, open_bag, Recovery,
                                           SMALL_MESSAGE_BYTES, TruncatedBagWarning)
from dcmotor_id.formats.bag.write import bag_size, PARTIAL_PREFIX, write_bag

__all__ = [
    'BAG_TOPICS', 'bag_size', 'DamagedBagWarning', 'DEFAULT_INTERFACES',
    'DEFAULT_JOINT_STATE_FIELDS', 'DYNAMIC_JOINT_STATES_TOPIC', 'FLOAT64_TYPE',
    'JOINT_STATE_FIELDS', 'JOINT_STATE_TYPE', 'JOINT_STATES_TOPIC', 'joint_state_topic',
    'load_messages', 'match_topic', 'MAX_CLOCK_OFFSET_NS', 'MCAP_MAGIC', 'MCAP_PEAK_FACTOR',
    'MCAP_SMALL_MESSAGE_FACTOR', 'MessageSource', 'open_bag', 'PARTIAL_PREFIX', 'read_bag',
    'read_dynamic_joint_states', 'read_joint_states', 'Recovery', 'register_from_bag',
    'SMALL_MESSAGE_BYTES', 'TruncatedBagWarning', 'write_bag',
]
