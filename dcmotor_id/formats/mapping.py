"""
How a recording's columns become a record's channels: column mapping, units, duty, gear.

Every reader (CSV, MATLAB, bags) hands over raw columns by their names in the file; a
:class:`ReadOptions` says which column is which channel (``--column voltage=m0_voltage``), in
which unit current, speed and position were written, whether the voltage is a PWM duty times a
bus voltage and whether speed and position were measured behind a gearbox.
:func:`build_record` turns the raw columns into a :class:`~dcmotor_id.core.records.Record` in SI
units at the motor shaft, which is what the identification and validation work in.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import math
import re
import shlex
from typing import Any, Optional
import warnings

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import Record

#: Channels a column can be mapped to (``duty`` and ``direction`` make the voltage;
#: ``segment`` marks the tests of a record, read only when mapped: ``--segment-column``).
CHANNELS = ('t', 'voltage', 'current', 'speed', 'position', 'duty', 'direction', 'segment')
#: Channels whose sign ``--negate`` flips.
SIGNED_CHANNELS = ('voltage', 'current', 'speed', 'position')
#: Channels whose sign ``--current-sign-from`` gives a current logged as a magnitude.
CURRENT_SIGN_SOURCES = ('voltage', 'speed')
#: Time column units -> factor to s (loggers stamp in ms, us or ns).
TIME_UNITS = {'s': 1.0, 'ms': 1e-3, 'us': 1e-6, 'ns': 1e-9}
#: Current units -> factor to A.
CURRENT_UNITS = {'A': 1.0, 'mA': 1e-3}
#: Speed units -> factor to rad/s.
SPEED_UNITS = {'rad/s': 1.0, 'rpm': 2.0 * math.pi / 60.0, 'rps': 2.0 * math.pi,
               'deg/s': math.pi / 180.0}
#: Position units -> factor to rad (``m`` for linear axes: kept as it is).
POSITION_UNITS = {'rad': 1.0, 'deg': math.pi / 180.0, 'm': 1.0}


#: Other names seen for the channels, for the hint of a refusal (never accepted silently).
ALIASES = {
    't': ('time', 'time_s', 'timestamp', 'stamp', 'tout'),
    'voltage': ('u', 'v', 'ua', 'va', 'volt', 'volts', 'voltage_v', 'armature_voltage'),
    'current': ('i', 'ia', 'amps', 'current_a', 'armature_current'),
    'speed': ('w', 'omega', 'speed_rad_s', 'velocity', 'rpm', 'n'),
    'position': ('theta', 'pos', 'angle', 'position_rad'),
}
#: A unit written after a column's name: ``Time [s]``, ``Current (A)``, ``speed {rad/s}``.
UNIT_SUFFIX = re.compile(r'\s*[\[({][^\])}]*[\])}]\s*$')


def bare_name(column: str) -> str:
    """
    Return a column's name as compared with the channels' names: lower case, no unit suffix.

    ``Time [s]``, ``Current (A)`` and ``speed_rad_s`` are looked up as ``time``, ``current``
    and ``speed_rad_s`` (spreadsheet and logger exports name their columns with units).
    """
    return UNIT_SUFFIX.sub('', column).strip().lower()


def column_option(channel: str, column: str) -> str:
    """Return the ``--column`` option that maps ``column`` to ``channel``, quoted for a shell."""
    if channel == 'segment':
        return '--segment-column ' + shlex.quote(column)
    return '--column ' + shlex.quote(f'{channel}={column}')


def looks_like(column: str, channel: str) -> bool:
    """Whether a column's name is the channel's own or one of its aliases (any case, units)."""
    bare = bare_name(column)
    return bare == channel or bare in ALIASES.get(channel, ())


def likely_columns(names: list[str], channels: tuple[str, ...]) -> dict[str, str]:
    """
    Return, per channel, the first name that looks like it (its own name or an alias).

    A dotted name (a MATLAB struct's field, ``output.time``) is judged by its last part.
    """
    found = {}
    for channel in channels:
        for name in names:
            if looks_like(name.rsplit('.', 1)[-1], channel):
                found[channel] = name
                break
    return found


@dataclass(frozen=True)
class ReadOptions:
    """
    How to read a recording (the CLI's reading options; the defaults read SI files as they are).

    Attributes
    ----------
    columns : dict
        Channel (:data:`CHANNELS`) -> name of its column in the file (CSV header name, MATLAB
        variable or ``variable:column`` with a 1-based column as in MATLAB).
    time_unit : str
        Unit of the time column (:data:`TIME_UNITS`; files with a time column: CSV, MATLAB,
        Parquet; bags and DataLogs carry their own stamps).
    current_unit : str
        Unit of the current column (:data:`CURRENT_UNITS`).
    speed_unit : str
        Unit of the speed column (:data:`SPEED_UNITS`).
    speed_counts_per_rev : float or None
        The speed column holds encoder pulses counted per sample, this many per revolution.
    position_unit : str
        Unit of the position column (:data:`POSITION_UNITS`).
    position_counts_per_rev : float or None
        The position column holds encoder counts, this many per revolution.
    gear_ratio : float
        Motor turns per output turn: speed and position were measured at the output shaft and
        are converted to the motor shaft (the parameters are then at the motor shaft).
    bus_voltage : float or None
        The voltage is ``duty * bus_voltage`` from a ``duty`` column in [-1, 1] (or in [0, 1]
        with a ``direction`` column whose positive values mean forward).
    duty_full_scale : float
        The duty column's value at full duty (1; 100 for percent, 255 for an 8-bit PWM
        register): the duty is divided by it.
    negated : tuple of str
        Channels (:data:`SIGNED_CHANNELS`) whose sign is flipped: an encoder counting the
        other way, a current sensor mounted the other way round.
    current_sign_from : str or None
        The current column is a magnitude (a motor controller's output current): it gets the
        sign of this channel (:data:`CURRENT_SIGN_SOURCES`; zero where that channel is zero).
    joint : str or None
        Bags with ``control_msgs/msg/DynamicJointState``: the joint to read.
    interfaces : dict
        Bags: channel -> interface name of the joint (default: the channel's own name, and
        ``velocity`` for speed, ``effort`` for nothing).
    sample_period_s : float or None
        The samples are this far apart [s]: the time is ``k * sample_period_s`` (for a file
        without a time column, or one whose time stamps are broken; a time column is then not
        used); for bags the grid step.

    """

    columns: Mapping[str, str] = field(default_factory=dict)
    time_unit: str = 's'
    current_unit: str = 'A'
    speed_unit: str = 'rad/s'
    speed_counts_per_rev: Optional[float] = None
    position_unit: str = 'rad'
    position_counts_per_rev: Optional[float] = None
    gear_ratio: float = 1.0
    bus_voltage: Optional[float] = None
    duty_full_scale: float = 1.0
    negated: tuple[str, ...] = ()
    current_sign_from: Optional[str] = None
    joint: Optional[str] = None
    interfaces: Mapping[str, str] = field(default_factory=dict)
    sample_period_s: Optional[float] = None

    def __post_init__(self) -> None:
        """Refuse unknown channels and units with a message naming the choices."""
        for channel in list(self.columns) + list(self.interfaces):
            if channel not in CHANNELS:
                raise InputDataError(f'--column/--interface {channel}=...: unknown channel '
                                     f'{channel!r}; the channels are {", ".join(CHANNELS)}')
        for channel in self.negated:
            if channel not in SIGNED_CHANNELS:
                raise InputDataError(f'--negate {channel}: choose one of '
                                     f'{", ".join(SIGNED_CHANNELS)}')
        if self.current_sign_from not in (None,) + CURRENT_SIGN_SOURCES:
            raise InputDataError(f'--current-sign-from {self.current_sign_from}: choose one of '
                                 f'{", ".join(CURRENT_SIGN_SOURCES)}')
        for unit, units, option in ((self.time_unit, TIME_UNITS, '--time-unit'),
                                    (self.current_unit, CURRENT_UNITS, '--current-unit'),
                                    (self.speed_unit, SPEED_UNITS, '--speed-unit'),
                                    (self.position_unit, POSITION_UNITS, '--position-unit')):
            if unit not in units:
                raise InputDataError(f'{option} {unit}: choose one of {", ".join(units)}')
        for value, option in ((self.speed_counts_per_rev, '--speed-counts-per-rev'),
                              (self.position_counts_per_rev, '--position-counts-per-rev'),
                              (self.gear_ratio, '--gear-ratio'),
                              (self.bus_voltage, '--voltage-from-duty'),
                              (self.duty_full_scale, '--duty-full-scale'),
                              (self.sample_period_s, '--sample-period')):
            if value is not None and not (np.isfinite(value) and value > 0):
                raise InputDataError(f'{option} must be a positive number, got {value}')

    def column(self, channel: str) -> str:
        """Name the file's column of a channel (the channel's own name by default)."""
        return self.columns.get(channel, channel)

    @property
    def mapped(self) -> bool:
        """Whether any column is mapped explicitly."""
        return bool(self.columns)

    def wanted(self) -> list[str]:
        """Channels to look for in the file, in :data:`CHANNELS` order."""
        skip = set() if self.bus_voltage is not None else {'duty', 'direction'}
        if 'segment' not in self.columns:
            skip.add('segment')
        return [channel for channel in CHANNELS if channel not in skip]

    def input_units(self) -> dict[str, dict[str, Any]]:
        """
        Return, per channel, the unit the file gave it in and the factor to SI (``input_units``).

        ``{'speed': {'given': 'rpm', 'si': 'rad/s', 'factor': 0.1047}, ...}`` for current, speed
        and position (the factor includes the gear ratio to the motor shaft), the voltage as
        given or made from a duty column, and the time ``t`` when it is not in seconds; a
        flipped sign says ``'negated': True``. The result and the report say from what the
        records were converted.
        """
        gear = self.gear_ratio
        speed_given = (f'encoder counts per sample ({self.speed_counts_per_rev:g} per rev)'
                       if self.speed_counts_per_rev is not None else self.speed_unit)
        position_given = (f'encoder counts ({self.position_counts_per_rev:g} per rev)'
                          if self.position_counts_per_rev is not None else self.position_unit)
        units: dict[str, dict[str, Any]] = {
            'voltage': {'given': 'V', 'si': 'V', 'factor': 1.0} if self.bus_voltage is None else
            {'given': f'duty (full scale {self.duty_full_scale:g}) on a {self.bus_voltage:g} V '
                      'bus', 'si': 'V', 'factor': self.bus_voltage / self.duty_full_scale},
            'current': {'given': self.current_unit, 'si': 'A',
                        'factor': CURRENT_UNITS[self.current_unit]},
            # counts per sample: the factor depends on the sample period (None here)
            'speed': {'given': speed_given, 'si': 'rad/s',
                      'factor': None if self.speed_counts_per_rev is not None else
                      SPEED_UNITS[self.speed_unit] * gear},
            'position': {'given': position_given,
                         'si': 'm' if self.position_unit == 'm' else 'rad',
                         'factor': self.position_factor},
        }
        if self.time_unit != 's':
            units['t'] = {'given': self.time_unit, 'si': 's',
                          'factor': TIME_UNITS[self.time_unit]}
        if gear != 1.0:
            for channel in ('speed', 'position'):
                units[channel]['given'] += f' at the output of a {gear:g}:1 gear'
        for channel in self.negated:
            units[channel]['negated'] = True
        if self.current_sign_from is not None:
            units['current']['sign_from'] = self.current_sign_from
        return units

    @property
    def position_factor(self) -> float:
        """Factor from the file's position unit to the motor shaft's rad (or m)."""
        if self.position_counts_per_rev is not None:
            factor = 2.0 * math.pi / self.position_counts_per_rev
        else:
            factor = POSITION_UNITS[self.position_unit]
        return factor * self.gear_ratio


#: The options that read an SI file as it is.
DEFAULT_OPTIONS = ReadOptions()


class ReadingNote(UserWarning):
    """A note on how a file was read (e.g. a matrix transposed): shown to the user."""


#: Relative difference beyond which ``--sample-period`` and the time column disagree (the
#: jitter of a logger's stamps is far below).
PERIOD_DISAGREEMENT = 0.05


def _compare_periods(time_s: Any, sample_period_s: float, source: str) -> None:
    """Say when ``--sample-period`` disagrees with the time column it replaces."""
    if time_s is None or len(time_s) < 3:
        return
    with np.errstate(all='ignore'):
        steps = np.diff(np.asarray(time_s[:100001], dtype=float))
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if not steps.size:
        return
    stamped = float(np.median(steps))
    if abs(stamped - sample_period_s) > PERIOD_DISAGREEMENT * stamped:
        note(f'{source}: --sample-period {sample_period_s:g} s disagrees with the time column, '
             f'whose samples are {stamped:.6g} s apart (a factor {sample_period_s / stamped:.3g}'
             '): the time column is not used, so La, J and the other time constants '
             'scale with --sample-period; drop it if the time column is right')


def note(text: str) -> None:
    """Tell the user how a file was read (:class:`ReadingNote`; the CLI prints it)."""
    warnings.warn(text, ReadingNote, stacklevel=2)


def parse_assignments(items: Optional[list[str]], option: str) -> dict[str, str]:
    """Parse repeated ``channel=name`` options (``--column``, ``--interface``) into a dict."""
    out: dict[str, str] = {}
    for item in items or []:
        channel, sep, name = item.partition('=')
        if not sep or not channel.strip() or not name.strip():
            raise InputDataError(f'{option} {item!r}: write CHANNEL=NAME, e.g. '
                                 f'{option} voltage=m0_voltage')
        out[channel.strip()] = name.strip()
    return out


def build_record(columns: Mapping[str, np.ndarray], options: ReadOptions = DEFAULT_OPTIONS,
                 source: str = '') -> Record:
    """
    Build a record in SI units at the motor shaft from raw columns by channel.

    The arrays may be modified in place (readers hand over arrays they own).

    Parameters
    ----------
    columns : dict
        Channel -> raw values as in the file (``t`` in s).
    options : ReadOptions
        Units, duty and gear of the file.
    source : str
        Path, for messages.

    Raises
    ------
    InputDataError
        A duty column absent or out of its range, a segment value that is not a number.

    """
    def scaled(name: str, factor: float) -> Optional[np.ndarray]:
        values = columns.get(name)
        if values is None:
            return None
        values = np.asarray(values, dtype=float)
        if factor != 1.0:
            values = values * factor  # a new array: the input columns stay as read
        return values

    time_s = _time_s(columns, options, source)

    def sign(channel: str) -> float:
        return -1.0 if channel in options.negated else 1.0

    voltage = scaled('voltage', sign('voltage'))
    if options.bus_voltage is not None:
        voltage = sign('voltage') * _voltage_from_duty(columns, options, source)
    current = scaled('current', CURRENT_UNITS[options.current_unit] * sign('current'))
    speed = columns.get('speed')
    if speed is not None:
        if options.speed_counts_per_rev is not None:
            period = float(np.median(np.diff(time_s[:10001]))) if len(time_s) > 1 else 1.0
            factor = 2.0 * math.pi / options.speed_counts_per_rev / period
        else:
            factor = SPEED_UNITS[options.speed_unit]
        speed = scaled('speed', factor * options.gear_ratio * sign('speed'))
    position = scaled('position', options.position_factor * sign('position'))
    current = _signed_current(current, {'voltage': voltage, 'speed': speed}, options, source)
    return Record(np.asarray(time_s, dtype=float), current, voltage, speed, position, source,
                  segment=_segment(columns.get('segment'), options, source))


def _time_s(columns: Mapping[str, np.ndarray], options: ReadOptions, source: str) -> Any:
    """Return the time [s]: the time column in its unit, or ``k * --sample-period``."""
    time_s = columns.get('t')
    others = [values for channel, values in columns.items() if channel != 't']
    if options.sample_period_s is not None and others:
        # the samples are this far apart: a time column (if any) is not used
        _compare_periods(time_s, options.sample_period_s, source)
        return np.arange(np.asarray(others[0]).shape[0]) * options.sample_period_s
    if time_s is None:
        raise InputDataError(f'{source}: no time column; map it with --column t=NAME, or give '
                             'the sample period with --sample-period S')
    if options.time_unit != 's':
        return np.asarray(time_s, dtype=float) * TIME_UNITS[options.time_unit]
    return time_s


def _signed_current(current: Optional[np.ndarray], signs: Mapping[str, Optional[np.ndarray]],
                    options: ReadOptions, source: str) -> Optional[np.ndarray]:
    """Give a current logged as a magnitude the sign of ``options.current_sign_from``."""
    channel = options.current_sign_from
    if channel is None or current is None:
        return current
    reference = signs[channel]
    if reference is None:
        raise InputDataError(f'{source}: --current-sign-from {channel}: the record has no '
                             f'{channel} column; map it with --column {channel}=NAME, or take '
                             f'the sign from the other channel')
    return np.abs(current) * np.sign(np.asarray(reference, dtype=float))


def _segment(values: Optional[np.ndarray], options: ReadOptions,
             source: str) -> Optional[np.ndarray]:
    """Return the segment column (values > 0 mark tests, 0 idle), refusing non-finite values."""
    if values is None:
        return None
    values = np.asarray(values, dtype=float)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise InputDataError(
            f'{source}: {column_option("segment", options.column("segment"))}: sample '
            f'{int(bad[0]) + 1} is {values[bad[0]]}, not a number; the segment column must '
            'hold numbers (> 0 in a test, 0 between tests)')
    return values


def _voltage_from_duty(columns: Mapping[str, np.ndarray], options: ReadOptions,
                       source: str) -> np.ndarray:
    """Return ``duty * bus_voltage``, signed by the direction column when there is one."""
    duty = columns.get('duty')
    if duty is None:
        raise InputDataError(f'{source}: --voltage-from-duty needs a duty column (named '
                             f'{options.column("duty")!r}); map it with --column duty=NAME')
    duty = np.asarray(duty, dtype=float) / options.duty_full_scale
    direction = columns.get('direction')
    finite = duty[np.isfinite(duty)]
    if direction is not None:
        if finite.size and (finite.min() < -1e-9 or finite.max() > 1 + 1e-9):
            raise InputDataError(f'{source}: duty with a direction column must lie in [0, 1]; '
                                 f'found {finite.min():.6g} .. {finite.max():.6g}'
                                 + _full_scale_hint(finite, options))
        duty = duty * np.where(np.asarray(direction, dtype=float) > 0, 1.0, -1.0)
    elif finite.size and np.max(np.abs(finite)) > 1 + 1e-9:
        raise InputDataError(
            f'{source}: the duty column must lie in [-1, 1] (or [0, 1] with a direction '
            f'column); found {finite.min():.6g} .. {finite.max():.6g}'
            + _full_scale_hint(finite, options))
    return duty * float(options.bus_voltage or 0.0)


#: Full scales of duty columns as logged: percent, 8-, 10-, 12- and 16-bit PWM registers.
DUTY_FULL_SCALES = (100.0, 255.0, 1023.0, 4095.0, 65535.0)


def _full_scale_hint(duty: np.ndarray, options: ReadOptions) -> str:
    """Say which ``--duty-full-scale`` the column's largest value suggests."""
    peak = float(np.max(np.abs(duty))) * options.duty_full_scale
    likely = [scale for scale in DUTY_FULL_SCALES if peak <= scale + 1e-9]
    if options.duty_full_scale != 1.0 or not likely:
        return (". Give the duty column's value at full duty with --duty-full-scale N "
                f'(now {options.duty_full_scale:g})')
    return (f'. If {likely[0]:g} is full duty (percent: 100; an 8-bit PWM value: 255), give '
            f'--duty-full-scale {likely[0]:g}')


def output_shaft(parameters: Mapping[str, float], gear_ratio: float) -> dict[str, float]:
    """
    Return the parameters seen at the output shaft of a gearbox of ratio ``gear_ratio``.

    Torques scale with the ratio and inertias and viscous coefficients with its square
    (a lossless gearbox): ``CPhi N``, ``J N^2``, ``b N^2``, ``Mc N``; Ra, La, Ka, Ta stay.
    """
    scale = {'CPhi': gear_ratio, 'J': gear_ratio ** 2, 'b': gear_ratio ** 2, 'Mc': gear_ratio}
    return {name: float(value) * scale.get(name, 1.0) for name, value in parameters.items()
            if value is not None}
