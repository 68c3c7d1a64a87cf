"""The :class:`Record` type (one uniformly sampled measurement) and its input checks."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import cached_property
import os
from typing import Any, Optional, Sequence, Union

import numpy as np

from dcmotor_id.core.checks import Check, register
from dcmotor_id.core.errors import InputDataError

#: A path given as text or as an :class:`os.PathLike`.
PathLike = Union[str, 'os.PathLike[str]']
#: Columns a record can carry, with their units.
COLUMNS = {'t': 's', 'voltage': 'V', 'current': 'A', 'speed': 'rad/s', 'position': 'rad'}
#: Fewest samples a record must have to be identified.
MIN_SAMPLES = 100
#: Largest tolerated deviation of a time step from the median step, relative.
SAMPLING_TOLERANCE = 0.01
#: Largest magnitude a drive's signal can have, by column: beyond it the values are corrupt
#: (or in the wrong unit); 1e9 V, A or rad/s is far above any electric drive.
MAGNITUDE_LIMITS = {'voltage': 1e9, 'current': 1e9, 'speed': 1e9, 'position': 1e12}
#: Largest ratio of a sample's magnitude to the column's typical one (its 99th percentile of
#: the non-zero magnitudes): a few samples this far above the rest are corrupt, not measured.
OUTLIER_RATIO = 1e8
#: Longest sample period of a record [s]: a DC motor's time constants are microseconds to
#: seconds; samples further apart (a time column in another unit, a wrong --sample-period)
#: cannot identify it, and beyond ~1e300 s they overflowed the simulation.
MAX_SAMPLE_PERIOD_S = 1e3


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
    speed_derived : bool
        The speed was derived from the position (not measured): the fit's ``auto`` criterion
        then compares the position instead
        (:mod:`dcmotor_id.identification.error_model.criterion`).
    segment : numpy.ndarray or None
        The tests of the record, as logged (``--segment-column``): a value > 0 marks a
        test's samples (a change of value starts another test), 0 the samples between tests
        (:mod:`dcmotor_id.identification.pipeline.segments`).
    notes : tuple of str
        What the preparation changed in the record as read (an angle unwrapped), said first
        among the warnings of its identification.

    """

    time_s: np.ndarray
    current: Optional[np.ndarray] = None
    voltage: Optional[np.ndarray] = None
    speed: Optional[np.ndarray] = None
    position: Optional[np.ndarray] = None
    source: str = ''
    speed_derived: bool = False
    segment: Optional[np.ndarray] = None
    notes: tuple[str, ...] = ()

    @cached_property
    def sample_period_s(self) -> float:
        """Median sample period [s] (computed on first use and kept: a record is frozen)."""
        return float(np.median(np.diff(self.time_s)))

    @property
    def speed_from_position(self) -> bool:
        """
        Whether the speed was derived from the position and the position is there to give it.

        True when :attr:`speed_derived` and a position of two samples or more: each sample
        period's mean speed is then the position's increment over it
        (:func:`~dcmotor_id.signals.filters.period_mean_speed`), free of the derivative
        filter's lag and smear, which the ramp check's one-step test and the speed's error
        over the sample periods compare instead of the derived speed.
        """
        return self.speed_derived and self.position is not None and len(self) > 1

    def noise_std(self, channel: str) -> float:
        """
        White-noise level of a channel (:func:`~dcmotor_id.core.noise.noise_std`).

        Measured on first use and kept, as :attr:`sample_period_s` (a record is frozen): the
        checks around a fit ask for the current's and the speed's about twenty times per
        ``identify`` call.
        """
        return self._channel_noise(channel)[0]

    def noise_level(self, channel: str) -> float:
        """
        Noise level of a channel with its quantisation floor (kept as :meth:`noise_std`).

        :func:`~dcmotor_id.core.noise.noise_level` of the channel.
        """
        return self._channel_noise(channel)[1]

    def _channel_noise(self, channel: str) -> list[float]:
        """Return ``[noise_std, noise_level]`` of a channel, measured on first use."""
        from dcmotor_id.core.noise import noise_level, noise_std

        if channel not in self._noise_levels:
            values = np.asarray(getattr(self, channel), dtype=float)
            std = noise_std(values)
            self._noise_levels[channel] = [std, noise_level(values, std)]
        return self._noise_levels[channel]

    @cached_property
    def _noise_levels(self) -> dict[str, list[float]]:
        """Return the noise levels measured so far, by channel (:meth:`_channel_noise`)."""
        return {}

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
                      cut(self.speed), cut(self.position), self.source, self.speed_derived,
                      cut(self.segment), self.notes)

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


#: Why a record without a current cannot be identified with others that have one.
NO_CURRENT = ('. Without the current, voltage and speed determine only the combinations '
              'kS = Ra Mc/CPhi, kV = CPhi + Ra b/CPhi and kA = Ra J/CPhi (the voltage-to-speed '
              'model), not the parameters: identify the records without a current on their own '
              '(they give kS, kV, kA), or record the armature current (a shunt, a current probe '
              "or the drive's current monitor; with a current-controlled drive its current "
              'set-point is the current)')


def check_record(record: Record, need_voltage: bool = True,
                 resample: bool = False, need_current: bool = True) -> Record:
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
    need_current : bool
        Whether a current column is required (not for the voltage-to-speed model).

    """
    name = record.source or 'record'
    present = record.columns()
    needed = (['current'] if need_current else []) + (['voltage'] if need_voltage else [])
    missing = [column for column in needed if column not in present]
    if record.speed is None and record.position is None:
        missing.append('speed (or position)')
    if missing:
        raise InputDataError(
            f'{name}: missing column(s) {", ".join(missing)}; found {", ".join(present)}. '
            'Name the columns t, voltage, current, speed (position optional); without a '
            'voltage column give --torque-constant for the mechanical-only mode'
            + (NO_CURRENT if missing[0] == 'current' else ''))
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
    check_magnitudes(record)
    steps = np.diff(record.time_s)
    if np.any(steps == 0):
        row = int(np.flatnonzero(steps == 0)[0]) + 1
        raise InputDataError(f'{name}: duplicate timestamp t = {record.time_s[row]} at sample '
                             f'{row}; remove duplicated samples, or, if the samples are '
                             'uniformly spaced and only the stamps are wrong, give the sample '
                             'period with --sample-period S (the time column is then not used)')
    if np.any(steps < 0):
        row = int(np.flatnonzero(steps < 0)[0]) + 1
        raise InputDataError(f'{name}: timestamps go backwards at sample {row} '
                             f'(t = {record.time_s[row]} after {record.time_s[row - 1]}); sort '
                             'the samples by time')
    period = _checked_period(name, steps)
    deviation = np.abs(steps - period) / period
    if np.max(deviation) > SAMPLING_TOLERANCE:
        if not resample:
            raise InputDataError(irregular_sampling(name, steps, period))
        return resample_uniform(record, period)
    return record


def _checked_period(name: str, steps: np.ndarray) -> float:
    """Return the median time step; refuse one beyond :data:`MAX_SAMPLE_PERIOD_S`."""
    period = float(np.median(steps))
    if period > MAX_SAMPLE_PERIOD_S:
        raise InputDataError(f'{name}: samples {period:.6g} s apart: no DC motor can be '
                             f'identified from samples more than {MAX_SAMPLE_PERIOD_S:g} s apart '
                             '(its time constants are microseconds to seconds); check the unit '
                             'of the time column or the --sample-period')
    return period


def check_magnitudes(record: Record) -> None:
    """
    Refuse finite values no drive produces, naming the column and the first such sample.

    Two checks per column: absolutely (:data:`MAGNITUDE_LIMITS`) and relative to the other
    samples (:data:`OUTLIER_RATIO` times the 99th percentile of the non-zero magnitudes), so
    a few corrupt samples (say +-1e308, finite but enough to overflow every derivative and
    make a least-squares solver loop) never reach the fit. The time column must advance by
    finite steps.

    Raises
    ------
    InputDataError
        Naming the column, the sample and its time, and what to do.

    """
    name = record.source or 'record'
    with np.errstate(over='ignore', invalid='ignore'):
        steps = np.diff(record.time_s)
    if steps.size and not np.all(np.isfinite(steps)):
        row = int(np.flatnonzero(~np.isfinite(steps))[0]) + 1
        raise InputDataError(
            f"{name}: column 't' jumps by more than a float can hold before sample {row} "
            f'(t = {float(record.time_s[row]):.6g} s); the times must be seconds on one clock')
    for column, limit in MAGNITUDE_LIMITS.items():
        values = getattr(record, column)
        if values is None or values.size == 0:
            continue
        magnitude = np.abs(np.asarray(values, dtype=float))
        unit = COLUMNS[column]
        beyond = np.flatnonzero(magnitude > limit)
        if beyond.size:
            row = int(beyond[0])
            raise InputDataError(
                f'{name}: column {column!r} has {beyond.size} value(s) beyond {limit:g} {unit}, '
                f'the first {float(values[row]):.6g} {unit} at sample {row} (t = '
                f'{float(record.time_s[row]):.9g} s): no drive produces that; remove or repair '
                f'those samples, or convert the column to {unit}')
        nonzero = magnitude[magnitude > 0]
        if nonzero.size < 10:
            continue
        typical = float(np.percentile(nonzero, 99.0))
        outliers = np.flatnonzero(magnitude > OUTLIER_RATIO * typical)
        if outliers.size:
            row = int(outliers[0])
            raise InputDataError(
                f'{name}: column {column!r} has {outliers.size} value(s) more than '
                f'{OUTLIER_RATIO:g} times its typical magnitude ({typical:.3g} {unit}), the first '
                f'{float(values[row]):.6g} {unit} at sample {row} (t = '
                f'{float(record.time_s[row]):.9g} s): corrupt samples; remove or repair them')


#: A step this many median periods long is a gap (samples missing), not a jittered stamp.
GAP_PERIODS = 3.0
#: A median step this long [s] may be milliseconds read as seconds: the refusal says so.
MILLISECOND_HINT_S = 1.0


def irregular_sampling(name: str, steps: np.ndarray, period: float) -> str:
    """
    Return the refusal of a record off a uniform grid, with the fix for what it is.

    Gaps (samples missing: a lost packet, a paused logger) and stamps that jitter around a
    fixed rate (a logger on a PC stamping on arrival) need different fixes: a gap is better
    split off than interpolated across, jittered stamps are better replaced by the rate.
    """
    row = int(np.argmax(np.abs(steps - period))) + 1
    text = (f'{name}: irregular sampling: the step before sample {row} is '
            f'{steps[row - 1]:.6g} s against a median of {period:.6g} s. The methods need a '
            'uniform grid')
    gaps = np.flatnonzero(steps > GAP_PERIODS * period)
    if gaps.size:
        longest = int(gaps[np.argmax(steps[gaps])])
        missing = int(round(steps[longest] / period)) - 1
        return (f'{text}: {gaps.size} gap(s) in the time stamps, the longest '
                f'{steps[longest]:.6g} s before sample {longest + 1} (about {missing} samples '
                'missing). Split the record at the gaps into files of their own (each is '
                'fitted from its own initial state), or pass --resample to interpolate across '
                'them (it invents the samples in between)')
    millis = (f' (stamps {period:.6g} s apart: if the time column is in milliseconds, that '
              f'is --sample-period {period / 1000.0:.6g}, and --time-unit ms reads its stamps '
              'in ms)') if period >= MILLISECOND_HINT_S else ''
    return (f'{text}: the stamps jitter between {float(np.min(steps)):.6g} and '
            f'{float(np.max(steps)):.6g} s. If the samples were taken at a fixed rate and only '
            f'the stamps jitter (a logger stamping on arrival), give --sample-period '
            f'{period:.6g}{millis} (the time column is then not used); else pass --resample to '
            'interpolate onto a uniform grid')


def resample_uniform(record: Record, sample_period_s: float) -> Record:
    """Interpolate every column linearly onto a uniform grid of the given period."""
    t = record.time_s
    grid = t[0] + np.arange(int(np.floor((t[-1] - t[0]) / sample_period_s)) + 1) * sample_period_s

    def interp(values: Optional[np.ndarray]) -> Optional[np.ndarray]:
        return None if values is None else np.interp(grid, t, values)
    # a test's mark is not interpolated: each grid point takes the mark of the sample before
    segment = None if record.segment is None else record.segment[
        np.clip(np.searchsorted(t, grid, side='right') - 1, 0, len(t) - 1)]
    return Record(grid, interp(record.current), interp(record.voltage), interp(record.speed),
                  interp(record.position), record.source, segment=segment)


def record_names(records: Sequence[Record]) -> str | None:
    """Name the records for the progress line: the one source, or how many records."""
    names = [rec.source for rec in records if rec.source]
    if not names:
        return None
    return names[0] if len(names) == 1 else f'{len(records)} records'


register(Check('record', 'read', 'record', check_record,
               "a record's channels: lengths, finite values, increasing times, regular sampling"))
register(Check('magnitudes', 'read', 'record', check_magnitudes,
               'channels in implausible units or scales (a voltage in mV, a speed in rpm)'))
