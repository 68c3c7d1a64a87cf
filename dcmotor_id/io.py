"""Measured records: the in-memory form, CSV reading and writing, and input checks.

A CSV file has a header naming the columns ``t`` [s], ``voltage`` [V], ``current`` [A],
``speed`` [rad/s] and optionally ``position`` [rad], in any order; other columns are ignored.
"""

import csv
import os
from dataclasses import dataclass, replace

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
    """One uniformly sampled measurement.

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

    def slice(self, start, stop):
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


def read_csv(path):
    """Read a record from a CSV file with a header row.

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
    index = {}
    for position, name in enumerate(header):
        if name in COLUMNS:
            if name in index:
                raise InputDataError(f'{path}: column {name!r} appears twice in the header')
            index[name] = position
    if 't' not in index:
        near = [name for name in header if name.lower() in ('t', 'time', 'time_s', 'timestamp')]
        hint = f' (found {near[0]!r}: rename it to t)' if near else ''
        raise InputDataError(f'{path}: no time column t in the header {header}{hint}; the '
                             f'columns must be named {", ".join(COLUMNS)}')
    if len(rows) == 1:
        raise InputDataError(f'{path}: the file has a header but no samples')
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
    """Check a record and return it uniformly sampled, or raise :class:`InputDataError`.

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
                f'sample {bad[0]} (t = {record.time_s[bad[0]]!r}); remove or repair them')
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
