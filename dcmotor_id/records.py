"""The :class:`Record` type (one uniformly sampled measurement) and its input checks."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
import os
from typing import Any, Optional, Union

import numpy as np

from dcmotor_id.errors import InputDataError

#: A path given as text or as an :class:`os.PathLike`.
PathLike = Union[str, 'os.PathLike[str]']
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
    current: Optional[np.ndarray] = None
    voltage: Optional[np.ndarray] = None
    speed: Optional[np.ndarray] = None
    position: Optional[np.ndarray] = None
    source: str = ''

    @property
    def sample_period_s(self) -> float:
        """Median sample period [s]."""
        return float(np.median(np.diff(self.time_s)))

    def __len__(self) -> int:
        """Return the number of samples."""
        return int(self.time_s.shape[0])

    def replace(self, **changes: Any) -> Record:
        """Return a copy with some fields changed."""
        return replace(self, **changes)

    def slice(self, start: int, stop: int) -> Record:  # noqa: A003  (a method, not the builtin)
        """Return samples ``start:stop`` as a new record."""
        def cut(values: Optional[np.ndarray]) -> Optional[np.ndarray]:
            return None if values is None else values[start:stop]
        return Record(self.time_s[start:stop], cut(self.current), cut(self.voltage),
                      cut(self.speed), cut(self.position), self.source)

    def columns(self) -> dict[str, np.ndarray]:
        """Return the present columns as a dict name -> array (``t`` first)."""
        out = {'t': self.time_s}
        for name in ('voltage', 'current', 'speed', 'position'):
            values = getattr(self, name)
            if values is not None:
                out[name] = values
        return out


def record_from_stamps(stamps_ns: np.ndarray, channels: Mapping[str, np.ndarray],
                       source: str = '') -> Record:
    """
    Build a record from grid timestamps [ns] and channel arrays (time from the first stamp).

    The node and :func:`dcmotor_id.formats.bag.read_bag` both build records this way, so a
    window identified in the node and the same window read back from its bag give identical
    arrays.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    time_s = (stamps - stamps[0]).astype(float) * 1e-9
    return Record(time_s, current=channels.get('current'), voltage=channels.get('voltage'),
                  speed=channels.get('speed'), position=channels.get('position'),
                  source=str(source))


def check_record(record: Record, need_voltage: bool = True,
                 resample: bool = False) -> Record:
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


def resample_uniform(record: Record, sample_period_s: float) -> Record:
    """Interpolate every column linearly onto a uniform grid of the given period."""
    t = record.time_s
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) / sample_period_s)) + 1) * sample_period_s

    def interp(values: Optional[np.ndarray]) -> Optional[np.ndarray]:
        return None if values is None else np.interp(grid, t, values)
    return Record(grid, interp(record.current), interp(record.voltage), interp(record.speed),
                  interp(record.position), record.source)
