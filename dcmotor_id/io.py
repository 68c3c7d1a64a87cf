"""
Measured records: the in-memory form, CSV reading and writing, and input checks.

A CSV file has a header naming the columns ``t`` [s], ``voltage`` [V], ``current`` [A],
``speed`` [rad/s] and optionally ``position`` [rad], in any order; other columns are ignored.
"""

import csv
from dataclasses import dataclass, replace
import errno
import os
import shutil

import numpy as np

from dcmotor_id.errors import InputDataError

#: Columns a record can carry, with their units.
COLUMNS = {'t': 's', 'voltage': 'V', 'current': 'A', 'speed': 'rad/s', 'position': 'rad'}
#: Fewest samples a record must have to be identified.
MIN_SAMPLES = 100
#: Largest tolerated deviation of a time step from the median step, relative.
SAMPLING_TOLERANCE = 0.01


@dataclass(frozen=True)
class Record:
    """
    One uniformly sampled measurement.

    Attributes
    ----------
    time_s : numpy.ndarray
        Sample instants [s].
    current : numpy.ndarray or None
        Armature current [A].
    voltage : numpy.ndarray or None
        Armature voltage [V], held over each sample.
    speed : numpy.ndarray or None
        Shaft speed [rad/s].
    position : numpy.ndarray or None
        Shaft position [rad].
    source : str
        Where the record came from (a path), for messages.

    """

    time_s: np.ndarray
    current: np.ndarray = None
    voltage: np.ndarray = None
    speed: np.ndarray = None
    position: np.ndarray = None
    source: str = ''

    @property
    def sample_period_s(self):
        """Median sample period [s]."""
        return float(np.median(np.diff(self.time_s)))

    def __len__(self):
        """Return the number of samples."""
        return int(self.time_s.shape[0])

    def replace(self, **changes):
        """Return a copy with some fields changed."""
        return replace(self, **changes)

    def slice(self, start, stop):  # noqa: A003  (a method, never shadows the builtin)
        """Return samples ``start:stop`` as a new record."""
        def cut(values):
            return None if values is None else values[start:stop]
        return Record(self.time_s[start:stop], cut(self.current), cut(self.voltage),
                      cut(self.speed), cut(self.position), self.source)

    def columns(self):
        """Return the present columns as a dict name -> array (``t`` first)."""
        out = {'t': self.time_s}
        for name in ('voltage', 'current', 'speed', 'position'):
            values = getattr(self, name)
            if values is not None:
                out[name] = values
        return out


#: Other names seen for the columns, for the hint of a refusal (never accepted silently).
_ALIASES = {
    't': ('time', 'time_s', 'timestamp', 'stamp'),
    'voltage': ('u', 'v', 'ua', 'volt', 'volts', 'voltage_v', 'armature_voltage'),
    'current': ('i', 'ia', 'amps', 'current_a', 'armature_current'),
    'speed': ('w', 'omega', 'speed_rad_s', 'velocity', 'rpm', 'n'),
    'position': ('theta', 'pos', 'angle', 'position_rad'),
}


def _check_names(path, header, index):
    """
    Refuse columns that are named like a known one but not exactly (e.g. ``Voltage``).

    A missing ``current``, or ``speed`` and ``position`` both missing, are refused here with the
    header's likely candidates named (every mode needs them); a missing ``voltage`` is left to
    the caller, since the mechanical-only mode does without it.
    """
    for name in COLUMNS:
        if name in index:
            continue
        near = [column for column in header
                if column.lower() == name or column.lower() in _ALIASES[name]]
        exact_case = [column for column in near if column.lower() == name]
        if exact_case:
            raise InputDataError(
                f'{path}: column {exact_case[0]!r} must be named {name!r} (column names are '
                f'lower case: {", ".join(COLUMNS)}); rename it')
        position_given = 'position' in index or any(
            column.lower() in _ALIASES['position'] for column in header)
        if near and (name == 'current' or (name == 'speed' and not position_given)):
            unit = ' (in rad/s)' if name == 'speed' else ' (in A)'
            raise InputDataError(
                f'{path}: no column named {name!r}; found {near[0]!r}: if that is the {name}, '
                f'rename it to {name}{unit}. The columns must be named {", ".join(COLUMNS)}')


def read_csv(path):
    """
    Read a record from a CSV file with a header row.

    Raises
    ------
    InputDataError
        When the file is missing, empty, lacks the ``t`` column, or has a cell that is not a
        number.

    """
    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file; give the path of a CSV file or a bag')
    with open(path, newline='', encoding='utf-8-sig') as stream:
        rows = [row for row in csv.reader(stream) if row and any(cell.strip() for cell in row)]
    if not rows:
        raise InputDataError(f'{path}: the file is empty; it needs a header row '
                             f'({", ".join(COLUMNS)}) and samples')
    header = [name.strip() for name in rows[0]]
    if len(header) == 1 and any(mark in header[0] for mark in (';', '\t', ' ')):
        raise InputDataError(f'{path}: the header {header[0]!r} is one single column: the file '
                             'must be comma-separated (t,voltage,current,speed)')
    index = {}
    for position, name in enumerate(header):
        if name in COLUMNS:
            if name in index:
                raise InputDataError(f'{path}: column {name!r} appears twice in the header')
            index[name] = position
    _check_names(path, header, index)
    if 't' not in index:
        near = [name for name in header if name.lower() in ('t', 'time', 'time_s', 'timestamp')]
        hint = f' (found {near[0]!r}: rename it to t)' if near else ''
        raise InputDataError(f'{path}: no time column t in the header {header}{hint}; the '
                             f'columns must be named {", ".join(COLUMNS)}')
    if len(rows) == 1:
        raise InputDataError(f'{path}: the file has a header but no samples; record or '
                             'export the data again')
    data = {name: np.empty(len(rows) - 1) for name in index}
    for row_number, row in enumerate(rows[1:], start=2):
        for name, column in index.items():
            try:
                data[name][row_number - 2] = float(row[column])
            except (IndexError, ValueError):
                cell = row[column] if column < len(row) else '(missing)'
                raise InputDataError(
                    f'{path}: line {row_number}, column {name!r}: {cell!r} is not a number; '
                    'fix or remove that line') from None
    return Record(time_s=data['t'], current=data.get('current'), voltage=data.get('voltage'),
                  speed=data.get('speed'), position=data.get('position'), source=str(path))


def write_csv(path, record):
    """Write a record as CSV with the standard header (``t`` first)."""
    columns = record.columns()
    names = list(columns)
    table = np.column_stack([columns[name] for name in names])
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    temporary = f'{path}.partial'
    np.savetxt(temporary, table, delimiter=',', header=','.join(names), comments='',
               fmt='%.17g')
    os.replace(temporary, path)


def check_record(record, need_voltage=True, resample=False):
    """
    Check a record and return it uniformly sampled, or raise :class:`InputDataError`.

    Parameters
    ----------
    record : Record
        The record as read.
    need_voltage : bool
        Whether a voltage column is required (not in mechanical-only mode).
    resample : bool
        Interpolate an irregularly sampled record onto a uniform grid instead of refusing it.

    """
    name = record.source or 'record'
    present = record.columns()
    needed = ['current'] + (['voltage'] if need_voltage else [])
    missing = [column for column in needed if column not in present]
    if record.speed is None and record.position is None:
        missing.append('speed (or position)')
    if missing:
        raise InputDataError(
            f'{name}: missing column(s) {", ".join(missing)}; found {", ".join(present)}. '
            'Name the columns t, voltage, current, speed (position optional); without a '
            'voltage column give --torque-constant for the mechanical-only mode')
    if len(record) < MIN_SAMPLES:
        raise InputDataError(f'{name}: only {len(record)} samples; at least {MIN_SAMPLES} are '
                             'needed to identify the motor: record for longer')
    for column, values in present.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputDataError(
                f'{name}: column {column!r} has {bad.size} NaN/inf value(s), the first at '
                f'sample {bad[0]} (t = {float(record.time_s[bad[0]]):.9g} s); remove or repair '
                'those samples')
    steps = np.diff(record.time_s)
    if np.any(steps == 0):
        row = int(np.flatnonzero(steps == 0)[0]) + 1
        raise InputDataError(f'{name}: duplicate timestamp t = {record.time_s[row]} at sample '
                             f'{row}; remove duplicated samples')
    if np.any(steps < 0):
        row = int(np.flatnonzero(steps < 0)[0]) + 1
        raise InputDataError(f'{name}: timestamps go backwards at sample {row} '
                             f'(t = {record.time_s[row]} after {record.time_s[row - 1]}); sort '
                             'the samples by time')
    period = float(np.median(steps))
    deviation = np.abs(steps - period) / period
    if np.max(deviation) > SAMPLING_TOLERANCE:
        row = int(np.argmax(deviation)) + 1
        if not resample:
            raise InputDataError(
                f'{name}: irregular sampling: the step before sample {row} is '
                f'{steps[row - 1]:.6g} s against a median of {period:.6g} s. The methods need a '
                'uniform grid: pass --resample to interpolate onto one, or fix the recording')
        return resample_uniform(record, period)
    return record


def resample_uniform(record, sample_period_s):
    """Interpolate every column linearly onto a uniform grid of the given period."""
    t = record.time_s
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) / sample_period_s)) + 1) * sample_period_s

    def interp(values):
        return None if values is None else np.interp(grid, t, values)
    return Record(grid, interp(record.current), interp(record.voltage), interp(record.speed),
                  interp(record.position), record.source)


# --------------------------------------------------------------------------------------------
# rosbag2 bags (MCAP or sqlite3 directories, bare .mcap/.db3 files)

#: Topic of every channel in a bag, as the identifier node names them (relative names match
#: any namespace: ``voltage`` matches ``/voltage`` and ``/drive/voltage``).
BAG_TOPICS = {'voltage': 'voltage', 'current': 'current', 'speed': 'speed', 'samples': 'samples'}
#: Label of the first dimension of a batched ``std_msgs/msg/Float64MultiArray`` sample message:
#: the data hold ``t`` [s] of every sample, then every voltage [V], current [A], speed [rad/s].
BATCH_LABEL = 't,voltage,current,speed'
#: Channels carried by a batch, in order.
BATCH_CHANNELS = ('t', 'voltage', 'current', 'speed')
#: Prefix of the window bags written by :class:`WindowBagWriter`.
WINDOW_PREFIX = 'window_'
_PARTIAL_PREFIX = '.partial_'
_FLOAT64 = 'std_msgs/msg/Float64'
_FLOAT64_ARRAY = 'std_msgs/msg/Float64MultiArray'
_CDR_LE = b'\x00\x01\x00\x00'
_FLOAT64_CDR = np.dtype([('header', 'S4'), ('data', '<f8')])


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def record_from_stamps(stamps_ns, channels, source=''):
    """
    Build a record from grid timestamps [ns] and channel arrays (time from the first stamp).

    The node and :func:`read_bag` both build records this way, so a window identified in the
    node and the same window read back from its bag give identical arrays.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    time_s = (stamps - stamps[0]).astype(float) * 1e-9
    return Record(time_s, current=channels.get('current'), voltage=channels.get('voltage'),
                  speed=channels.get('speed'), position=channels.get('position'),
                  source=str(source))


def encode_batch(time_s, voltage, current, speed):
    """Lay out samples as the data of a batched Float64MultiArray (see :data:`BATCH_LABEL`)."""
    return np.concatenate([np.asarray(values, dtype=float) for values in
                           (time_s, voltage, current, speed)])


def decode_batch(labels, sizes, data):
    """
    Split the data of a batched Float64MultiArray into ``t, voltage, current, speed``.

    Raises
    ------
    InputDataError
        When the layout is not the documented one.

    """
    data = np.asarray(data, dtype=float)
    if len(labels) < 1 or labels[0] != BATCH_LABEL or sizes[0] != len(BATCH_CHANNELS):
        raise InputDataError(
            f'batched samples need layout.dim[0] labelled {BATCH_LABEL!r} with size '
            f'{len(BATCH_CHANNELS)} (got labels {list(labels)}, sizes {list(sizes)})')
    if data.size % len(BATCH_CHANNELS):
        raise InputDataError(f'batched samples: {data.size} values is not a multiple of '
                             f'{len(BATCH_CHANNELS)} channels')
    return data.reshape(len(BATCH_CHANNELS), -1)


def _match_topic(wanted, available):
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


def read_bag(path, topics=None, sample_period_s=None):
    """
    Read a record from a rosbag2 bag, using the bag's own timestamps.

    Accepts a bag directory (MCAP or sqlite3 storage, with metadata.yaml) or a bare ``.mcap``
    or ``.db3`` file. Either the three ``std_msgs/msg/Float64`` topics voltage, current and
    speed are paired by timestamp on a uniform grid, or one batched
    ``std_msgs/msg/Float64MultiArray`` samples topic (layout :data:`BATCH_LABEL`) gives every
    sample its own time (message timestamp plus its offset in the batch).

    Parameters
    ----------
    path : str
        The bag.
    topics : dict, optional
        Channel (``voltage``, ``current``, ``speed``, ``samples``) -> topic name; missing
        channels keep :data:`BAG_TOPICS`. A relative name matches any namespace.
    sample_period_s : float, optional
        Grid step [s]; default the median step of the timestamps.

    Raises
    ------
    InputDataError
        When the bag cannot be read (naming the topics it has), or its timestamps do not lie
        on a uniform grid.

    """
    from rosbags.rosbag2 import Reader
    from dcmotor_id.streams import align_timestamps

    names = dict(BAG_TOPICS)
    names.update(topics or {})
    path = str(path)
    if os.path.isdir(path) and not os.path.isfile(os.path.join(path, 'metadata.yaml')):
        raise InputDataError(
            f'{path}: a directory without metadata.yaml is not a finished rosbag2 bag (a '
            'recording that was killed before it closed?); give a bag directory or a .mcap '
            'file')
    if not os.path.exists(path):
        raise InputDataError(f'{path}: no such file or directory; give a CSV file, a rosbag2 '
                             'directory or a .mcap file')
    typestore = _typestore()
    try:
        reader = Reader(path)
        reader.open()
    except Exception as error:  # noqa: BLE001  (rosbags raises several unrelated types)
        raise InputDataError(f'{path}: cannot open as a rosbag2 bag ({error})') from None
    try:
        available = {conn.topic: conn.msgtype for conn in reader.connections}
        batch_topic = _match_topic(names['samples'], available)
        if batch_topic is not None and available[batch_topic] == _FLOAT64_ARRAY:
            return _read_batches(reader, batch_topic, typestore, path, sample_period_s)
        wanted = {channel: _match_topic(names[channel], available)
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
        wanted = {channel: topic for channel, topic in wanted.items() if topic is not None}
        for channel, topic in wanted.items():
            if available[topic] != _FLOAT64:
                raise InputDataError(f'{path}: topic {topic} is {available[topic]}; the '
                                     f'{channel} topic must be {_FLOAT64}')
        raw = {channel: ([], []) for channel in wanted}
        by_topic = {topic: channel for channel, topic in wanted.items()}
        connections = [conn for conn in reader.connections if conn.topic in by_topic]
        for connection, stamp, data in reader.messages(connections=connections):
            stamps, payloads = raw[by_topic[connection.topic]]
            stamps.append(stamp)
            payloads.append(bytes(data))
    finally:
        reader.close()
    stamps_by_channel, values_by_channel = {}, {}
    for channel, (stamps, payloads) in raw.items():
        if not stamps:
            raise InputDataError(f'{path}: topic {wanted[channel]} has no messages')
        stamps_by_channel[channel] = np.array(stamps, dtype=np.int64)
        values_by_channel[channel] = _decode_float64(payloads, typestore)
    grid, values = align_timestamps(stamps_by_channel, values_by_channel, sample_period_s,
                                    source=path)
    return record_from_stamps(grid, values, source=path)


def _decode_float64(payloads, typestore):
    if all(len(data) == 12 and data[:4] == _CDR_LE for data in payloads):
        return np.frombuffer(b''.join(payloads), dtype=_FLOAT64_CDR)['data'].astype(float)
    return np.array([typestore.deserialize_cdr(data, _FLOAT64).data for data in payloads])


def _read_batches(reader, topic, typestore, path, sample_period_s):
    from dcmotor_id.streams import align_timestamps

    stamps, blocks = [], []
    connections = [conn for conn in reader.connections if conn.topic == topic]
    for _, stamp, data in reader.messages(connections=connections):
        message = typestore.deserialize_cdr(data, _FLOAT64_ARRAY)
        dims = message.layout.dim
        block = decode_batch([dim.label for dim in dims], [dim.size for dim in dims],
                             message.data)
        if block.shape[1] == 0:
            continue
        offsets = np.rint((block[0] - block[0, 0]) * 1e9).astype(np.int64)
        stamps.append(np.int64(stamp) + offsets)
        blocks.append(block[1:])
    if not stamps:
        raise InputDataError(f'{path}: topic {topic} has no samples')
    stamps = np.concatenate(stamps)
    values = np.hstack(blocks)
    channels = BATCH_CHANNELS[1:]
    grid, aligned = align_timestamps({name: stamps for name in channels},
                                     {name: values[row] for row, name in enumerate(channels)},
                                     sample_period_s, source=path)
    return record_from_stamps(grid, aligned, source=path)


def write_bag(path, stamps_ns, channels, topics=None, batch_samples=0):
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
        samples on the samples topic (see :data:`BATCH_LABEL`).

    Returns
    -------
    int
        Bytes written.

    """
    from rosbags.rosbag2 import StoragePlugin, Writer

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
    staging = os.path.join(parent, _PARTIAL_PREFIX + name)
    if os.path.exists(staging):
        shutil.rmtree(staging)
    os.makedirs(staging)
    temporary = os.path.join(staging, name)
    typestore = _typestore()
    try:
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
        _fsync_tree(temporary)
        os.rename(temporary, path)
        _fsync_dir(parent)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return bag_size(path)


def _write_float64(writer, typestore, names, stamps, channels):
    ordered = [channel for channel in ('voltage', 'current', 'speed') if channel in channels]
    connections = [writer.add_connection(names[channel], _FLOAT64, typestore=typestore)
                   for channel in ordered]
    payloads = []
    for channel in ordered:
        table = np.empty(stamps.size, dtype=_FLOAT64_CDR)
        table['header'] = _CDR_LE
        table['data'] = np.asarray(channels[channel], dtype=float)
        payloads.append(table.tobytes())
    size = _FLOAT64_CDR.itemsize
    for row, stamp in enumerate(stamps.tolist()):
        for connection, payload in zip(connections, payloads):
            writer.write(connection, stamp, payload[row * size:(row + 1) * size])


def _write_batches(writer, typestore, topic, stamps, channels, batch_samples):
    message_type = typestore.types[_FLOAT64_ARRAY]
    layout_type = typestore.types['std_msgs/msg/MultiArrayLayout']
    dim_type = typestore.types['std_msgs/msg/MultiArrayDimension']
    connection = writer.add_connection(topic, _FLOAT64_ARRAY, typestore=typestore)
    nan = np.full(stamps.size, np.nan)
    for start in range(0, stamps.size, batch_samples):
        part = slice(start, min(start + batch_samples, stamps.size))
        count = part.stop - part.start
        time_s = (stamps[part] - stamps[part.start]).astype(float) * 1e-9
        data = encode_batch(time_s, channels.get('voltage', nan)[part],
                            channels['current'][part], channels['speed'][part])
        layout = layout_type(dim=[dim_type(label=BATCH_LABEL, size=len(BATCH_CHANNELS),
                                           stride=len(BATCH_CHANNELS) * count),
                                  dim_type(label='sample', size=count, stride=count)],
                             data_offset=0)
        message = message_type(layout=layout, data=data)
        writer.write(connection, int(stamps[part.start]),
                     typestore.serialize_cdr(message, _FLOAT64_ARRAY))


def _fsync_tree(path):
    for name in os.listdir(path):
        descriptor = os.open(os.path.join(path, name), os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)
    _fsync_dir(path)


def _fsync_dir(path):
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def bag_size(path):
    """Bytes used by the files of a bag directory."""
    return sum(entry.stat().st_size for entry in os.scandir(path) if entry.is_file())


class WindowBagWriter:
    """
    Write consecutive windows of samples as separate bags under a directory, within a budget.

    Every window becomes its own bag directory ``window_<number>_<first stamp ns>`` written
    by :func:`write_bag` (temporary name, then rename), so a window on disk is always a
    finished, readable bag, whatever happens to the process. After each window the oldest
    windows are deleted until the total is within ``budget_bytes`` (the newest is kept).
    Leftover temporary directories of a killed writer are removed on start.

    Parameters
    ----------
    record_dir : str
        Directory of the windows (created if needed).
    budget_bytes : int
        Disk budget of all windows together.
    topics : dict, optional
        Channel -> topic name written (see :func:`write_bag`).
    batch_samples : int
        0 for Float64 messages, N for batches of N samples.
    min_free_bytes : int
        Refuse to start a window when the file system has less free space than this plus
        the size of the window (an ``OSError`` with ``ENOSPC``).

    """

    def __init__(self, record_dir, budget_bytes, topics=None, batch_samples=0,
                 min_free_bytes=16 * 2 ** 20):
        self.record_dir = os.path.abspath(os.path.expanduser(str(record_dir)))
        self.budget_bytes = int(budget_bytes)
        self.topics = topics
        self.batch_samples = int(batch_samples)
        self.min_free_bytes = int(min_free_bytes)
        self.deleted = []
        self.removed_partials = []
        os.makedirs(self.record_dir, exist_ok=True)
        for entry in os.scandir(self.record_dir):
            if entry.name.startswith(_PARTIAL_PREFIX + WINDOW_PREFIX) and entry.is_dir():
                shutil.rmtree(entry.path, ignore_errors=True)
                self.removed_partials.append(entry.path)
        numbers = [self._number(path) for path in self.windows()]
        self._next_number = max(numbers, default=0) + 1

    @staticmethod
    def _number(path):
        try:
            return int(os.path.basename(path)[len(WINDOW_PREFIX):].split('_')[0])
        except ValueError:
            return 0

    def windows(self):
        """Paths of the finished windows, oldest first."""
        try:
            entries = [entry for entry in os.scandir(self.record_dir)
                       if entry.name.startswith(WINDOW_PREFIX) and entry.is_dir()]
        except FileNotFoundError:
            return []
        return [entry.path for entry in sorted(entries, key=lambda e: self._number(e.path))]

    def estimate_bytes(self, n_samples, n_channels=3):
        """Rough size of a window of ``n_samples`` [bytes] (for the free-space check)."""
        per_sample = 8 * (n_channels + 1) if self.batch_samples else 45 * n_channels
        return 4096 + n_samples * per_sample

    def write(self, stamps_ns, channels):
        """Write one window; return its path. Rotates the oldest windows out of the budget."""
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        free = shutil.disk_usage(self.record_dir).free
        need = self.estimate_bytes(stamps.size, len(channels)) + self.min_free_bytes
        if free < need:
            raise OSError(errno.ENOSPC, f'{self.record_dir}: only {free / 2 ** 20:.1f} MiB '
                          f'free, a window needs {need / 2 ** 20:.1f} MiB with the margin; '
                          'free space or point record_dir elsewhere')
        name = f'{WINDOW_PREFIX}{self._next_number:06d}_{int(stamps[0])}'
        path = os.path.join(self.record_dir, name)
        write_bag(path, stamps, channels, topics=self.topics, batch_samples=self.batch_samples)
        self._next_number += 1
        self.rotate(keep=path)
        return path

    def rotate(self, keep=None):
        """Delete the oldest windows until the total is within the budget."""
        windows = self.windows()
        sizes = {path: bag_size(path) for path in windows}
        total = sum(sizes.values())
        for path in windows:
            if total <= self.budget_bytes or path == keep:
                break
            shutil.rmtree(path, ignore_errors=True)
            total -= sizes[path]
            self.deleted.append(path)
        return total
