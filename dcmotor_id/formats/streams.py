"""
Aligning sample streams that arrive separately onto one uniform grid (no ROS here).

A drive publishes voltage, current and speed as separate streams. Each value belongs to one
sample instant ``t_k = origin + k dt``; this module puts the values of the same ``k`` together,
whatever order they arrive in, and says which samples were lost.

* :class:`StreamAligner` is the online form: values go in with their sample index ``k`` (one
  by one or in blocks), complete samples come out in order once every channel has delivered
  them. A sample still incomplete once every channel has delivered an index
  ``max_delay_samples`` beyond it is given up as lost; a value that arrives after its sample
  was emitted or given up is counted as late and dropped. Memory is a fixed ring of
  ``capacity`` samples: a channel running further ahead pushes the oldest samples out, and a
  channel that stops is handled by :meth:`StreamAligner.flush`.
* :class:`SampleInbox` is where message callbacks put values: it finds each value's sample
  index (from the DDS publication sequence number or by timestamp) and hands everything that
  arrived to an aligner in one go.
* :func:`grid_indices` turns timestamps into sample indices, and :func:`align_timestamps` is
  the offline form used by the bag reader: every channel's ``(stamp_ns, value)`` pairs onto one
  grid.
* :func:`contiguous_runs` splits emitted indices where samples are missing.
"""

from __future__ import annotations

from dataclasses import dataclass
import threading
import time
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from dcmotor_id.core.errors import InputDataError

#: Largest tolerated distance of a timestamp from its grid instant, in sample periods.
MAX_GRID_RESIDUAL = 0.25
#: Largest sample index taken (2^53: exact as a float, and far from int64 overflow).
MAX_INDEX = 2 ** 53


@dataclass
class AlignerStats:
    """
    Counters of an aligner, for diagnostics.

    Attributes
    ----------
    received : int
        Values accepted (all channels).
    emitted : int
        Complete samples handed out.
    lost : int
        Samples given up because a channel never delivered them in time.
    late : int
        Values that arrived after their sample had been emitted or given up.
    duplicates : int
        Values for a (channel, index) already filled.
    reordered : int
        Values whose index was below the newest index already seen on their channel.
    invalid : int
        Values refused because they were not finite.
    restarts : int
        Times the indices jumped back by more than the ring (a restarted source).
    unmatched_at_start : int
        Incomplete samples before the first complete one (a channel not connected yet):
        not counted as lost.

    """

    received: int = 0
    emitted: int = 0
    lost: int = 0
    late: int = 0
    duplicates: int = 0
    reordered: int = 0
    invalid: int = 0
    restarts: int = 0
    unmatched_at_start: int = 0

    def as_dict(self) -> dict[str, int]:
        """Return the counters as a plain dict."""
        return dict(self.__dict__)


class StreamAligner:
    """
    Collect per-channel values by sample index and emit complete samples in order.

    Parameters
    ----------
    channels : sequence of str
        Channel names, e.g. ``('voltage', 'current', 'speed')``.
    max_delay_samples : int
        An incomplete sample is counted as lost once every channel has delivered an index
        this far beyond it.
    capacity : int, optional
        Ring size in samples (default ``4 * max_delay_samples``, at least 1024). A value whose
        index is more than ``capacity`` ahead of the oldest pending sample pushes the oldest
        ones out (emitted if complete, lost otherwise); :meth:`add_blocks` feeds large blocks
        of all channels in pieces that fit, so that nothing is pushed out.
    restart_samples : int, optional
        A jump of the indices forward by more than this (default ``1000 * capacity``) is a
        new origin (a restarted source, a new clock), counted in ``restarts``, not as that
        many lost samples.

    Attributes
    ----------
    invalid_by_channel : dict
        Channel name -> values refused because they were not finite.

    """

    def __init__(self, channels: Sequence[str], max_delay_samples: int = 200,
                 capacity: Optional[int] = None,
                 restart_samples: Optional[int] = None) -> None:
        self.channels = tuple(channels)
        if not self.channels:
            raise ValueError('at least one channel is needed')
        if max_delay_samples < 1:
            raise ValueError('max_delay_samples must be at least 1')
        self.max_delay_samples = int(max_delay_samples)
        self.capacity = int(capacity or max(4 * self.max_delay_samples, 1024))
        if self.capacity <= self.max_delay_samples:
            raise ValueError('capacity must exceed max_delay_samples')
        self.restart_samples = int(restart_samples or 1000 * self.capacity)
        self.invalid_by_channel = dict.fromkeys(self.channels, 0)
        self._column = {name: column for column, name in enumerate(self.channels)}
        self._values = np.full((self.capacity, len(self.channels)), np.nan)
        self._have = np.zeros((self.capacity, len(self.channels)), dtype=bool)
        self._base: Any = None     # lowest index not yet emitted or given up
        self._newest: Any = None   # highest index seen on any channel
        self._newest_by_channel: dict[str, Any] = dict.fromkeys(self.channels)
        self.stats = AlignerStats()
        self.first_index: Optional[int] = None    # lowest index ever seen
        self._out_indices: list[np.ndarray] = []
        self._out_values: list[np.ndarray] = []

    @property
    def next_index(self) -> Optional[int]:
        """Lowest sample index not yet emitted or given up (None before any value)."""
        return self._base

    def add(self, channel: str, index: int, value: float) -> None:
        """Add one value of ``channel`` for sample ``index``."""
        self.add_block(channel, np.array([index], dtype=np.int64), np.array([value], float))

    def add_block(self, channel: str, indices: Any, values: Any) -> None:
        """
        Add values of one channel for the given sample indices (any order).

        Non-finite values are refused (counted as ``invalid``); their samples stay incomplete
        and are eventually counted as lost.
        """
        column = self._column.get(channel)
        if column is None:
            raise KeyError(f'unknown channel {channel!r}; expected one of {self.channels}')
        indices = np.asarray(indices, dtype=np.int64).ravel()
        values = np.asarray(values, dtype=float).ravel()
        if indices.shape != values.shape:
            raise ValueError('indices and values must have the same length')
        if indices.size == 0:
            return
        finite = np.isfinite(values)
        invalid = int(np.count_nonzero(~finite))
        self.stats.invalid += invalid
        self.invalid_by_channel[channel] += invalid
        indices, values = indices[finite], values[finite]
        if indices.size == 0:
            return
        self._count_reordered(channel, indices)
        self._follow_numbering(indices)
        late = indices < self._base
        self.stats.late += int(np.count_nonzero(late))
        indices, values = indices[~late], values[~late]
        if indices.size == 0:
            return
        self._store(column, indices, values)
        slowest = list(self._newest_by_channel.values())
        if None not in slowest:
            # every channel has moved on by max_delay_samples: what is missing will not come
            self._collect(min(slowest) - self.max_delay_samples)

    def _count_reordered(self, channel: str, indices: np.ndarray) -> None:
        """Count the indices of ``channel`` that run backwards; note its newest index."""
        newest_here = self._newest_by_channel[channel]
        running = np.maximum.accumulate(indices)
        backwards = np.count_nonzero(indices[1:] < running[:-1])
        if newest_here is not None:
            backwards += int(indices[0] < newest_here)
            self._newest_by_channel[channel] = max(newest_here, int(running[-1]))
        else:
            self._newest_by_channel[channel] = int(running[-1])
        self.stats.reordered += int(backwards)

    def _follow_numbering(self, indices: np.ndarray) -> None:
        """Place the ring for new indices: the first ones, a restart, an earlier start."""
        if self._base is None:
            self._base = int(indices.min())
            self._newest = int(indices.max())
        self.first_index = int(indices.min()) if self.first_index is None else \
            min(self.first_index, int(indices.min()))
        top, low = int(indices.max()), int(indices.min())
        if (top < self._base and low < self._base - self.capacity) or \
                low > self._newest + self.restart_samples:
            # all behind what went out and reaching far back, or absurdly far ahead: the
            # source restarted its numbering (a new origin, a publisher restarted with its
            # clock); the samples in between were never taken, not lost
            self.flush()
            self.stats.restarts += 1
            self._base = int(indices.min())
            self._newest = int(indices.max())
            self._newest_by_channel = dict.fromkeys(self.channels)
        low = int(indices.min())
        if low < self._base and self.stats.emitted == 0 and \
                self._newest - low < self.capacity:
            # nothing went out yet: the first values seen need not be the earliest
            self._base = low

    def _store(self, column: int, indices: np.ndarray, values: np.ndarray) -> None:
        """Write values not late into the ring (advancing it), counting duplicates."""
        top = int(indices.max())
        if top >= self._base + self.capacity:
            self._advance(top - self.capacity + 1)
            keep = indices >= self._base
            self.stats.late += int(np.count_nonzero(~keep))
            indices, values = indices[keep], values[keep]
        self._newest = max(self._newest, top)
        slots = indices % self.capacity
        duplicate = self._have[slots, column]
        # a repeated index inside the block is a duplicate too
        unique_slots, first = unique_sorted(slots, return_index=True)
        self.stats.duplicates += int(np.count_nonzero(duplicate)) + slots.size - first.size
        take = np.zeros(slots.size, dtype=bool)
        take[first] = True
        take &= ~duplicate
        self._values[slots[take], column] = values[take]
        self._have[slots[take], column] = True
        self.stats.received += int(np.count_nonzero(take))

    def add_blocks(self, blocks: Mapping[str, tuple[Any, Any]]) -> None:
        """
        Add values of several channels at once: ``{channel: (indices, values)}``.

        Blocks that span more than the ring (a batch of many samples, a backlog) are fed in
        pieces of at most ``capacity - max_delay_samples`` consecutive indices, every channel
        piece by piece, so the samples of one piece are complete and emitted before the next
        piece comes: nothing is pushed out of the ring and lost. The pieces follow the
        indices present (a sparse block costs one piece per ``capacity - max_delay_samples``
        values, never one per index of its span).
        """
        arrays = {}
        for channel, (indices, values) in blocks.items():
            indices = np.asarray(indices, dtype=np.int64).ravel()
            values = np.asarray(values, dtype=float).ravel()
            if indices.shape != values.shape:
                raise ValueError('indices and values must have the same length')
            if indices.size:
                arrays[channel] = (indices, values)
        if not arrays:
            return
        piece = self.capacity - self.max_delay_samples
        low = min(int(indices.min()) for indices, _ in arrays.values())
        high = max(int(indices.max()) for indices, _ in arrays.values())
        if high - low < piece:  # the common case: one message, one small batch
            for channel, (indices, values) in arrays.items():
                self.add_block(channel, indices, values)
            return
        orders = {}
        for channel, (indices, _) in arrays.items():
            order = np.argsort(indices, kind='stable')
            orders[channel] = (order, indices[order])
        cursors = dict.fromkeys(arrays, 0)
        start: Optional[int] = low
        while start is not None:
            stop = start + piece  # exclusive
            following = []
            for channel, (indices, values) in arrays.items():
                order, sorted_indices = orders[channel]
                first = cursors[channel]
                last = cursors[channel] = int(np.searchsorted(sorted_indices, stop))
                if last > first:
                    # the channel's values of this piece, in the order they came
                    chosen = np.sort(order[first:last])
                    self.add_block(channel, indices[chosen], values[chosen])
                if last < sorted_indices.size:
                    following.append(int(sorted_indices[last]))
            start = min(following) if following else None

    def _advance(self, new_base):
        """Force the base up to ``new_base``: emit what is complete, lose the rest."""
        self._collect(new_base - 1, force=True)
        if new_base > self._base:  # indices never stored (beyond the ring) are lost too
            self.stats.lost += new_base - self._base
            self._base = int(new_base)

    def _collect(self, expired_through, force=False):
        """Move complete samples to the output; give up incomplete ones up to the horizon."""
        if self._base is None or self._newest is None:
            return
        stop = max(self._newest, expired_through) if force else self._newest
        stop = min(stop, self._base + self.capacity - 1)
        if stop < self._base:
            return
        span = np.arange(self._base, stop + 1, dtype=np.int64)
        slots = span % self.capacity
        complete = self._have[slots].all(axis=1)
        expired = span <= expired_through
        blocked = ~complete & ~expired
        end = int(np.argmax(blocked)) if blocked.any() else span.size
        if end == 0:
            return
        done = slice(0, end)
        ready = complete[done]
        missing = ~ready
        if self.stats.emitted == 0:
            # before the first complete sample, channels are still being connected
            before_first = np.arange(end) < (int(np.argmax(ready)) if ready.any() else end)
            self.stats.unmatched_at_start += int(np.count_nonzero(missing & before_first))
            missing &= ~before_first
        if ready.any():
            self._out_indices.append(span[done][ready])
            self._out_values.append(self._values[slots[done][ready]].copy())
            self.stats.emitted += int(np.count_nonzero(ready))
        self.stats.lost += int(np.count_nonzero(missing))
        self._have[slots[done]] = False
        self._values[slots[done]] = np.nan
        self._base = int(span[end - 1]) + 1

    def flush(self) -> None:
        """Give up waiting: emit every complete pending sample and lose the others."""
        if self._base is not None and self._newest is not None:
            self._collect(self._newest, force=True)

    def pop_ready(self) -> tuple[np.ndarray, np.ndarray]:
        """
        Return ``(indices, values)`` of the complete samples emitted since the last call.

        ``values`` has one column per channel, in the order of ``channels``.
        """
        if not self._out_indices:
            return np.empty(0, dtype=np.int64), np.empty((0, len(self.channels)))
        indices = np.concatenate(self._out_indices)
        values = np.vstack(self._out_values)
        self._out_indices.clear()
        self._out_values.clear()
        return indices, values


class SampleInbox:
    """
    Take values from message callbacks (any thread) until the processing step aligns them.

    Parameters
    ----------
    channels : sequence of str
        Channel names.
    sample_period_s : float
        The sample period [s]; timestamps are rounded to this grid.
    align_by : str
        ``'sequence'``: a value's index is its message's DDS publication sequence number
        minus one (the n-th message published on each topic is sample n); ``'timestamp'``:
        its DDS source timestamp on the grid (see :meth:`index_of_stamp`).

    Attributes
    ----------
    last_seen : dict
        Channel name -> :func:`time.monotonic` of its latest value.

    """

    def __init__(self, channels: Sequence[str], sample_period_s: float,
                 align_by: str = 'sequence') -> None:
        self.channels = tuple(channels)
        self.sample_period_s = float(sample_period_s)
        self.align_by = align_by
        self.last_seen: dict[str, float] = {}
        self._origin_ns: Optional[int] = None
        self.invalid_times = 0
        self._lock = threading.Lock()
        self._boxes: dict[str, tuple[list, list]] = self._empty()

    def _empty(self) -> dict[str, tuple[list, list]]:
        return {channel: ([], []) for channel in self.channels}

    def index_of_stamp(self, stamp_ns: int) -> int:
        """Sample index of a timestamp [ns] on the grid that starts at the first one seen."""
        if self._origin_ns is None:
            self._origin_ns = int(stamp_ns)
        return int(grid_indices([stamp_ns], self.sample_period_s, self._origin_ns)[0])

    def put_message(self, channel: str, value: float, info: Mapping[str, Any],
                    by_timestamp: bool = False) -> None:
        """
        Put the value of one message with its DDS metadata ``info``.

        ``info`` holds ``publication_sequence_number`` and ``source_timestamp`` or
        ``received_timestamp`` [ns], as rclpy's ``take_message`` returns them;
        ``by_timestamp`` places this channel by timestamp whatever ``align_by`` says.
        """
        sequence = info.get('publication_sequence_number')
        if self.align_by == 'sequence' and not by_timestamp and sequence:
            index = int(sequence) - 1
        else:
            index = self.index_of_stamp(info.get('source_timestamp') or
                                        info['received_timestamp'])
        self.put(channel, index, value)

    def seen(self, channels: Sequence[str]) -> None:
        """Note that values of ``channels`` arrived now (held elsewhere before they come)."""
        now = time.monotonic()
        with self._lock:
            for channel in channels:
                self.last_seen[channel] = now

    def put(self, channel: str, index: int, value: float) -> None:
        """Put one value of ``channel`` for sample ``index``."""
        with self._lock:
            self.last_seen[channel] = time.monotonic()
            indices, values = self._boxes[channel]
            indices.append(index)
            values.append(value)

    def put_block(self, channel: str, indices: np.ndarray, values: np.ndarray) -> None:
        """Put values of ``channel`` for the sample ``indices``."""
        with self._lock:
            self.last_seen[channel] = time.monotonic()
            store_indices, store_values = self._boxes[channel]
            store_indices.append(indices)
            store_values.append(values)

    def put_times(self, time_s: np.ndarray, columns: Mapping[str, np.ndarray]) -> None:
        """
        Put samples taken at ``time_s`` [s] (one grid instant each).

        NaN times, and times beyond :data:`MAX_INDEX` sample periods (no int64 arithmetic
        on them is safe), are dropped and counted in ``invalid_times``.
        """
        with np.errstate(invalid='ignore', over='ignore'):
            indices = np.rint(np.asarray(time_s, dtype=float) / self.sample_period_s)
            good = np.isfinite(indices) & (np.abs(indices) <= MAX_INDEX)
        self.invalid_times += int(good.size - np.count_nonzero(good))
        indices = indices[good].astype(np.int64)
        for channel, values in columns.items():
            if channel in self.channels:
                self.put_block(channel, indices, np.asarray(values)[good])

    def drain_into(self, aligner: StreamAligner) -> None:
        """Hand every value put so far to ``aligner``, channel by channel."""
        with self._lock:
            boxes, self._boxes = self._boxes, self._empty()
        blocks: dict[str, tuple[Any, Any]] = {}
        for channel, (indices, values) in boxes.items():
            if not indices:
                continue
            if isinstance(indices[0], np.ndarray):
                blocks[channel] = (np.concatenate(indices), np.concatenate(values))
            else:
                blocks[channel] = (indices, values)
        aligner.add_blocks(blocks)


def grid_indices(stamps_ns: Any, sample_period_s: float, origin_ns: int) -> np.ndarray:
    """Nearest sample index ``round((stamp - origin) / dt)`` of every timestamp [ns]."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    return np.rint((stamps - np.int64(origin_ns)) / (sample_period_s * 1e9)).astype(np.int64)


def contiguous_runs(indices: Any) -> list[slice]:
    """Split sorted sample indices into runs without gaps; return a list of slices."""
    indices = np.asarray(indices)
    if indices.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(indices) != 1) + 1
    starts = np.concatenate([[0], breaks])
    stops = np.concatenate([breaks, [indices.size]])
    return [slice(int(a), int(b)) for a, b in zip(starts, stops)]


def unique_sorted(values: Any, return_index: bool = False) -> Any:
    """
    ``numpy.unique`` by a stable sort (and its ``return_index``: first occurrences).

    numpy 2.4's hash-based ``unique`` takes seconds on 200 000 int64 stamps (a 1 M-sample
    bag took 90 s to align); a sort takes milliseconds.
    """
    values = np.asarray(values)
    order = np.argsort(values, kind='stable')
    ordered = values[order]
    keep = np.ones(ordered.size, dtype=bool)
    keep[1:] = ordered[1:] != ordered[:-1]
    if return_index:
        return ordered[keep], order[keep]
    return ordered[keep]


def estimate_period_ns(stamps_by_channel: Mapping[str, Any]) -> float:
    """
    Return the median step of the timestamps [ns] (duplicates ignored).

    Channels whose own median step is under half the longest one (stamped on arrival, in
    bursts) are left out: their steps say how fast messages came, not the period.
    """
    steps = []
    for stamps in stamps_by_channel.values():
        stamps = unique_sorted(np.asarray(stamps, dtype=np.int64))
        if stamps.size > 1:
            steps.append(np.diff(stamps))
    if not steps:
        raise InputDataError('too few messages to find the sample period; each topic needs '
                             'at least two')
    medians = [float(np.median(channel_steps)) for channel_steps in steps]
    kept = [channel_steps for channel_steps, median in zip(steps, medians)
            if median >= 0.5 * max(medians)]
    return float(np.median(np.concatenate(kept)))


def refine_period_ns(stamps_by_channel: Mapping[str, Any], period_ns: float) -> float:
    """
    Return the period [ns] that the timestamps keep over their whole span.

    The median step of jittered stamps is a little off (0.05 % for a 5 % jitter), and over
    thousands of samples that drifts by periods. Each channel's stamps are counted against
    a grid from their start over a span that doubles (32, 64, ... steps), the period taken
    from the least-squares slope of stamp against grid index at each doubling, so the index
    is never more than a fraction of a period off. Channels with more than 5 % of their
    stamps over :data:`MAX_GRID_RESIDUAL` off their grid in the end, or sharing a grid
    instant (stamped on arrival, in bursts), do not count, unless no channel is on a grid.
    A result more than 1 % from ``period_ns`` is not taken.
    """
    fits = []
    for stamps in stamps_by_channel.values():
        stamps = unique_sorted(np.asarray(stamps, dtype=np.int64))
        if stamps.size < 3:
            continue
        offsets = (stamps - stamps[0]).astype(float)
        period = period_ns
        span = 32
        while True:
            part = offsets[:span + 1]
            index = np.rint(part / period)
            if unique_sorted(index).size >= 3:
                period = float(np.polyfit(index, part, 1)[0])
            if span >= offsets.size:
                break
            span *= 2
        index = np.rint(offsets / period)
        residual = np.abs(offsets / period - index)
        # on a grid: near its instants, one stamp an instant (not a burst on one)
        on_grid = (np.count_nonzero(residual > MAX_GRID_RESIDUAL) <= 0.05 * offsets.size and
                   offsets.size - unique_sorted(index).size <= 0.05 * offsets.size)
        fits.append((period, stamps.size, on_grid))
    chosen = [fit for fit in fits if fit[2]] or fits
    if not chosen:
        return period_ns
    refined = float(np.average([fit[0] for fit in chosen], weights=[fit[1] for fit in chosen]))
    return refined if abs(refined / period_ns - 1.0) < 0.01 else period_ns


def align_timestamps(stamps_by_channel: Mapping[str, Any], values_by_channel: Mapping[str, Any],
                     sample_period_s: Optional[float] = None,
                     source: str = '') -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """
    Pair the values of several channels by timestamp on one uniform grid.

    Parameters
    ----------
    stamps_by_channel : dict
        Channel name -> timestamps [ns] (int), any order.
    values_by_channel : dict
        Channel name -> values, same lengths.
    sample_period_s : float, optional
        The grid step [s]; default the median step of the timestamps.
    source : str
        Name used in error messages (a path).

    Returns
    -------
    stamps_ns : numpy.ndarray
        Grid instants [ns] of the samples every channel has, sorted.
    values : dict
        Channel name -> values at those instants (the first value where an index repeats).

    Raises
    ------
    InputDataError
        When no sample is shared by all channels, or the timestamps do not lie on a uniform
        grid (more than a quarter of a period off for over 5 % of the messages).

    """
    name = source or 'data'
    if sample_period_s is None:
        period_ns = refine_period_ns(stamps_by_channel, estimate_period_ns(stamps_by_channel))
    else:
        period_ns = float(sample_period_s) * 1e9
    if not period_ns > 0:
        raise InputDataError(f'{name}: the timestamps do not advance (median step 0); the '
                             'messages need distinct timestamps')
    origin = _grid_origin(stamps_by_channel, period_ns)
    common = None
    per_channel = {}
    for channel, stamps in stamps_by_channel.items():
        unique, values = _on_grid(stamps, values_by_channel[channel], origin, period_ns,
                                  f'{name}: the timestamps of {channel}')
        per_channel[channel] = (unique, values)
        common = unique if common is None else np.intersect1d(common, unique,
                                                              assume_unique=True)
    if common is None or common.size == 0:
        raise InputDataError(f'{name}: no instant has a value on every channel '
                             f'({", ".join(stamps_by_channel)}); check the topic names')
    aligned = {channel: channel_values[np.searchsorted(index, common)]
               for channel, (index, channel_values) in per_channel.items()}
    stamps = origin + np.rint(common * period_ns).astype(np.int64)
    return stamps, aligned


def _grid_origin(stamps_by_channel: Mapping[str, Any], period_ns: float) -> int:
    """Return the grid's origin [ns]: where the stamps are on average (circular mean)."""
    origin = min(int(np.min(stamps)) for stamps in stamps_by_channel.values())
    # put the grid where the stamps are on average (circular mean of their phase)
    phases = np.concatenate([(np.asarray(stamps, dtype=np.int64) - origin) % period_ns
                             for stamps in stamps_by_channel.values()]) / period_ns
    shift = np.angle(np.mean(np.exp(2j * np.pi * phases))) / (2 * np.pi)
    return origin + int(round(shift * period_ns))


def _on_grid(stamps: Any, values: Any, origin: int, period_ns: float,
             what: str) -> tuple[np.ndarray, np.ndarray]:
    """
    Return one channel's grid indices (sorted, unique) and its first value at each.

    Raises
    ------
    InputDataError
        When over 5 % of the stamps are more than a quarter period off the grid (``what``
        names the channel).

    """
    stamps = np.asarray(stamps, dtype=np.int64)
    values = np.asarray(values, dtype=float)
    exact = (stamps - origin) / period_ns
    index = np.rint(exact).astype(np.int64)
    residual = np.abs(exact - index)
    off = np.count_nonzero(residual > MAX_GRID_RESIDUAL)
    if off > 0.05 * stamps.size:
        raise InputDataError(
            f'{what} are not on a uniform grid of '
            f'{period_ns * 1e-9:.6g} s ({off} of {stamps.size} messages are more than a '
            'quarter period off; up to a quarter period of jitter is placed on the grid). '
            'If the sample period is known, give it with --sample-period S; else record '
            'with the identifier node, or with timestamps taken when each sample was '
            'measured')
    order = np.argsort(index, kind='stable')
    index, values = index[order], values[order]
    unique, first = unique_sorted(index, return_index=True)
    return unique, values[first]
