"""
Reading a record from a bag: Float64 topics, batched samples or joint states, by what it has.

The bag's own timestamps time the samples; Float64 topics are paired on a uniform grid
(:func:`~dcmotor_id.formats.streams.align_timestamps`), a batched samples topic gives every
sample its own time, and joint states are read by :mod:`.joints`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
import struct
from typing import Any, Optional

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike, Record, record_from_stamps
from dcmotor_id.formats.bag.joints import (DYNAMIC_JOINT_STATES_TOPIC, joint_state_topic,
                                           read_dynamic_joint_states, read_joint_states)
from dcmotor_id.formats.bag.messages import (BAG_TOPICS, deserialize, FLOAT64_TYPE,
                                             jazzy_typestore, match_topic, read_float64)
from dcmotor_id.formats.bag.source import MessageSource, open_bag, Recovery, warn_recovered
from dcmotor_id.formats.batch import BATCH_CHANNELS, BATCH_TYPE, decode_batch_message
from dcmotor_id.formats.mapping import build_record, DEFAULT_OPTIONS, ReadOptions


def read_bag(path: PathLike, topics: Optional[Mapping[str, str]] = None,
             sample_period_s: Optional[float] = None,
             options: ReadOptions = DEFAULT_OPTIONS) -> Record:
    """
    Read a record from a rosbag2 bag, using the bag's own timestamps.

    Accepts a bag directory (MCAP or sqlite3 storage, with metadata.yaml) or a bare ``.mcap``
    or ``.db3`` file. Either the three ``std_msgs/msg/Float64`` topics voltage, current and
    speed are paired by timestamp on a uniform grid, or one batched
    ``std_msgs/msg/Float64MultiArray`` samples topic (layout
    :data:`dcmotor_id.formats.batch.BATCH_LABEL`) gives every sample its own time (message
    timestamp plus its offset in the batch). A truncated MCAP file is read up to its last
    complete chunk, with a :class:`TruncatedBagWarning`.

    Parameters
    ----------
    path : str
        The bag.
    topics : dict, optional
        Channel (``voltage``, ``current``, ``speed``, ``samples``) -> topic name; missing
        channels keep :data:`BAG_TOPICS`. A relative name matches any namespace.
    sample_period_s : float, optional
        Grid step [s]; default the median step of the timestamps.
    options : ReadOptions
        Units of the channels; for ``control_msgs/msg/DynamicJointState`` bags (topic
        :data:`DYNAMIC_JOINT_STATES_TOPIC`) the joint and the interface of each channel, a
        channel without one from its Float64 topic (:func:`read_dynamic_joint_states`); for
        ``sensor_msgs/msg/JointState`` bags (topic :data:`JOINT_STATES_TOPIC`, read when a
        current or speed topic is missing or a joint or an interface is named) the joint and
        the field of each channel, the other channels from their Float64 topics
        (:func:`read_joint_states`).

    Raises
    ------
    InputDataError
        When the bag cannot be read (naming the topics it has), or its timestamps do not lie
        on a uniform grid.

    """
    record = _read_bag_si(path, topics, sample_period_s, options)
    if options == DEFAULT_OPTIONS:
        return record
    columns: dict[str, np.ndarray] = dict(record.columns())
    return build_record(columns, replace(options, bus_voltage=None), source=record.source)


def _read_bag_si(path: PathLike, topics: Optional[Mapping[str, str]],
                 sample_period_s: Optional[float], options: ReadOptions) -> Record:
    try:
        return _read_bag_topics(path, topics, sample_period_s, options)
    except (AttributeError, KeyError, IndexError, TypeError, ValueError, RecursionError,
            struct.error, UnicodeError) as error:
        # A payload that decodes but holds the wrong fields (rosbags' SerdeError itself is
        # caught where it is raised, in deserialize).
        raise InputDataError(f'{path}: a message does not decode as its declared type '
                             f'({type(error).__name__}: {str(error)[:200]}); the bag is '
                             'damaged or declares a wrong type: re-record it or give other '
                             'topics') from None


def _read_bag_topics(path: PathLike, topics: Optional[Mapping[str, str]],
                     sample_period_s: Optional[float], options: ReadOptions) -> Record:
    from dcmotor_id.formats.streams import align_timestamps

    names = dict(BAG_TOPICS)
    names.update(topics or {})
    path = str(path)
    typestore = jazzy_typestore()
    with open_bag(path) as source:
        available = source.topics
        recovery = source.recovery
        joint_topic = match_topic(DYNAMIC_JOINT_STATES_TOPIC, available)
        state_topic = joint_state_topic(available)
        if joint_topic is not None and (
                options.joint is not None or match_topic(names['current'], available) is None
                or (state_topic is None and match_topic(names['speed'], available) is None)):
            record = read_dynamic_joint_states(source, joint_topic, path, options, names,
                                               sample_period_s)
            if recovery is not None:
                _warn_recovered_record(path, recovery, record)
            return record
        if state_topic is not None and (
                options.joint is not None or options.interfaces
                or any(match_topic(names[channel], available) is None
                       for channel in ('current', 'speed'))):
            record = read_joint_states(source, state_topic, path, options, names,
                                       sample_period_s)
            if recovery is not None:
                _warn_recovered_record(path, recovery, record)
            return record
        batch_topic = match_topic(names['samples'], available)
        if batch_topic is not None and available[batch_topic] == BATCH_TYPE:
            record = _read_batches(source, batch_topic, typestore, path, sample_period_s)
            if recovery is not None:
                _warn_recovered_record(path, recovery, record)
            return record
        wanted = {channel: match_topic(names[channel], available)
                  for channel in ('voltage', 'current', 'speed')}
        # voltage may be absent (mechanical-only identification); current and speed may not
        missing = [f'{channel} ({names[channel]})' for channel, topic in wanted.items()
                   if topic is None and channel != 'voltage']
        if missing:
            listing = ', '.join(f'{topic} [{kind}]' for topic, kind in sorted(available.items()))
            raise InputDataError(
                f'{path}: topic(s) {", ".join(missing)} not in the bag; it has: '
                f'{listing or "no topics"}. Name them with --voltage-topic, --current-topic, '
                '--speed-topic (or --samples-topic for batched samples)')
        chosen = {channel: topic for channel, topic in wanted.items() if topic is not None}
        for channel, topic in chosen.items():
            if available[topic] != FLOAT64_TYPE:
                raise InputDataError(f'{path}: topic {topic} is {available[topic]}; the '
                                     f'{channel} topic must be {FLOAT64_TYPE}')
        stamps_by_channel, values_by_channel = read_float64(source, chosen, typestore, path)
    grid, values = align_timestamps(stamps_by_channel, values_by_channel, sample_period_s,
                                    source=path)
    record = record_from_stamps(grid, values, source=path)
    if recovery is not None:
        _warn_recovered_record(path, recovery, record)
    return record


def _warn_recovered_record(path: str, recovery: Recovery, record: Record) -> None:
    warn_recovered(path, recovery, f'{len(record)} samples ({recovery.messages} messages)',
                   len(record) * record.sample_period_s, stacklevel=4)


def _read_batches(source: MessageSource, topic: str, typestore: Any, path: str,
                  sample_period_s: Optional[float]) -> Record:
    from dcmotor_id.formats.streams import align_timestamps

    stamps, blocks = [], []
    for _, stamp, data in source.messages((topic,)):
        block = decode_batch_message(deserialize(typestore, data, BATCH_TYPE, topic, path,
                                                 stamp))
        if block.shape[1] == 0:
            continue
        offsets = np.rint((block[0] - block[0, 0]) * 1e9).astype(np.int64)
        stamps.append(np.int64(stamp) + offsets)
        blocks.append(block[1:])
    if not stamps:
        raise InputDataError(f'{path}: topic {topic} has no samples')
    all_stamps = np.concatenate(stamps)
    values = np.hstack(blocks)
    channels = BATCH_CHANNELS[1:]
    grid, aligned = align_timestamps({name: all_stamps for name in channels},
                                     {name: values[row] for row, name in enumerate(channels)},
                                     sample_period_s, source=path)
    return record_from_stamps(grid, aligned, source=path)
