"""
Decoding the messages of a bag: the Jazzy type store, topic names, ``std_msgs/msg/Float64``.

Decoding is rosbags' deserializer throughout (no hand-written CDR in the package); a type
outside the standard store is taught from the definition the bag itself carries
(:func:`register_from_bag`).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any, Optional

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.formats.bag.source import MessageSource


#: Topic of every channel in a bag, as the identifier node names them (relative names match
#: any namespace: ``voltage`` matches ``/voltage`` and ``/drive/voltage``).
BAG_TOPICS = {'voltage': 'voltage', 'current': 'current', 'speed': 'speed', 'samples': 'samples'}
#: Message type of the per-sample topics.
FLOAT64_TYPE = 'std_msgs/msg/Float64'


def jazzy_typestore() -> Any:
    """Return rosbags' type store of ROS 2 Jazzy (the standard message types)."""
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def match_topic(wanted: str, available: Collection[str]) -> Optional[str]:
    """Return the available topic that ``wanted`` names (exact, or its last components)."""
    if wanted in available:
        return wanted
    absolute = '/' + wanted.lstrip('/')
    if absolute in available:
        return absolute
    if wanted.startswith('/'):
        return None
    tail = [topic for topic in available if topic.endswith('/' + wanted)]
    return tail[0] if len(tail) == 1 else None


def deserialize(typestore: Any, data: bytes, msgtype: str, topic: str, path: str,
                stamp: int) -> Any:
    """Decode one CDR payload, or refuse it naming the topic and the time."""
    try:
        return typestore.deserialize_cdr(data, msgtype)
    except RecursionError:
        raise InputDataError(f'{path}: a message of {topic} (bag time {stamp} ns) nests without '
                             f'end and is not a valid {msgtype}: the bag is damaged; re-record '
                             'it or give other topics') from None
    except Exception as error:  # noqa: BLE001  (SerdeError, struct.error, IndexError ...)
        raise InputDataError(f'{path}: a message of {topic} (bag time {stamp} ns) is not a '
                             f'valid {msgtype} ({type(error).__name__}: {str(error)[:200]}): '
                             'the bag is damaged or declares a wrong type; re-record it or '
                             'give other topics') from None


def register_from_bag(typestore: Any, source: MessageSource, msgtype: str, path: str) -> None:
    """
    Teach ``typestore`` a message type from the definition the bag itself carries.

    rosbag2 stores every connection's message definition (``ros2msg`` text with its
    dependencies), so a type outside the standard store (e.g. control_msgs) is read without a
    ROS installation; only definitions are parsed, no module is imported.
    """
    from rosbags.typesys import get_types_from_msg

    if msgtype in typestore.types:
        return
    text = source.definitions.get(msgtype, '')
    if not text.strip():
        raise InputDataError(f'{path}: the bag has no definition of {msgtype}; it cannot be '
                             'decoded without one (record with a rosbag2 that stores them)')
    try:
        typestore.register(get_types_from_msg(text, msgtype))
    except Exception as error:  # noqa: BLE001  (the parser raises several types)
        raise InputDataError(f'{path}: the definition of {msgtype} in the bag cannot be '
                             f'parsed ({error})') from None


def read_float64(source: MessageSource, topics: Mapping[str, str], typestore: Any,
                 path: str) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """
    Read ``std_msgs/msg/Float64`` topics; return each channel's bag times [ns] and values.

    ``topics`` maps channel -> topic; a topic without messages is refused.
    """
    raw: dict[str, tuple[list[int], list[bytes]]] = {channel: ([], []) for channel in topics}
    by_topic = {topic: channel for channel, topic in topics.items()}
    for topic, stamp, data in source.messages(by_topic):
        stamps, payloads = raw[by_topic[topic]]
        stamps.append(stamp)
        payloads.append(data)
    stamps_by_channel, values_by_channel = {}, {}
    for channel, (stamps, payloads) in raw.items():
        if not stamps:
            damage = '; '.join(getattr(source, 'damage', []))
            raise InputDataError(f'{path}: topic {topics[channel]} has no messages' + (
                f' that could be read: {damage}; re-record it or repair the file'
                if damage else ''))
        values, good = _decode_float64(payloads, typestore)
        if not good.all():
            bad = np.flatnonzero(~good)
            getattr(source, 'damage', []).append(
                f'the bag is damaged: {bad.size} of {len(payloads)} messages of '
                f'{topics[channel]} are not valid {FLOAT64_TYPE} and were left out (the first '
                f'at t = {(stamps[bad[0]] - stamps[0]) * 1e-9:.3f} s)')
            if bad.size > len(payloads) // 2:
                raise InputDataError(
                    f'{path}: {bad.size} of {len(payloads)} messages of {topics[channel]} are '
                    f'not valid {FLOAT64_TYPE}: the topic is damaged or of another type; '
                    're-record it or give another topic')
        stamps_by_channel[channel] = np.array(stamps, dtype=np.int64)[good]
        values_by_channel[channel] = values[good]
    return stamps_by_channel, values_by_channel


def _decode_float64(payloads: list[bytes], typestore: Any) -> tuple[np.ndarray, np.ndarray]:
    """Return the values and which payloads decoded (a damaged one is NaN, not decoded)."""
    # rosbags' deserializer, not a hand-written CDR decoder: bench/cdr_results.md measures a
    # whole bag (60 s x 3 channels at 1 kHz) read and written only 1.3 times faster with
    # one, some 0.1-0.2 s a minute of samples: not worth code of our own
    try:
        values = np.array([typestore.deserialize_cdr(data, FLOAT64_TYPE).data
                           for data in payloads], dtype=float)
        return values, np.ones(values.size, dtype=bool)
    except Exception:  # noqa: BLE001  (SerdeError, struct, index: a damaged payload)
        pass
    values = np.full(len(payloads), np.nan)
    good = np.zeros(len(payloads), dtype=bool)
    for index, data in enumerate(payloads):
        try:
            values[index] = float(typestore.deserialize_cdr(data, FLOAT64_TYPE).data)
            good[index] = True
        except Exception:  # noqa: BLE001, S112  (counted as damaged)
            continue
    return values, good
