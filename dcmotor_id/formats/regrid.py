"""
Placing the messages of real publishers on the identification grid (no ROS here).

A robot's drive does not publish one message per sample on a perfect grid: header stamps are
taken with ``now()`` when the message is published, a timer-driven loop catches up in bursts
(50 ms of samples published at once, all stamped within microseconds), stamps jitter, the
voltage comes at 1 kHz from a publisher of its own (stamped by DDS on publication) while the
joint states come at 500 Hz. Rounding each stamp to the grid (what
:meth:`~dcmotor_id.formats.streams.SampleInbox.index_of_stamp` does) then puts a whole burst on
one or two grid instants: most values are dropped as duplicates, the rest lost.

:class:`StampRegridder` counts instead of rounding. Each *source* (a topic: ``joint_states``
carrying current and speed, ``voltage``, ...) numbers its messages: by the DDS publication
sequence number when there is one (a gap is a lost message, counted), else by arrival. The
stamps are used only to find, once per source, *where* its numbering lies on the grid:

* the source's rate: the slope of the lower envelope of stamp against number over the first
  ``settle_s`` seconds (publication delays, bursts and stalls lie above it), taken as a whole
  ratio of the grid rate (1, 2, ... 10 times faster or slower) when it is within 3 % of one
  (else the measured rate);
* its offset: the median stamp residual, or, when the stamps come in bursts (over 10 % of the
  steps shorter than half a period), from the last messages of the bursts (the newest
  sample due, published within a period of its instant); two sources both stamped in bursts
  are paired by their bursts' last messages (one loop publishes both);
* a source whose instants lie within a quarter grid period (:data:`SNAP`) of the grid's (or of
  every other grid instant's, for a faster source) is placed exactly on them: the common case
  of one control loop publishing every topic; other sources are *resampled* onto the grid
  instants: linearly, or as a zero-order hold for the channels in ``hold_channels`` (a held
  command: the voltage).

A repeated value is a sample; a duplicate is the same sequence number, or without sequence
numbers the same stamp, twice. What was placed, resampled, held, lost and dropped is counted
per source in :attr:`StampRegridder.stats` (:class:`SourceStats`).

Messages are taken as they come (:meth:`StampRegridder.put`) and the grid values handed to a
:class:`~dcmotor_id.formats.streams.SampleInbox` by :meth:`StampRegridder.drain_into`; the
aligner behind it pairs the channels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Mapping, Optional, Protocol, Sequence

import numpy as np

__all__ = ['BURST_FRACTION', 'SNAP', 'SourceStats', 'StampRegridder']

#: A source is placed exactly on the grid when its instants are within this many grid periods
#: of grid instants (or of every other one, and so on, for a faster source).
SNAP = 0.25
#: Stamps come in bursts when more than this fraction of their steps is under half a period.
BURST_FRACTION = 0.1
#: Whole ratios of a source's rate to the grid's that are taken as exact (within 3 %).
RATIOS = tuple(float(k) for k in range(1, 11)) + tuple(1.0 / k for k in range(2, 11))
RATIO_TOLERANCE = 0.03
#: Positions closer than this to a grid instant are on it [grid periods].
EPS = 1e-6
#: A source placed this far [s] from where the others are now is on another clock.
MAX_CLOCK_GAP_S = 2.0


class BlockSink(Protocol):
    """Where grid values go: a :class:`~dcmotor_id.formats.streams.SampleInbox`."""

    def put_block(self, channel: str, indices: np.ndarray, values: np.ndarray) -> None:
        """Put values of ``channel`` for the grid ``indices``."""


@dataclass
class SourceStats:
    """
    Counters of one source, for the answer of ``~/identify`` and ``/diagnostics``.

    Attributes
    ----------
    received : int
        Messages taken (duplicates included).
    duplicates : int
        Messages dropped because their sequence number (or, without one, their stamp) repeated
        an earlier one.
    lost : int
        Messages missing from the sequence numbers (never received).
    late : int
        Messages older than what was already placed (dropped).
    restarts : int
        Times the numbering started again (a restarted publisher): the source is placed anew.
    on_grid : int
        Grid values taken exactly from a message (placed).
    resampled : int
        Grid values interpolated, or held, between two messages.
    between_grid : int
        Messages of a faster source between grid instants (their value is not a grid value;
        with a zero-order hold the value at the grid instant before them is).
    ratio : float
        The source's rate over the grid's (0 until placed).
    shift : float
        Where the source's first message lies on the grid [grid periods] (nan until placed).
    snapped : bool
        Whether the source was placed exactly on grid instants.
    bursty : bool
        Whether its stamps came in bursts.
    stamp_spread : float
        Spread (95th minus 5th percentile) of the stamps about their fitted line when placed
        [grid periods]: the jitter, or the length of a burst.
    other_clock : int
        Messages dropped because their stamps were :data:`MAX_CLOCK_GAP_S` or more from the
        other sources' (another clock); ``clock_gap_s`` says how far [s].

    """

    received: int = 0
    duplicates: int = 0
    lost: int = 0
    late: int = 0
    restarts: int = 0
    on_grid: int = 0
    resampled: int = 0
    between_grid: int = 0
    ratio: float = 0.0
    shift: float = float('nan')
    snapped: bool = False
    bursty: bool = False
    stamp_spread: float = float('nan')
    other_clock: int = 0
    clock_gap_s: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        """Return the counters as a plain dict."""
        return dict(self.__dict__)


@dataclass
class _Source:
    """One source's state: its messages waiting to be placed, its placement, its tail."""

    channels: tuple[str, ...]
    stats: SourceStats = field(default_factory=SourceStats)
    numbers: list = field(default_factory=list)    # int message numbers
    stamps: list = field(default_factory=list)     # int stamps [ns] (relative to the base)
    values: list = field(default_factory=list)     # rows, one value per channel
    last_number: Optional[int] = None
    last_stamp: Optional[int] = None
    placed: bool = False
    number0: int = 0           # the number at position ``shift``
    tail: Optional[tuple[float, int, np.ndarray]] = None  # last (position, number, values)
    next_grid: Optional[int] = None    # lowest grid index not emitted yet


class StampRegridder:
    """
    Number each source's messages, place the numbering on the grid, emit grid values.

    Parameters
    ----------
    sample_period_s : float
        The identification grid's period [s].
    hold_channels : sequence of str
        Channels resampled as a zero-order hold (a held command); the others linearly.
    settle_s : float
        Stamps of a source collected before it is placed [s] (its messages are held, not
        lost, meanwhile).

    """

    def __init__(self, sample_period_s: float, hold_channels: Sequence[str] = ('voltage',),
                 settle_s: float = 1.0) -> None:
        if not sample_period_s > 0:
            raise ValueError('sample_period_s must be positive')
        self.period_ns = float(sample_period_s) * 1e9
        self.hold_channels = frozenset(hold_channels)
        self.settle_ns = float(settle_s) * 1e9
        self._sources: dict[str, _Source] = {}
        #: Channel name -> values refused because they were not finite (their grid values
        #: are never handed on: the aligner counts those samples as lost).
        self.invalid_by_channel: dict[str, int] = {}
        self._base_ns: Optional[int] = None    # stamps are kept relative to this
        self._origin: Optional[float] = None   # grid index 0 [ns, relative to the base]
        self._origin_bursty = False
        #: (stamps, positions) of the first bursty source placed
        self._anchor: Optional[tuple[np.ndarray, np.ndarray]] = None

    @property
    def stats(self) -> dict[str, SourceStats]:
        """Source name -> its counters."""
        return {name: source.stats for name, source in self._sources.items()}

    def add_source(self, name: str, channels: Sequence[str]) -> None:
        """Declare a source (a topic) and the channels each of its messages carries."""
        self._sources[name] = _Source(tuple(channels))
        for channel in channels:
            self.invalid_by_channel.setdefault(channel, 0)

    def put(self, name: str, stamp_ns: int, number: Optional[int],
            values: Sequence[float]) -> None:
        """
        Take one message of source ``name``: its stamp [ns], sequence number, values.

        ``number`` is the DDS publication sequence number (None or 0 when unknown: the
        messages are then numbered as they arrive); ``values`` has one value per channel of
        the source, in the order given to :meth:`add_source`.
        """
        source = self._sources[name]
        stats = source.stats
        stats.received += 1
        for channel, value in zip(source.channels, values):
            if not math.isfinite(value):
                self.invalid_by_channel[channel] += 1
        if self._base_ns is None:
            self._base_ns = int(stamp_ns)
        stamp = int(stamp_ns) - self._base_ns
        if number:
            number = int(number)
            if source.last_number is not None and number <= source.last_number:
                if source.last_stamp is None or stamp <= source.last_stamp:
                    stats.duplicates += 1   # the same sequence number again
                    return
                self._restart(source)     # numbered again, later: a restarted publisher
        elif source.last_stamp is not None and stamp == source.last_stamp:
            stats.duplicates += 1
            return
        else:
            number = 1 if source.last_number is None else source.last_number + 1
        if source.last_number is not None and number > source.last_number + 1:
            stats.lost += number - source.last_number - 1
        source.last_number, source.last_stamp = number, stamp
        source.numbers.append(number)
        source.stamps.append(stamp)
        source.values.append(values)

    def _restart(self, source: _Source) -> None:
        """Forget a source's placement; its messages not yet drained are counted as late."""
        source.stats.restarts += 1
        source.stats.late += len(source.numbers)
        source.placed = False
        source.tail = None
        source.last_number = source.last_stamp = None
        source.numbers, source.stamps, source.values = [], [], []

    def drain_into(self, sink: BlockSink, force: bool = False) -> None:
        """
        Place what was put so far and put the grid values into ``sink``.

        ``force``: place the sources with less than ``settle_s`` of stamps too (a stream that
        stopped; at least 8 messages are needed).
        """
        # the sources at the grid rate or slower first: one of them sets the grid's origin
        ordered = sorted(self._sources.values(), key=lambda source: not self._slow(source))
        for source in ordered:
            if not source.numbers:
                continue
            if not source.placed:
                if len(source.numbers) < 8 or (
                        not force and source.stamps[-1] - source.stamps[0] < self.settle_ns):
                    continue
                if self._origin is None and not force and not self._slow(source) and \
                        source.stamps[-1] - source.stamps[0] < 5 * self.settle_ns and any(
                            self._slow(other) and other.stats.received
                            for other in self._sources.values()):
                    continue  # a faster source waits (a while) for the grid-rate one
                if not self._place(source):
                    continue
            self._emit(source, sink)

    def _slow(self, source: _Source) -> bool:
        """Whether a source publishes at most about at the grid rate (by its stamps)."""
        if source.placed or len(source.stamps) < 2:
            return source.stats.ratio <= 1.0 + RATIO_TOLERANCE
        return self._ratio(np.asarray(source.numbers, dtype=float),
                           np.asarray(source.stamps, dtype=float))[0] <= 1.0 + RATIO_TOLERANCE

    def _ratio(self, numbers: np.ndarray, stamps: np.ndarray) -> tuple[float, bool]:
        """
        Return the source's rate over the grid's, and whether it is a whole ratio.

        The slope of the stamps' lower envelope against the number (:func:`envelope_slope`:
        publication delays, bursts and stalls lie above it), taken as the nearest of
        :data:`RATIOS` when within :data:`RATIO_TOLERANCE` of it.
        """
        relative = numbers - numbers[0]
        slope = envelope_slope(relative, stamps) if np.ptp(relative) > 0 else self.period_ns
        ratio = self.period_ns / slope if slope > 0 else 1.0
        nearest = min(RATIOS, key=lambda candidate: abs(candidate / ratio - 1.0))
        exact = abs(nearest / ratio - 1.0) < RATIO_TOLERANCE
        return (nearest if exact else ratio), exact

    def grid_stamp_ns(self, index: int) -> int:
        """Return the time of grid ``index`` [ns] in the stamps' clock."""
        base = self._base_ns or 0
        return base + int(round((self._origin or 0.0) + index * self.period_ns))

    def _place(self, source: _Source) -> bool:
        """
        Find the source's rate, offset and shift from its stamps so far; return whether placed.

        A source whose newest message would land more than :data:`MAX_CLOCK_GAP_S` from where
        the sources placed before it are now is on another clock (a voltage stamped by DDS
        beside replayed joint states, say): its messages are dropped, counted in
        ``other_clock``, and it is tried again with the next ones.
        """
        numbers = np.asarray(source.numbers, dtype=float)
        stamps = np.asarray(source.stamps, dtype=float)
        relative = numbers - numbers[0]
        ratio, exact = self._ratio(numbers, stamps)
        period = self.period_ns / ratio
        residual = stamps - relative * period
        bursty = bool(np.mean(np.diff(stamps) < 0.5 * period) > BURST_FRACTION)
        offset = _burst_offset(stamps, residual, period, self.period_ns) if bursty else \
            float(np.median(residual))
        if self._origin is None:
            self._origin, self._origin_bursty = offset, bursty
        shift = (offset - self._origin) / self.period_ns
        step = 1.0 / ratio if exact and ratio > 1 else 1.0
        if bursty and self._anchor is not None:
            # publication times of one loop: its messages published together belong together
            matched = self._matched_shift(stamps, relative / ratio)
            shift = matched if math.isfinite(matched) else shift
        nearest_shift = round(shift / step) * step
        # publication times place a source within half a period only: the nearest instant
        tolerance = 0.5 if bursty or self._origin_bursty else SNAP
        snapped = exact and abs(shift - nearest_shift) <= tolerance + EPS
        stats = source.stats
        shift = nearest_shift if snapped else shift
        if self._other_clock(source, shift + relative[-1] / ratio, numbers.size):
            return False
        stats.ratio, stats.bursty, stats.snapped = ratio, bursty, snapped
        stats.shift = shift
        spread = np.percentile(residual, [5, 95]) if residual.size else [0.0, 0.0]
        stats.stamp_spread = float(spread[1] - spread[0]) / self.period_ns
        source.number0 = int(numbers[0])
        source.placed = True
        if bursty and self._anchor is None:
            self._anchor = (stamps, stats.shift + relative / ratio)
        return True

    def _other_clock(self, source: _Source, newest: float, count: int) -> bool:
        """Drop and count a source's messages when ``newest`` is far from the others' now."""
        tails = [other.tail[0] for other in self._sources.values()
                 if other is not source and other.placed and other.tail is not None]
        if not tails:
            return False
        gap_s = (newest - max(tails)) * self.period_ns * 1e-9
        if abs(gap_s) <= MAX_CLOCK_GAP_S:
            return False
        source.stats.other_clock += count
        source.stats.clock_gap_s = gap_s
        source.numbers, source.stamps, source.values = [], [], []
        return True

    def _matched_shift(self, stamps: np.ndarray, positions: np.ndarray) -> float:
        """
        Return a bursty source's shift from the bursts it shares with the anchor.

        Two sources stamped by publication, in bursts of one loop: the last message of a burst
        is, on each topic, the newest sample due when the loop woke, the same sample (to
        within the faster source's period). The median of the shifts implied by the bursts'
        last messages, each paired with the anchor's burst that ended nearest in time, is
        returned (nan without shared bursts). ``positions`` are the source's positions
        without shift [grid periods].
        """
        assert self._anchor is not None
        anchor_stamps, anchor_positions = self._anchor
        anchor_ends, ends = _burst_ends(anchor_stamps), _burst_ends(stamps)
        if anchor_ends.size < 2 or ends.size < 2:
            return float('nan')
        end_stamps = anchor_stamps[anchor_ends]
        after = np.clip(np.searchsorted(end_stamps, stamps[ends]), 1, end_stamps.size - 1)
        before = after - 1
        nearest = np.where(stamps[ends] - end_stamps[before] <= end_stamps[after] -
                           stamps[ends], before, after)
        return float(np.median(anchor_positions[anchor_ends[nearest]] - positions[ends]))

    def _emit(self, source: _Source, sink: BlockSink) -> None:
        """Turn the source's placed messages into grid values; keep the last as the tail."""
        stats = source.stats
        numbers = np.asarray(source.numbers, dtype=np.int64)
        values = np.asarray(source.values, dtype=float).reshape(numbers.size, -1)
        source.numbers, source.stamps, source.values = [], [], []
        positions = stats.shift + (numbers - source.number0) / stats.ratio
        had_tail = source.tail is not None
        if source.tail is not None:
            tail_position, tail_number, tail_values = source.tail
            positions = np.concatenate([[tail_position], positions])
            numbers = np.concatenate([[tail_number], numbers])
            values = np.vstack([tail_values, values])
        source.tail = (float(positions[-1]), int(numbers[-1]), values[-1])
        first = int(np.ceil(positions[0] - EPS))
        if source.next_grid is not None:
            first = max(first, source.next_grid)
        last = int(np.floor(positions[-1] + EPS))
        on = np.abs(positions - np.rint(positions)) < EPS
        stats.between_grid += int(np.count_nonzero(~on[1:] if had_tail else ~on))
        if last < first:
            return
        source.next_grid = last + 1
        grid = np.arange(first, last + 1)
        at = np.searchsorted(positions, grid + EPS, side='right') - 1
        exact = np.abs(positions[at] - grid) < EPS
        following = np.minimum(at + 1, positions.size - 1)
        joined = (numbers[following] - numbers[at] == 1) & (following > at)
        keep = exact | joined
        grid, at, following, exact = grid[keep], at[keep], following[keep], exact[keep]
        stats.on_grid += int(np.count_nonzero(exact))
        stats.resampled += int(np.count_nonzero(~exact))
        span = positions[following] - positions[at]
        weight = np.where(exact | (span <= 0), 0.0, (grid - positions[at]) /
                          np.where(span > 0, span, 1.0))
        for column, channel in enumerate(source.channels):
            low = values[at, column]
            if channel not in self.hold_channels:
                with np.errstate(invalid='ignore'):
                    low = np.where(weight > 0, low + weight * (values[following, column] - low),
                                   low)
            finite = np.isfinite(low)  # counted when put
            sink.put_block(channel, grid[finite], low[finite])

    def summary(self) -> list[str]:
        """Say per source what was placed, resampled, lost and dropped (empty before any)."""
        phrases = []
        for name, source in self._sources.items():
            stats = source.stats
            if not stats.received:
                continue
            if not source.placed and stats.other_clock:
                phrases.append(f'{name}: {stats.other_clock} messages not paired: their stamps '
                               f'are {stats.clock_gap_s:+.3g} s from those of the other topics '
                               '(another clock? a voltage stamped on arrival beside replayed '
                               'joint states: replay both, or record the voltage with a '
                               'header)')
                continue
            if not source.placed and stats.ratio == 0:
                phrases.append(f'{name}: {stats.received} messages, not placed yet (needs '
                               f'{self.settle_ns * 1e-9:g} s of stamps)')
                continue
            how = 'on the grid' if stats.snapped else 'resampled'
            kind = 'bursts' if stats.bursty else 'stamps'
            parts = [f'{name}: {stats.received} messages at {stats.ratio:.4g} x the grid rate, '
                     f'{how} ({kind} spread {stats.stamp_spread:.2g} periods); '
                     f'{stats.on_grid} grid values placed, {stats.resampled} resampled']
            for count, what in ((stats.between_grid, 'between grid instants (faster source)'),
                                (stats.lost, 'lost (sequence gaps)'),
                                (stats.duplicates, 'duplicates dropped (same sequence number '
                                 'or stamp)'),
                                (stats.late, 'late'),
                                (stats.restarts, 'restarts')):
                if count:
                    parts.append(f'{count} {what}')
            phrases.append(', '.join(parts))
        return phrases

    def key_values(self) -> list[tuple[str, str]]:
        """Return ``regrid.<source>.<counter>`` key-values for ``/diagnostics``."""
        pairs = []
        for name, stats in self.stats.items():
            for key, value in stats.as_dict().items():
                text = f'{value:.6g}' if isinstance(value, float) else str(value)
                pairs.append((f'regrid.{name}.{key}', text))
        return pairs


def envelope_slope(x: np.ndarray, y: np.ndarray) -> float:
    """
    Return the slope of the line below every point ``(x, y)`` closest to them on average.

    The edge of the lower convex hull above the mean ``x`` (``x`` increasing): stamps that
    are late by any delay (a burst, a stalled publisher) leave it alone, as long as some
    messages went out on time. Falls back to the least-squares slope with fewer than three
    distinct points.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if np.unique(x).size < 3:
        return float(np.polyfit(x, y, 1)[0])
    hull: list[int] = []
    for index in range(x.size):  # Andrew's monotone chain, the lower half
        while len(hull) >= 2:
            first, middle = hull[-2], hull[-1]
            cross = (x[middle] - x[first]) * (y[index] - y[first]) - \
                (y[middle] - y[first]) * (x[index] - x[first])
            if cross > 0:
                break
            hull.pop()
        hull.append(index)
    points = np.asarray(hull)
    edge = int(np.clip(np.searchsorted(x[points], x.mean()), 1, points.size - 1))
    low, high = points[edge - 1], points[edge]
    return float((y[high] - y[low]) / (x[high] - x[low]))


def _burst_ends(stamps: np.ndarray) -> np.ndarray:
    """Return the indices of the last messages of the bursts (followed by a long step)."""
    steps = np.diff(stamps)
    if steps.size == 0:
        return np.empty(0, dtype=np.int64)
    return np.flatnonzero(steps > 10.0 * max(float(np.median(steps)), 1.0))


def _burst_offset(stamps: np.ndarray, residual: np.ndarray, period: float,
                  grid_period: float) -> float:
    """
    Return the offset of a source whose stamps are publication times of bursts [ns].

    The last message of a burst is the newest sample due when the loop woke, at most a
    period old then; the burst's first message is published on waking (the others wait for
    the messages before them). The stamp of the first message less the last one's place on
    the line, ``r``, bounds the offset to ``(max r - T, min r]``; the middle of that interval
    is returned (the newest sample's instant when the loop wakes at every phase, half a
    period before the wake-up when it always wakes at the same phase). ``T`` is the longer
    of the source's and the grid's period, so that a source faster than the grid, published
    by the same loop as one at the grid rate, lands on one of that one's instants, not
    between two.
    """
    last = np.flatnonzero(np.diff(stamps) >= 0.5 * period)
    if last.size >= 2:
        first = last[:-1] + 1   # the burst after each end, from its first to its last message
        ends = residual[last[1:]] - (stamps[last[1:]] - stamps[first])
    else:
        ends = residual
    span = max(period, grid_period)
    # a stalled burst or two (published late) do not widen the interval
    top = min(float(np.percentile(ends, 90)), float(ends.min()) + span)
    return (float(ends.min()) + top - span) / 2.0


def regrid_columns(period_s: float, messages: Mapping[str, tuple[Any, Any, Any]],
                   channels: Mapping[str, Sequence[str]],
                   hold_channels: Sequence[str] = ('voltage',),
                   settle_s: float = 1.0) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]],
                                                   StampRegridder]:
    """
    Regrid whole recordings at once: ``{source: (stamps_ns, numbers, rows)}``.

    Returns ``{channel: (grid indices, values)}`` and the regridder (its counters).
    """
    regridder = StampRegridder(period_s, hold_channels, settle_s)
    for name, names in channels.items():
        regridder.add_source(name, names)
    for name, (stamps, numbers, rows) in messages.items():
        numbers = [None] * len(stamps) if numbers is None else numbers
        for stamp, number, row in zip(stamps, numbers, rows):
            regridder.put(name, int(stamp), number, row)
    sink = _Collect()
    regridder.drain_into(sink)
    return {channel: (np.concatenate(parts[0]), np.concatenate(parts[1]))
            for channel, parts in sink.blocks.items()}, regridder


class _Collect:
    """A sink that keeps every block (for :func:`regrid_columns`)."""

    def __init__(self) -> None:
        self.blocks: dict[str, tuple[list, list]] = {}

    def put_block(self, channel: str, indices: np.ndarray, values: np.ndarray) -> None:
        indices_list, values_list = self.blocks.setdefault(channel, ([], []))
        indices_list.append(np.asarray(indices))
        values_list.append(np.asarray(values))
