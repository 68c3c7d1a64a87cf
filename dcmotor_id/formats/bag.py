"""
rosbag2 bags (MCAP or sqlite3 directories, bare ``.mcap``/``.db3`` files): reading and writing.

Reading goes through rosbags' reader; an MCAP file whose end is missing (a recorder that
crashed, a copy that was interrupted) is read with the mcap library's stream reader up to its
last complete chunk instead, with a :class:`TruncatedBagWarning` saying how much was recovered.
Writing produces a Jazzy (version 9) MCAP bag atomically: a temporary name, then one rename.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
import io
import os
import shutil
import struct
from typing import Any, Callable, Optional, Protocol
import warnings

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike, Record, record_from_stamps
from dcmotor_id.formats.batch import (BATCH_CHANNELS, batch_message, BATCH_TYPE, BatchTypes,
                                      decode_batch_message)
from dcmotor_id.formats.budget import check_budget
from dcmotor_id.formats.mapping import build_record, DEFAULT_OPTIONS, note, ReadOptions

#: Topic of every channel in a bag, as the identifier node names them (relative names match
#: any namespace: ``voltage`` matches ``/voltage`` and ``/drive/voltage``).
BAG_TOPICS = {'voltage': 'voltage', 'current': 'current', 'speed': 'speed', 'samples': 'samples'}
#: Prefix of the staging directory of a bag being written (removed by the window writer).
PARTIAL_PREFIX = '.partial_'
#: Message type of the per-sample topics.
FLOAT64_TYPE = 'std_msgs/msg/Float64'
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
#: The first bytes of an MCAP file.
MCAP_MAGIC = b'\x89MCAP0\r\n'


class DamagedBagWarning(UserWarning):
    """Messages of a bag were lost or could not be decoded; says how many, of which topic."""


class TruncatedBagWarning(UserWarning):
    """An MCAP file ended early; the messages of its complete chunks were read."""


@dataclass(frozen=True)
class Recovery:
    """
    What was read from a truncated MCAP file.

    Attributes
    ----------
    path : str
        The truncated file.
    messages : int
        Messages recovered (those of the complete chunks before the cut).
    first_ns, last_ns : int
        Timestamps of the first and last recovered message [ns] (0 when none).
    reason : str
        Why rosbags could not open the file.

    """

    path: str
    messages: int
    first_ns: int
    last_ns: int
    reason: str

    @property
    def duration_s(self) -> float:
        """Time spanned by the recovered messages [s]."""
        return (self.last_ns - self.first_ns) * 1e-9


class MessageSource(Protocol):
    """
    The messages of an open bag, undecoded (what :func:`open_bag` yields).

    Attributes
    ----------
    topics : dict
        Topic -> message type name (as the bag declares it; never imported here).
    recovery : Recovery or None
        What was read of a truncated MCAP file, or None for a complete bag.

    """

    topics: dict[str, str]
    recovery: Optional[Recovery]
    #: What was lost reading a damaged bag (one sentence each), filled as messages are read.
    damage: list[str]
    #: Message type -> its definition as stored in the bag (``ros2msg`` text, dependencies
    #: appended), for types the reader's type store does not know.
    definitions: dict[str, str]

    def messages(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        """Yield ``(topic, stamp_ns, cdr_bytes)`` of the given topics in time order."""


class _RosbagsSource:
    """Messages of a bag that rosbags opened."""

    def __init__(self, reader: Any) -> None:
        self._reader = reader
        self.topics = {conn.topic: conn.msgtype for conn in reader.connections}
        self.recovery: Optional[Recovery] = None
        self.damage: list[str] = []
        self.definitions = {conn.msgtype: getattr(conn.msgdef, 'data', '')
                            for conn in reader.connections}

    def messages(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        """
        Yield the messages; count them against the bag's own counts.

        A damaged bag (bytes overwritten mid-file) either stops rosbags' reader with an
        exception or loses messages silently: both end the reading here, and what was lost
        (how many messages of which topic, after which time) goes to :attr:`damage`.
        """
        connections = [conn for conn in self._reader.connections if conn.topic in topics]
        declared: dict[str, int] = {}
        for connection in connections:
            declared[connection.topic] = declared.get(connection.topic, 0) + int(
                getattr(connection, 'msgcount', 0) or 0)
        seen: dict[str, list[int]] = {topic: [] for topic in declared}
        stopped = ''
        try:
            for connection, stamp, data in self._reader.messages(connections=connections):
                seen[connection.topic].append(int(stamp))
                yield connection.topic, int(stamp), bytes(data)
        except Exception as error:  # noqa: BLE001  (rosbags raises anything on damaged bytes)
            stopped = f'reading stopped ({type(error).__name__}: {error}); '
        lost = {topic: declared[topic] - len(seen[topic]) for topic in declared
                if declared[topic] > len(seen[topic])}
        if stopped or lost:
            starts = [stamps[0] for stamps in seen.values() if stamps]
            origin = min(starts) if starts else 0
            self.damage.append(f'the bag is damaged: {stopped}' + ', '.join(
                f'{count} of {declared[topic]} messages of {topic} lost '
                f'({_gaps(seen[topic], origin)})' for topic, count in sorted(lost.items())))


def _gaps(stamps: list[int], origin: int, shown: int = 3) -> str:
    """Say where a topic's messages are missing: its widest gaps, in s from ``origin``."""
    if not stamps:
        return 'none of them could be read'
    times = np.asarray(stamps, dtype=np.int64)
    if times.size < 3:
        return f'only {times.size} read, up to t = {(times[-1] - origin) * 1e-9:.3f} s'
    steps = np.diff(times)
    typical = float(np.median(steps))
    wide = np.flatnonzero(steps > 1.5 * typical)
    if wide.size == 0:
        return f'after t = {(times[-1] - origin) * 1e-9:.3f} s of the recording'
    wide = wide[np.argsort(-steps[wide], kind='stable')][:shown]
    return 'missing ' + ', '.join(
        f'between t = {(times[k] - origin) * 1e-9:.3f} s and {(times[k + 1] - origin) * 1e-9:.3f}'
        ' s' for k in sorted(wide)) + (' and elsewhere' if np.sum(
            steps > 1.5 * typical) > shown else '')


class _RecoveredSource:
    """Messages read from the complete chunks of truncated MCAP files."""

    def __init__(self, topics: dict[str, str], messages: list[tuple[str, int, bytes]],
                 recovery: Recovery, definitions: Optional[dict[str, str]] = None) -> None:
        self.topics = topics
        self._messages = messages
        self.recovery: Optional[Recovery] = recovery
        self.damage: list[str] = []
        self.definitions = dict(definitions or {})

    def messages(self, topics: Collection[str]) -> Iterator[tuple[str, int, bytes]]:
        return (message for message in self._messages if message[0] in topics)


def _mcap_files(path: str) -> list[str]:
    if os.path.isdir(path):
        return sorted(os.path.join(path, name) for name in os.listdir(path)
                      if name.endswith('.mcap'))
    return [path] if path.endswith('.mcap') else []


def _mcap_pieces(data: bytes) -> tuple[int, bytes]:
    """
    Find where an MCAP file stops being complete.

    Returns the end of the last complete record (the file up to there is readable record by
    record) and, when the record cut by the end of the file is an uncompressed chunk, the
    bytes of that chunk's records that did arrive (else ``b''``). Only the record framing of
    the MCAP specification (opcode, uint64 length) and the chunk header are read here; the
    records themselves are parsed by the mcap library.
    """
    from mcap.opcode import Opcode

    position = len(MCAP_MAGIC)
    while position + 9 <= len(data):
        opcode, length = struct.unpack_from('<BQ', data, position)
        end = position + 9 + length
        if end > len(data):
            if opcode != Opcode.CHUNK:
                break
            # chunk: start, end time (uint64), uncompressed size (uint64), crc (uint32),
            # compression (uint32-prefixed string), records (uint64-prefixed bytes)
            header = position + 9 + 28
            if header + 4 > len(data):
                break
            (name_length,) = struct.unpack_from('<I', data, header)
            records = header + 4 + name_length + 8
            if records > len(data) or name_length:
                break  # only an uncompressed chunk can be read in part
            return position, data[records:]
        position = end
    return position, b''


def _recover_mcap(files: list[str], reason: str) -> Optional[_RecoveredSource]:
    """
    Read the complete records of MCAP files whose end is missing.

    Every chunk before the cut is complete and read whole; of an uncompressed chunk cut by
    the end of the file, the messages that arrived whole are read too. Return None when the
    files are not MCAP at all.
    """
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, str] = {}
    definitions: dict[str, str] = {}
    channels: dict[int, str] = {}
    topics: dict[str, str] = {}
    messages: list[tuple[str, int, bytes]] = []

    def take(stream: io.BytesIO, skip_magic: bool) -> None:
        try:
            for record in StreamReader(stream, skip_magic=skip_magic).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record.name
                    definitions[record.name] = bytes(record.data).decode('utf-8', 'replace')
                elif isinstance(record, Channel):
                    channels[record.id] = record.topic
                    topics[record.topic] = schemas.get(record.schema_id, '')
                elif isinstance(record, Message) and record.channel_id in channels:
                    messages.append((channels[record.channel_id], int(record.log_time),
                                     bytes(record.data)))
        except Exception:  # noqa: BLE001, S110  (the end of the bytes: EndOfFile or struct)
            pass
    for name in files:
        with open(name, 'rb') as stream:
            data = stream.read()
        if not data.startswith(MCAP_MAGIC):
            return None  # not an MCAP file: nothing to recover
        complete, partial = _mcap_pieces(data)
        take(io.BytesIO(data[:complete]), skip_magic=False)
        if partial:
            take(io.BytesIO(partial), skip_magic=True)
    messages.sort(key=lambda message: message[1])
    stamps = [message[1] for message in messages]
    recovery = Recovery(path=', '.join(files), messages=len(messages),
                        first_ns=min(stamps, default=0), last_ns=max(stamps, default=0),
                        reason=reason)
    return _RecoveredSource(topics, messages, recovery, definitions)


#: Peak memory of reading a bag per byte of its chunks, uncompressed, by the mean size of its
#: messages (measured 7.8 for the batched samples topic, 2.7 for one Float64 per message:
#: bench/csv_memory_results.md).
MCAP_PEAK_FACTOR = 8.0
MCAP_SMALL_MESSAGE_FACTOR = 3.0
#: Mean message size [bytes] below which a bag counts as one of small messages.
SMALL_MESSAGE_BYTES = 200.0


def _check_mcap_budget(files: list[str]) -> None:
    """
    Refuse MCAP files whose chunks decompress beyond the memory budget, before reading them.

    A chunk is decompressed whole (545 KB of zstd declared 3 GB): its declared uncompressed
    size, from the summary at the end of the file, is checked against the budget, as is the
    total of the chunks times :data:`MCAP_PEAK_FACTOR` or, for small messages,
    :data:`MCAP_SMALL_MESSAGE_FACTOR` (the messages read are kept, then
    decoded and aligned). Files without a summary (truncated)
    are left to the recovery, which reads them whole (bounded by their size on disk).
    """
    from mcap.reader import SeekingReader
    total = messages = 0.0
    for name in files:
        try:
            with open(name, 'rb') as stream:
                summary = SeekingReader(stream).get_summary()
        except Exception:  # noqa: BLE001, S112  (no or damaged summary: the recovery's case)
            continue
        if summary is None:
            continue
        for index in summary.chunk_indexes:
            check_budget(float(index.uncompressed_size), name,
                         f'a {index.compression or "uncompressed"} chunk of '
                         f'{index.compressed_size} bytes declaring {index.uncompressed_size} '
                         'bytes')
            total += float(index.uncompressed_size)
        if summary.statistics is not None:
            messages += float(summary.statistics.message_count)
    if files:
        factor = MCAP_SMALL_MESSAGE_FACTOR if messages and total / messages < \
            SMALL_MESSAGE_BYTES else MCAP_PEAK_FACTOR
        check_budget(factor * total, ', '.join(files),
                     f'chunks of {total:.4g} bytes (read at up to {factor:g} times that, '
                     'bench/csv_memory_results.md)')


@contextmanager
def open_bag(path: PathLike) -> Iterator[MessageSource]:
    """
    Open a bag for reading; yield its :class:`MessageSource`.

    rosbags reads complete bags; a truncated MCAP file is read with the mcap library up to
    the cut, and the source's ``recovery`` says how much that was.

    Raises
    ------
    InputDataError
        When the path is not a readable bag.

    """
    from rosbags.rosbag2 import Reader

    path = str(path)
    if os.path.isdir(path) and not os.path.isfile(os.path.join(path, 'metadata.yaml')):
        with open_bag(_unfinished_bag_file(path)) as source:
            yield source
        return
    if not os.path.exists(path):
        raise InputDataError(f'{path}: no such file or directory; give a CSV file, a rosbag2 '
                             'directory or a .mcap file')
    _check_mcap_budget(_mcap_files(path))
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # noqa: BLE001  (rosbags raises several unrelated types)
        reader, reason = None, str(error)
    if reader is None:
        files = _mcap_files(path)
        recovered = _recover_mcap(files, reason) if files else None
        if recovered is None or recovered.recovery is None or not recovered.recovery.messages:
            raise InputDataError(f'{path}: cannot open as a rosbag2 bag ({reason})')
        yield recovered
        _warn_damage(path, recovered)
        return
    try:
        source = _RosbagsSource(reader)
        yield source
        _warn_damage(path, source)
    finally:
        reader.close()


def _unfinished_bag_file(path: str) -> str:
    """
    Return the one MCAP file of a bag directory without ``metadata.yaml``, said in a note.

    rosbag2 writes ``metadata.yaml`` when it closes: a recording that was killed leaves the
    directory without it, and its MCAP file is read as it is (up to a cut, if it has one).
    """
    files = sorted(name for name in os.listdir(path) if name.endswith('.mcap'))
    if len(files) != 1:
        found = (f'it holds {len(files)} .mcap files ({", ".join(files[:4])}'
                 f'{", ..." if len(files) > 4 else ""}): give them one by one' if files
                 else 'it holds no .mcap file')
        raise InputDataError(
            f'{path}: a directory without metadata.yaml is not a finished rosbag2 bag (a '
            f'recording that was killed before it closed?) and {found}; give a bag directory '
            'or a .mcap file')
    note(f'{path}: no metadata.yaml (the recording did not close): read its file {files[0]} '
         'as it is')
    return os.path.join(path, files[0])


def _warn_damage(path: str, source: MessageSource) -> None:
    for text in dict.fromkeys(source.damage):
        warnings.warn(f'{path}: {text}', DamagedBagWarning, stacklevel=4)


def _warn_recovered(path: str, recovery: Recovery, what: str, duration_s: float,
                    stacklevel: int = 3) -> None:
    warnings.warn(
        f'{path}: the MCAP file is truncated ({recovery.reason}); recovered {what} spanning '
        f'{duration_s:.3f} s, every complete message before the cut; the rest is lost',
        TruncatedBagWarning, stacklevel=stacklevel)


def load_messages(path: PathLike, *,
                  check: Optional[Callable[[Mapping[str, str]], None]] = None,
                  ) -> tuple[dict[str, str], list[tuple[int, str, bytes]]]:
    """
    Read every message of a bag, undecoded.

    Parameters
    ----------
    path : str
        The bag.
    check : callable, optional
        Called with ``{topic: msgtype}`` before any message is read (it raises to refuse).

    Returns
    -------
    tuple
        ``({topic: msgtype}, [(stamp_ns, topic, cdr_bytes), ...])``, messages in time order.

    Raises
    ------
    InputDataError
        When the path is not a readable bag.

    """
    with open_bag(path) as source:
        topics = dict(source.topics)
        if check is not None:
            check(topics)
        messages = [(stamp, topic, data) for topic, stamp, data in source.messages(topics)]
        recovery = source.recovery
    messages.sort(key=lambda item: item[0])
    if recovery is not None:
        _warn_recovered(str(path), recovery, f'{len(messages)} messages', recovery.duration_s)
    return topics, messages


def _typestore() -> Any:
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def _batch_types(typestore: Any) -> BatchTypes:
    return BatchTypes(message=typestore.types[BATCH_TYPE],
                      layout=typestore.types['std_msgs/msg/MultiArrayLayout'],
                      dimension=typestore.types['std_msgs/msg/MultiArrayDimension'])


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
        # caught where it is raised, in _deserialize).
        raise InputDataError(f'{path}: a message does not decode as its declared type '
                             f'({type(error).__name__}: {str(error)[:200]}); the bag is '
                             'damaged or declares a wrong type: re-record it or give other '
                             'topics') from None


def _deserialize(typestore: Any, data: bytes, msgtype: str, topic: str, path: str,
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


def _read_bag_topics(path: PathLike, topics: Optional[Mapping[str, str]],
                     sample_period_s: Optional[float], options: ReadOptions) -> Record:
    from dcmotor_id.formats.streams import align_timestamps

    names = dict(BAG_TOPICS)
    names.update(topics or {})
    path = str(path)
    typestore = _typestore()
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
        stamps_by_channel, values_by_channel = _read_float64(source, chosen, typestore, path)
    grid, values = align_timestamps(stamps_by_channel, values_by_channel, sample_period_s,
                                    source=path)
    record = record_from_stamps(grid, values, source=path)
    if recovery is not None:
        _warn_recovered_record(path, recovery, record)
    return record


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
    typestore = _typestore()
    register_from_bag(typestore, source, msgtype, path)
    interfaces = dict(DEFAULT_INTERFACES)
    interfaces.update(options.interfaces)
    header_stamps: list[int] = []
    log_stamps: list[int] = []
    values: dict[str, list[float]] = {channel: [] for channel in interfaces}
    joint = options.joint
    present: list[str] = []
    for _, stamp, data in source.messages((topic,)):
        message = _deserialize(typestore, data, msgtype, topic, path, stamp)
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
    float_stamps, float_values = _read_float64(source, float_topics, _typestore(), path)
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
    typestore = _typestore()
    header_stamps: list[int] = []
    log_stamps: list[int] = []
    values: dict[str, list[float]] = {channel: [] for channel in fields}
    for _, stamp, data in source.messages((topic,)):
        message = _deserialize(typestore, data, JOINT_STATE_TYPE, topic, path, stamp)
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


def _warn_recovered_record(path: str, recovery: Recovery, record: Record) -> None:
    _warn_recovered(path, recovery, f'{len(record)} samples ({recovery.messages} messages)',
                    len(record) * record.sample_period_s, stacklevel=4)


def _read_float64(source: MessageSource, topics: Mapping[str, str], typestore: Any,
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


def _read_batches(source: MessageSource, topic: str, typestore: Any, path: str,
                  sample_period_s: Optional[float]) -> Record:
    from dcmotor_id.formats.streams import align_timestamps

    stamps, blocks = [], []
    for _, stamp, data in source.messages((topic,)):
        block = decode_batch_message(_deserialize(typestore, data, BATCH_TYPE, topic, path,
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


def write_bag(path: PathLike, stamps_ns: np.ndarray, channels: Mapping[str, np.ndarray],
              topics: Optional[Mapping[str, str]] = None, batch_samples: int = 0) -> int:
    """
    Write samples as a rosbag2 bag with MCAP storage (Jazzy's version 9), atomically.

    The bag is written under a temporary name next to ``path`` and renamed when complete, so
    ``path`` is either absent or a finished, readable bag, even if the process is killed.

    Parameters
    ----------
    path : str
        Bag directory to create (must not exist).
    stamps_ns : array_like of int
        Timestamp of every sample [ns] (the message timestamps).
    channels : dict
        ``voltage``, ``current``, ``speed`` -> arrays (voltage may be absent).
    topics : dict, optional
        Channel -> topic name written (default ``/voltage``, ``/current``, ``/speed``,
        ``/samples``).
    batch_samples : int
        0: one Float64 message per sample and channel; N > 0: Float64MultiArray messages of N
        samples on the samples topic (see :mod:`dcmotor_id.formats.batch`).

    Returns
    -------
    int
        Bytes written.

    """
    names = {channel: '/' + topic.lstrip('/') for channel, topic in BAG_TOPICS.items()}
    names.update(topics or {})
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    path = os.path.abspath(str(path))
    if os.path.exists(path):
        raise FileExistsError(f'{path} exists already; bags are never overwritten')
    parent, name = os.path.split(path)
    os.makedirs(parent, exist_ok=True)
    # the bag is built as <parent>/.partial_<name>/<name> so that its files carry their
    # final names, then moved up in one rename
    staging = os.path.join(parent, PARTIAL_PREFIX + name)
    if os.path.exists(staging):
        shutil.rmtree(staging)
    os.makedirs(staging)
    temporary = os.path.join(staging, name)
    try:
        _write_messages(temporary, names, stamps, channels, batch_samples)
        _fsync_tree(temporary)
        os.rename(temporary, path)
        _fsync_dir(parent)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return bag_size(path)


def _write_messages(temporary: str, names: Mapping[str, str], stamps: np.ndarray,
                    channels: Mapping[str, np.ndarray], batch_samples: int) -> None:
    """Write the bag's messages (Float64 per sample, or batches) at ``temporary``."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    typestore = _typestore()
    writer = Writer(temporary, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    try:
        if batch_samples > 0:
            _write_batches(writer, typestore, names['samples'], stamps, channels,
                           int(batch_samples))
        else:
            _write_float64(writer, typestore, names, stamps, channels)
    finally:
        writer.close()


def _write_float64(writer: Any, typestore: Any, names: Mapping[str, str], stamps: np.ndarray,
                   channels: Mapping[str, np.ndarray]) -> None:
    ordered = [channel for channel in ('voltage', 'current', 'speed') if channel in channels]
    connections = [writer.add_connection(names[channel], FLOAT64_TYPE, typestore=typestore)
                   for channel in ordered]
    # rosbags' serializer, not a hand-written CDR encoder (see bench/cdr_results.md)
    message = typestore.types[FLOAT64_TYPE]
    values = [np.asarray(channels[channel], dtype=float).tolist() for channel in ordered]
    for row, stamp in enumerate(stamps.tolist()):
        for connection, column in zip(connections, values):
            writer.write(connection, stamp,
                         typestore.serialize_cdr(message(data=column[row]), FLOAT64_TYPE))


def _write_batches(writer: Any, typestore: Any, topic: str, stamps: np.ndarray,
                   channels: Mapping[str, np.ndarray], batch_samples: int) -> None:
    types = _batch_types(typestore)
    connection = writer.add_connection(topic, BATCH_TYPE, typestore=typestore)
    nan = np.full(stamps.size, np.nan)
    for start in range(0, stamps.size, batch_samples):
        part = slice(start, min(start + batch_samples, stamps.size))
        time_s = (stamps[part] - stamps[part.start]).astype(float) * 1e-9
        message = batch_message(types, time_s, channels.get('voltage', nan)[part],
                                channels['current'][part], channels['speed'][part])
        writer.write(connection, int(stamps[part.start]),
                     typestore.serialize_cdr(message, BATCH_TYPE))


def _fsync_tree(path: str) -> None:
    for name in os.listdir(path):
        descriptor = os.open(os.path.join(path, name), os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
    _fsync_dir(path)


def _fsync_dir(path: str) -> None:
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def bag_size(path: PathLike) -> int:
    """Bytes used by the files of a bag directory."""
    return sum(entry.stat().st_size for entry in os.scandir(path) if entry.is_file())
