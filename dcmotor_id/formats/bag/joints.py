"""
Joint states in a bag: ros2_control's ``DynamicJointState`` and ``sensor_msgs`` ``JointState``.

One joint's samples, timed by their header stamps, with the channels the joint does not give
read from their ``std_msgs/msg/Float64`` topics and paired by timestamp on one grid.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import replace
from typing import Optional
import warnings

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import Record
from dcmotor_id.formats.bag.messages import (BAG_TOPICS, deserialize, FLOAT64_TYPE,
                                             jazzy_typestore, match_topic, read_float64,
                                             register_from_bag)
from dcmotor_id.formats.bag.source import MessageSource
from dcmotor_id.formats.mapping import build_record, DEFAULT_OPTIONS, ReadOptions


#: Topic of ros2_control's joint states with every interface (joint_state_broadcaster).
DYNAMIC_JOINT_STATES_TOPIC = '/dynamic_joint_states'
#: Channel -> interface name of a joint in DynamicJointState messages, by default.
DEFAULT_INTERFACES = {'voltage': 'voltage', 'current': 'current', 'speed': 'velocity',
                      'position': 'position', 'duty': 'duty', 'direction': 'direction'}
#: Topic of ros2_control's joint states (joint_state_broadcaster, robot drivers).
JOINT_STATES_TOPIC = '/joint_states'
#: Message type of :data:`JOINT_STATES_TOPIC`.
JOINT_STATE_TYPE = 'sensor_msgs/msg/JointState'
#: The per-joint arrays of a JointState message (what ``--interface CHANNEL=FIELD`` may name).
JOINT_STATE_FIELDS = ('position', 'velocity', 'effort')
#: Channel -> JointState field, by default (current from effort only when asked: effort is
#: a torque on most robots).
DEFAULT_JOINT_STATE_FIELDS = {'speed': 'velocity', 'position': 'position'}
#: Header stamps further than this from the bag's time of the messages are on another clock
#: (simulated time, a drive's own clock) and cannot be paired with Float64 topics [ns].
MAX_CLOCK_OFFSET_NS = 1_000_000_000


def _choose_joint(names: Sequence[str], joint: Optional[str], topic: str, path: str) -> str:
    """Return the joint to read: ``joint``, or the message's only one (else a clear error)."""
    if joint is None:
        if len(names) != 1:
            raise InputDataError(f'{path}: {topic} has the joints {", ".join(names)}; '
                                 'choose one with --joint NAME')
        return names[0]
    if joint not in names:
        raise InputDataError(f'{path}: joint {joint!r} is not in {topic}; it has '
                             f'{", ".join(names) or "no joints"} (--joint NAME)')
    return joint


def read_dynamic_joint_states(source: MessageSource, topic: str, path: str,
                              options: ReadOptions = DEFAULT_OPTIONS,
                              topics: Optional[Mapping[str, str]] = None,
                              sample_period_s: Optional[float] = None) -> Record:
    """
    Read one joint of ``control_msgs/msg/DynamicJointState`` messages, Float64 topics beside.

    Each message is one sample, timed by its header stamp (the bag's time when the stamp is
    zero). The joint is ``options.joint`` (or the only one); channel ``c`` is the interface
    ``options.interfaces[c]``, by default :data:`DEFAULT_INTERFACES` (``voltage``,
    ``current``, ``velocity`` as speed, ``position``). A voltage, current or speed the joint
    has no interface for comes from its ``std_msgs/msg/Float64`` topic (``topics``, default
    :data:`BAG_TOPICS`) when the bag has one, paired with the joint's samples by timestamp on
    one grid (as :func:`read_joint_states` does).

    Parameters
    ----------
    source : MessageSource
        The open bag.
    topic : str
        The DynamicJointState topic.
    path : str
        The bag, for messages.
    options : ReadOptions
        The joint, the interface of each channel and the units (the current, speed and
        position units are applied by :func:`read_bag`, the duty here).
    topics : dict, optional
        Channel -> Float64 topic name of the channels the joint has no interface for.
    sample_period_s : float, optional
        Grid step when Float64 topics are paired [s]; default the median step.

    Raises
    ------
    InputDataError
        The joint or an asked-for interface is absent (naming what the messages have), or
        neither the joint nor a Float64 topic gives the current or the speed (naming the
        options that would).

    """
    names = dict(BAG_TOPICS)
    names.update(topics or {})
    header_stamps, log_stamps, joint_values, joint, present = _dynamic_joint_state_values(
        source, topic, path, options)
    wanted = [channel for channel in ('voltage', 'current', 'speed')
              if channel not in joint_values
              and not (channel == 'voltage' and options.bus_voltage is not None)]
    float_topics = _float64_topics(source.topics, names, wanted, topic, path)
    _require_dynamic_channels(source, topic, path, names, (joint, present),
                              set(joint_values) | set(float_topics))
    columns = _pair_with_float64(source, topic, path, header_stamps, log_stamps, joint_values,
                                 float_topics, sample_period_s)
    return build_record(columns, replace(options, current_unit='A', speed_unit='rad/s',
                                         speed_counts_per_rev=None, position_unit='rad',
                                         position_counts_per_rev=None, gear_ratio=1.0),
                        source=path)


def _require_dynamic_channels(source: MessageSource, topic: str, path: str,
                              names: Mapping[str, str], joint: tuple[str, list[str]],
                              found: Collection[str]) -> None:
    """
    Refuse a DynamicJointState bag without speed or current (``found``: the channels read).

    ``joint`` is the joint's name and the interfaces it has (named in the message, with the
    options that would give the channel).
    """
    name, present = joint
    for channel in ('speed', 'current'):
        if channel in found:
            continue
        interface = DEFAULT_INTERFACES[channel]  # one asked for has raised already
        listing = ', '.join(f'{topic_name} [{kind}]'
                            for topic_name, kind in sorted(source.topics.items()))
        hint = (' (e.g. --interface current=effort, with --torque-constant 1 if the effort is '
                'a torque in N m: mechanical-only)' if channel == 'current' else '')
        raise InputDataError(
            f'{path}: no {channel}: joint {name!r} in {topic} has no {interface!r} interface '
            f'(it has {", ".join(present) or "none"}) and the bag has no Float64 {channel} '
            f'topic ({names[channel]}); it has {listing}. Name the interface with --interface '
            f'{channel}=NAME{hint} or the topic with --{channel}-topic')


def _dynamic_joint_state_values(source: MessageSource, topic: str, path: str,
                                options: ReadOptions,
                                ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], str,
                                           list[str]]:
    """
    Decode a joint's interfaces from DynamicJointState messages, in time order.

    Returns the header stamps (the bag's time where a stamp is zero), the bag's times [ns],
    channel -> values, the joint and the interface names of its last message. An interface
    asked for in ``options.interfaces`` must be there in every message; a default one is
    dropped when a message lacks it.
    """
    msgtype = source.topics[topic]
    typestore = jazzy_typestore()
    register_from_bag(typestore, source, msgtype, path)
    interfaces = dict(DEFAULT_INTERFACES)
    interfaces.update(options.interfaces)
    header_stamps: list[int] = []
    log_stamps: list[int] = []
    values: dict[str, list[float]] = {channel: [] for channel in interfaces}
    joint = options.joint
    present: list[str] = []
    for _, stamp, data in source.messages((topic,)):
        message = deserialize(typestore, data, msgtype, topic, path, stamp)
        names = list(message.joint_names)
        joint = _choose_joint(names, joint, topic, path)
        entry = message.interface_values[names.index(joint)]
        available = dict(zip(entry.interface_names, entry.values))
        present = list(available)
        for channel, name in list(interfaces.items()):
            if name in available:
                values[channel].append(float(available[name]))
            elif channel in options.interfaces:
                raise InputDataError(
                    f'{path}: joint {joint!r} has no interface {name!r} for the {channel}; it '
                    f'has {", ".join(available)} (--interface {channel}=NAME)')
            else:
                del interfaces[channel]
                values.pop(channel)
        header_ns = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        header_stamps.append(int(header_ns) if header_ns else int(stamp))
        log_stamps.append(int(stamp))
    if not header_stamps or joint is None:
        raise InputDataError(f'{path}: topic {topic} has no messages')
    order = np.argsort(np.asarray(header_stamps, dtype=np.int64), kind='stable')
    return (np.asarray(header_stamps, dtype=np.int64)[order],
            np.asarray(log_stamps, dtype=np.int64)[order],
            {channel: np.asarray(items, dtype=float)[order] for channel, items in values.items()},
            joint, present)


def _float64_topics(available: Mapping[str, str], names: Mapping[str, str],
                    channels: Collection[str], own_topic: str, path: str) -> dict[str, str]:
    """
    Return channel -> ``std_msgs/msg/Float64`` topic of those ``channels`` the bag has.

    ``names`` gives each channel's topic name (a relative name matches any namespace); the
    joint states' own topic never counts. A topic of another type is refused.
    """
    float_topics: dict[str, str] = {}
    for channel in channels:
        name = match_topic(names[channel], available)
        if name is None or name == own_topic:
            continue
        if available[name] != FLOAT64_TYPE:
            raise InputDataError(f'{path}: topic {name} is {available[name]}; the {channel} '
                                 f'topic must be {FLOAT64_TYPE}')
        float_topics[channel] = name
    return float_topics


def _pair_with_float64(source: MessageSource, topic: str, path: str,
                       header_stamps: np.ndarray, log_stamps: np.ndarray,
                       joint_values: Mapping[str, np.ndarray], float_topics: Mapping[str, str],
                       sample_period_s: Optional[float]) -> dict[str, np.ndarray]:
    """
    Pair a joint's samples with Float64 topics by timestamp on one grid; return the columns.

    The joint's samples (from ``topic``) are timed by their header stamps, or by the bag's
    times when the header stamps are on another clock (with a warning). Without Float64
    topics the columns are the joint's own, at its header stamps. ``t`` is in s from the
    first sample.
    """
    from dcmotor_id.formats.streams import align_timestamps

    if not float_topics:
        columns: dict[str, np.ndarray] = {
            't': (header_stamps - header_stamps[0]).astype(float) * 1e-9}
        columns.update(joint_values)
        return columns
    offset = np.median(header_stamps - log_stamps)
    if abs(offset) > MAX_CLOCK_OFFSET_NS:
        warnings.warn(
            f'{path}: the header stamps of {topic} are {offset * 1e-9:.3g} s from the time '
            'the bag gives its messages (another clock); its samples are paired with the '
            'Float64 topics by the bag time instead', UserWarning, stacklevel=5)
        header_stamps = log_stamps
    stamps_by_channel: dict[str, np.ndarray] = {}
    values_by_channel: dict[str, np.ndarray] = {}
    for channel, values in joint_values.items():
        stamps_by_channel[channel] = header_stamps
        values_by_channel[channel] = values
    float_stamps, float_values = read_float64(source, float_topics, jazzy_typestore(), path)
    stamps_by_channel.update(float_stamps)
    values_by_channel.update(float_values)
    grid, aligned = align_timestamps(stamps_by_channel, values_by_channel, sample_period_s,
                                     source=path)
    return {'t': (grid - grid[0]).astype(float) * 1e-9, **aligned}


def joint_state_topic(available: Mapping[str, str]) -> Optional[str]:
    """Return the bag's JointState topic (``/joint_states`` or the only one), or None."""
    topic = match_topic(JOINT_STATES_TOPIC, available)
    if topic is not None and available[topic] == JOINT_STATE_TYPE:
        return topic
    typed = [name for name, kind in available.items() if kind == JOINT_STATE_TYPE]
    return typed[0] if len(typed) == 1 else None


def read_joint_states(source: MessageSource, topic: str, path: str,
                      options: ReadOptions = DEFAULT_OPTIONS,
                      topics: Optional[Mapping[str, str]] = None,
                      sample_period_s: Optional[float] = None) -> Record:
    """
    Read one joint of ``sensor_msgs/msg/JointState`` messages, with Float64 topics beside.

    The conventions are the identifier node's (``input: joint_state``): each message is one
    sample at its header stamp (the bag's time when the stamp is zero); the joint is
    ``options.joint`` (or the only one). A channel named in ``options.interfaces`` is that
    field of the joint; any other channel comes from its ``std_msgs/msg/Float64`` topic
    (``topics``, default :data:`BAG_TOPICS`) when the bag has one, else speed from the
    ``velocity`` field and position from the ``position`` field. The current is read from a
    field only when asked (``--interface current=effort``: effort is a torque on most robots).
    Float64 topics are paired with the joint's samples by timestamp on one grid.

    Parameters
    ----------
    source : MessageSource
        The open bag.
    topic : str
        The JointState topic.
    path : str
        The bag, for messages.
    options : ReadOptions
        The joint, the field of each channel (``interfaces``: channel -> ``position``,
        ``velocity`` or ``effort``) and the units (applied by :func:`read_bag`).
    topics : dict, optional
        Channel -> Float64 topic name of the channels not in the joint states.
    sample_period_s : float, optional
        Grid step when Float64 topics are paired [s]; default the median step.

    Raises
    ------
    InputDataError
        The joint is absent or ambiguous, a field asked for is not a JointState field or is
        empty, or neither the joint states nor a topic give the current or the speed (naming
        the option that would).

    """
    names = dict(BAG_TOPICS)
    names.update(topics or {})
    for channel, field_name in options.interfaces.items():
        if field_name not in JOINT_STATE_FIELDS:
            raise InputDataError(
                f'{path}: --interface {channel}={field_name}: {topic} is a '
                f'{JOINT_STATE_TYPE}, whose fields are {", ".join(JOINT_STATE_FIELDS)}')
    float_topics = _float64_topics(
        source.topics, names, [channel for channel in ('voltage', 'current', 'speed')
                               if channel not in options.interfaces], topic, path)
    fields = {channel: field_name for channel, field_name in DEFAULT_JOINT_STATE_FIELDS.items()
              if channel not in float_topics}
    fields.update(options.interfaces)
    header_stamps, log_stamps, joint_values = _joint_state_values(
        source, topic, path, options.joint, fields, explicit=set(options.interfaces))
    _require_joint_channels(source, topic, path, names, set(joint_values) | set(float_topics))
    columns = _pair_with_float64(source, topic, path, header_stamps, log_stamps, joint_values,
                                 float_topics, sample_period_s)
    return build_record(columns, _si_options(options), source=path)


def _require_joint_channels(source: MessageSource, topic: str, path: str,
                            names: Mapping[str, str], found: Collection[str]) -> None:
    """Refuse a JointState bag without speed or current (``found``: the channels read)."""
    missing = [channel for channel in ('current', 'speed') if channel not in found]
    if 'speed' in missing:
        raise InputDataError(
            f'{path}: no speed: the joint in {topic} has no velocity values and the bag has no '
            f'Float64 speed topic ({names["speed"]}); take it from another field with '
            '--interface speed=FIELD or name its topic with --speed-topic')
    if missing:
        listing = ', '.join(f'{name} [{kind}]' for name, kind in sorted(source.topics.items()))
        raise InputDataError(
            f'{path}: no current: {topic} ({JOINT_STATE_TYPE}) gives the current only when '
            f'asked and the bag has no Float64 current topic ({names["current"]}); it has '
            f'{listing}. If the effort of the joint is the motor current, add --interface '
            'current=effort (with --current-unit mA if in mA); if it is a torque in N m, add '
            '--interface current=effort --torque-constant 1 (mechanical-only: J, b, Mc); or '
            'name the current topic with --current-topic')


def _joint_state_values(source: MessageSource, topic: str, path: str, joint: Optional[str],
                        fields: Mapping[str, str], explicit: Collection[str],
                        ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """
    Decode a joint's fields from JointState messages, in time order.

    Returns the header stamps (the bag's time where a stamp is zero), the bag's times [ns]
    and channel -> values. A field asked for explicitly (``explicit``) must be there in every
    message; a default one is dropped when a message lacks it.
    """
    typestore = jazzy_typestore()
    header_stamps: list[int] = []
    log_stamps: list[int] = []
    values: dict[str, list[float]] = {channel: [] for channel in fields}
    for _, stamp, data in source.messages((topic,)):
        message = deserialize(typestore, data, JOINT_STATE_TYPE, topic, path, stamp)
        names = list(message.name)
        joint = _choose_joint(names, joint, topic, path)
        index = names.index(joint)
        for channel, field_name in list(fields.items()):
            if channel not in values:
                continue
            array = getattr(message, field_name)
            if len(array) > index:
                values[channel].append(float(array[index]))
            elif channel in explicit:
                present = [name for name in JOINT_STATE_FIELDS
                           if len(getattr(message, name)) > index]
                raise InputDataError(
                    f'{path}: joint {joint!r} in {topic} has no {field_name} values for the '
                    f'{channel} (the {field_name} array of the message is empty); it has '
                    f'{", ".join(present) or "no values"} (--interface {channel}=FIELD)')
            else:
                del values[channel]
        header_ns = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        header_stamps.append(int(header_ns) if header_ns else int(stamp))
        log_stamps.append(int(stamp))
    if not header_stamps:
        raise InputDataError(f'{path}: topic {topic} has no messages')
    order = np.argsort(np.asarray(header_stamps, dtype=np.int64), kind='stable')
    return (np.asarray(header_stamps, dtype=np.int64)[order],
            np.asarray(log_stamps, dtype=np.int64)[order],
            {channel: np.asarray(items, dtype=float)[order] for channel, items in values.items()})


def _si_options(options: ReadOptions) -> ReadOptions:
    """Return the options that keep the values as read (:func:`read_bag` applies the units)."""
    return replace(options, current_unit='A', speed_unit='rad/s', speed_counts_per_rev=None,
                   position_unit='rad', position_counts_per_rev=None, gear_ratio=1.0,
                   bus_voltage=None)
