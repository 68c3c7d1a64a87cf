"""
Opening a rosbag2 bag: its messages undecoded, from rosbags or, when cut, from the MCAP bytes.

rosbags reads complete bags; an MCAP file whose end is missing (a recorder that crashed, a copy
that was interrupted) is read with the mcap library's stream reader up to its last complete
chunk instead, with a :class:`TruncatedBagWarning` saying how much was recovered. Lost or
undecodable messages of a damaged bag are reported with a :class:`DamagedBagWarning`.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
import io
import os
import struct
from typing import Any, Callable, Optional, Protocol
import warnings

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike
from dcmotor_id.formats.budget import check_budget
from dcmotor_id.formats.mapping import note


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


def warn_recovered(path: str, recovery: Recovery, what: str, duration_s: float,
                   stacklevel: int = 3) -> None:
    """Warn that ``path`` was truncated and ``what`` (spanning ``duration_s``) recovered."""
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
        warn_recovered(str(path), recovery, f'{len(messages)} messages', recovery.duration_s)
    return topics, messages
