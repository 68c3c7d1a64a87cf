"""
WPILib DataLog files (``.wpilog``), what FRC robots and WPILib SysId record.

A DataLog holds named entries (``/motor/voltage``, ``NT:/URCL/SparkMax-12/Velocity``), each
logged at its own instants with a timestamp in microseconds. The channels are addressed by
entry name (``--column voltage=/motor/voltage --column speed=...``); without ``--column`` the
reader refuses with the list of the entries and their types. The time comes from the records'
timestamps:

* channels logged at the same instants (within a quarter of a period, the common case of
  entries appended in one robot loop) are paired on one uniform grid as the bag reader pairs
  topics (:func:`dcmotor_id.formats.streams.align_timestamps`), values unchanged;
* otherwise (other rates, other phases) they are resampled onto one grid, the step of the
  slowest channel (or ``--sample-period``): the voltage, duty and direction held from their
  last value (what a drive applies), the other channels interpolated linearly; a note says so.

The ``sysid-test-state-<mechanism>`` string entry of WPILib's SysIdRoutine marks its tests
(quasistatic and dynamic, forward and reverse): their stretches are printed as a note.

The file is read with ``wpiutil.log.DataLogReader`` of the ``robotpy-wpiutil`` package (an
optional dependency: ``pip install robotpy-wpiutil``); without it the reader refuses, saying
so. Units: as the entries hold them (``--speed-unit rpm``, ``--current-unit``, ...).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Optional

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike, Record
from dcmotor_id.formats.mapping import build_record, DEFAULT_OPTIONS, note, ReadOptions
from dcmotor_id.formats.streams import align_timestamps

__all__ = ['read_wpilog', 'sysid_segments', 'WPILOG_SUFFIXES']

#: File name endings of WPILib DataLog files.
WPILOG_SUFFIXES = ('.wpilog',)
#: Entry types read as numbers -> the DataLogRecord getter.
NUMERIC_TYPES = {'double': 'getDouble', 'float': 'getFloat', 'int64': 'getInteger'}
#: Name (after the last ``/``) of the string entry of WPILib's SysIdRoutine test states.
SYSID_STATE_PREFIX = 'sysid-test-state-'
#: Channels held from their last value when resampled (what a drive applies); the others are
#: interpolated linearly.
HELD_CHANNELS = ('voltage', 'duty', 'direction')


@dataclasses.dataclass
class _Entry:
    """One entry of the log: its name, type (``kind``) and the records read for it."""

    name: str
    kind: str
    stamps_us: list = dataclasses.field(default_factory=list)
    values: list = dataclasses.field(default_factory=list)


def _open_reader(path: PathLike) -> Any:
    """Return a ``wpiutil.log.DataLogReader`` of the file; refuse clearly without wpiutil."""
    try:
        from wpiutil.log import DataLogReader
    except ImportError:
        raise InputDataError(
            f'{path}: a WPILib DataLog (.wpilog); reading it needs the robotpy-wpiutil '
            'package: pip install robotpy-wpiutil (or export the channels to CSV with '
            "WPILib's DataLogTool)") from None
    try:
        reader = DataLogReader(str(path))
    except (OSError, RuntimeError, ValueError) as error:
        raise InputDataError(f'{path}: not readable as a WPILib DataLog ({error})') from None
    if not reader.isValid():
        raise InputDataError(f'{path}: not a WPILib DataLog (no WPILOG header); give a .wpilog '
                             'file as the robot wrote it')
    return reader


def _is_state_entry(name: str) -> bool:
    return name.rsplit('/', 1)[-1].startswith(SYSID_STATE_PREFIX)


def _read_entries(path: PathLike, wanted: set[str]) -> dict[str, _Entry]:
    """
    Read the entries of a log by name: every entry's type, and the records of the wanted ones.

    Only the entries named in ``wanted`` and the SysId test-state entries keep their records
    (an entry finished and started again under the same name keeps one list).
    """
    by_name: dict[str, _Entry] = {}
    by_id: dict[int, _Entry] = {}
    for record in _open_reader(path):
        if record.isStart():
            data = record.getStartData()
            by_id[data.entry] = by_name.setdefault(data.name, _Entry(data.name, data.type))
            continue
        if record.isControl():
            continue
        found = by_id.get(record.getEntry())
        if found is None:
            continue
        entry = found
        if entry.name in wanted and entry.kind in NUMERIC_TYPES:
            entry.stamps_us.append(record.getTimestamp())
            entry.values.append(getattr(record, NUMERIC_TYPES[entry.kind])())
        elif entry.kind == 'string' and _is_state_entry(entry.name):
            entry.stamps_us.append(record.getTimestamp())
            entry.values.append(record.getString())
    return by_name


def _entry_list(entries: dict[str, _Entry]) -> str:
    return ', '.join(f'{name} ({entry.kind})' for name, entry in sorted(entries.items()))


def _channel_entries(path: PathLike, entries: dict[str, _Entry],
                     options: ReadOptions) -> dict[str, _Entry]:
    """Return channel -> entry of the ``--column`` mapping; refuse what cannot be read."""
    if 't' in options.columns:
        raise InputDataError(f'{path}: --column t=...: the time of a .wpilog comes from its '
                             "records' timestamps; leave t out")
    if not options.columns:
        raise InputDataError(
            f'{path}: a WPILib DataLog names its channels by entry; say which entry is which '
            'with --column voltage=ENTRY --column current=ENTRY --column speed=ENTRY (or '
            f'position=ENTRY). The entries: {_entry_list(entries) or "none"}')
    chosen = {}
    for channel, name in options.columns.items():
        entry = entries.get(name)
        if entry is None:
            raise InputDataError(f'{path}: no entry {name!r} for {channel}; the entries: '
                                 f'{_entry_list(entries) or "none"}')
        if entry.kind not in NUMERIC_TYPES:
            raise InputDataError(f'{path}: entry {name!r} ({channel}) is of type {entry.kind}, '
                                 f'not a number ({", ".join(NUMERIC_TYPES)}); map another '
                                 'entry')
        if not entry.values:
            raise InputDataError(f'{path}: entry {name!r} ({channel}) has no values')
        chosen[channel] = entry
    return chosen


def _resampled(stamps_ns: dict[str, np.ndarray], values: dict[str, np.ndarray],
               sample_period_s: Optional[float],
               path: PathLike) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Resample channels logged at their own instants onto one grid (held or linear)."""
    steps = {channel: float(np.median(np.diff(stamps))) if stamps.size > 1 else 0.0
             for channel, stamps in stamps_ns.items()}
    period_ns = sample_period_s * 1e9 if sample_period_s else max(steps.values())
    start = max(int(stamps[0]) for stamps in stamps_ns.values())
    stop = min(int(stamps[-1]) for stamps in stamps_ns.values())
    if not period_ns > 0 or stop - start < 2 * period_ns:
        raise InputDataError(f'{path}: the entries mapped share no stretch of time with more '
                             'than two samples; map entries logged during the same test')
    grid = start + np.arange(int((stop - start) // period_ns) + 1) * period_ns
    aligned = {}
    for channel, stamps in stamps_ns.items():
        if channel in HELD_CHANNELS:
            index = np.searchsorted(stamps, grid, side='right') - 1
            aligned[channel] = values[channel][np.clip(index, 0, None)]
        else:
            aligned[channel] = np.interp(grid, stamps, values[channel])
    note(f'{path}: the entries are logged at their own instants ('
         + ', '.join(f'{channel} every {step * 1e-6:.4g} ms' for channel, step in steps.items())
         + f'); resampled onto one grid of {period_ns * 1e-6:.4g} ms: '
         + ', '.join(channel for channel in aligned if channel in HELD_CHANNELS)
         + ' held, the others interpolated linearly')
    return np.rint(grid).astype(np.int64), aligned


def _sorted_channel(entry: _Entry) -> tuple[np.ndarray, np.ndarray]:
    stamps = np.asarray(entry.stamps_us, dtype=np.int64) * 1000
    order = np.argsort(stamps, kind='stable')
    return stamps[order], np.asarray(entry.values, dtype=float)[order]


def _aligned(path: PathLike, chosen: dict[str, _Entry],
             sample_period_s: Optional[float]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Put the channels on one grid: paired when they share instants, else resampled."""
    stamps_ns, values = {}, {}
    for channel, entry in chosen.items():
        stamps_ns[channel], values[channel] = _sorted_channel(entry)
    try:
        return align_timestamps(stamps_ns, values, sample_period_s, str(path))
    except InputDataError:
        return _resampled(stamps_ns, values, sample_period_s, path)


def sysid_segments(entries: dict[str, _Entry], origin_us: float) -> list[tuple[str, str, float,
                                                                               float]]:
    """
    Return the SysId test stretches: (entry, state, start [s], end [s]) from ``origin_us``.

    A stretch runs from a state's record to the next record of the entry; the state ``none``
    (between tests) is left out, and the last stretch ends at the last record.
    """
    segments = []
    for name, entry in sorted(entries.items()):
        if not (entry.kind == 'string' and _is_state_entry(name) and entry.stamps_us):
            continue
        stamps = list(entry.stamps_us) + [entry.stamps_us[-1]]
        for index, state in enumerate(entry.values):
            if state and state != 'none':
                segments.append((name, state, (stamps[index] - origin_us) * 1e-6,
                                 (stamps[index + 1] - origin_us) * 1e-6))
    return segments


def read_wpilog(path: PathLike, options: ReadOptions = DEFAULT_OPTIONS,
                sample_period_s: Optional[float] = None, **_: Any) -> Record:
    """
    Read a record from a WPILib DataLog, its channels addressed by entry name.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.wpilog`` file.
    options : ReadOptions
        ``columns`` maps channels to entry names (required); units, gear, sign as for any
        file.
    sample_period_s : float, optional
        Grid step [s]; default from the timestamps.

    Raises
    ------
    InputDataError
        Without robotpy-wpiutil, for a file that is not a DataLog, without ``--column``
        (listing the entries and their types), or for an entry that is absent or not a number.

    """
    wanted = set(options.columns.values())
    entries = _read_entries(path, wanted)
    chosen = _channel_entries(path, entries, options)
    stamps_ns, aligned = _aligned(path, chosen, sample_period_s or options.sample_period_s)
    segments = sysid_segments(entries, stamps_ns[0] / 1000.0)
    if segments:
        note(f'{path}: SysId tests (t from the first sample): ' + '; '.join(
            f'{state} {max(start, 0.0):.3f}..{end:.3f} s' for _, state, start, end in segments))
    columns = {'t': (stamps_ns - stamps_ns[0]) * 1e-9, **aligned}
    return build_record(columns, dataclasses.replace(options, sample_period_s=None),
                        source=str(path))
