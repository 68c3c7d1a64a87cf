"""
Cutting aligned drive samples into windows and choosing the windows to identify (no ROS here).

A :class:`WindowCutter` takes the complete samples a
:class:`~dcmotor_id.formats.streams.StreamAligner`
emits (sample indices and one value column per channel) and cuts them into :class:`Window` s:

* a window ends when it holds ``window_s`` of samples, or at a lost sample (a gap in the
  indices), or when it is closed on request (``~/identify``, a stopped topic, shutdown);
* a run of samples shorter than ``min_window_s`` (at least ``min_samples``) is dropped and
  counted in :attr:`WindowCutter.discarded_samples`;
* the windows of about the last ``3 window_s`` are kept in memory, and :meth:`WindowCutter.select`
  picks the newest of them that together hold at least ``window_s`` of data.

The cutter knows nothing of callbacks, threads of an executor or files: the node feeds it,
takes the closed windows with :meth:`WindowCutter.pop_closed` and writes them.
"""

from __future__ import annotations

from collections import deque
import itertools
import math
import threading
from typing import Callable, NamedTuple, Optional, Sequence

import numpy as np

from dcmotor_id.formats.streams import contiguous_runs

_numbers = itertools.count(1)


class Window:
    """
    A contiguous run of aligned samples: grid stamps [ns] and channel arrays.

    Attributes
    ----------
    number : int
        Serial number of the window in this process (1, 2, ...).
    stamps_ns : numpy.ndarray
        Sample instants [ns] on the grid of the sample period.
    channels : dict
        Channel name -> values at those instants.
    path : str or None
        Where the window was recorded, once it was.
    error : str or None
        Why it was not recorded, if it was not.
    written : threading.Event
        Set once recording it has finished (or was not asked for).

    """

    def __init__(self, stamps_ns: np.ndarray, channels: dict[str, np.ndarray]) -> None:
        self.number = next(_numbers)
        self.stamps_ns = stamps_ns
        self.channels = channels
        self.path: Optional[str] = None
        self.error: Optional[str] = None
        self.written = threading.Event()

    @property
    def size(self) -> int:
        """Return the number of samples."""
        return int(self.stamps_ns.size)

    @property
    def duration_s(self) -> float:
        """Span covered by the samples [s] (samples times the period)."""
        if self.stamps_ns.size < 2:
            return 0.0
        step = (self.stamps_ns[-1] - self.stamps_ns[0]) / (self.stamps_ns.size - 1)
        return float(self.stamps_ns.size * step * 1e-9)

    @property
    def source(self) -> str:
        """Name of the window in records and messages: its bag, else ``window <number>``."""
        return self.path or f'window {self.number}'


class Run(NamedTuple):
    """Samples without a gap, as added to a cutter, and whether a gap came before them."""

    indices: np.ndarray
    values: np.ndarray
    after_gap: bool


class WindowCutter:
    """
    Cut aligned samples into windows; keep the recent ones; select those to identify.

    Parameters
    ----------
    channels : sequence of str
        Channel names, the order of the value columns.
    sample_rate_hz : float
        Sample rate [Hz].
    window_s : float
        Length of a full window, and the data :meth:`select` gathers [s].
    min_window_s : float
        Runs shorter than this are dropped [s].
    min_samples : int
        Runs with fewer samples are dropped whatever ``min_window_s`` says.
    clock_ns : callable
        Returns the time [ns] that the first sample is anchored at (the node's clock).
    restart_samples : int
        A forward jump of the indices by more than this is a new origin, like any jump back.

    Attributes
    ----------
    anchor_ns : int or None
        The stamp sample index 0 has (the first sample is stamped with the clock's time when
        it arrives, every later one ``period`` after the one before it). When the indices
        go back (a restarted publisher, a new time origin) or jump absurdly far ahead, the
        cutter anchors anew: the first sample of the new origin gets the clock's time, but
        never less than a period after the last sample stamped, so windows never overlap
        and are never stamped in the past. ``restarts`` counts the new anchors.

    """

    def __init__(self, channels: Sequence[str], sample_rate_hz: float, window_s: float,
                 min_window_s: float, *, min_samples: int,
                 clock_ns: Callable[[], int], restart_samples: int = 2 ** 40) -> None:
        self.channels = tuple(channels)
        self.sample_rate_hz = float(sample_rate_hz)
        self.window_s = float(window_s)
        self.min_samples = max(int(min_window_s * self.sample_rate_hz), int(min_samples))
        self.discarded_samples = 0
        self.anchor_ns: Optional[int] = None
        self.restarts = 0
        self.restart_samples = int(restart_samples)
        self._clock_ns = clock_ns
        self._period_ns = 1e9 / self.sample_rate_hz
        self._last_index: Optional[int] = None
        self._reference: tuple[int, int] = (0, 0)   # (index, its stamp [ns])
        self._clock_pending = False  # anchored on a clock without time (sim time, no /clock)
        self._last_stamp_ns: Optional[int] = None
        self._current: list[tuple[np.ndarray, np.ndarray]] = []
        self._current_count = 0
        self._windows: deque[Window] = deque()
        self._closed: list[Window] = []
        self._lock = threading.Lock()

    @property
    def windows(self) -> tuple[Window, ...]:
        """Return the windows kept in memory, oldest first."""
        with self._lock:
            return tuple(self._windows)

    @property
    def held_samples(self) -> int:
        """Count the samples in the kept windows and in the window being filled."""
        with self._lock:
            return sum(window.size for window in self._windows) + self._current_count

    def add(self, indices: np.ndarray, values: np.ndarray) -> list[Run]:
        """
        Add complete samples (increasing indices, one value column per channel).

        A gap in the indices, also against the previous call, closes the current window.
        Returns the runs without gaps that the samples consist of, in order.
        """
        runs: list[Run] = []
        if indices.size == 0:
            return runs
        full = self.window_s * self.sample_rate_hz
        for run_slice in contiguous_runs(indices):
            run_indices, run_values = indices[run_slice], values[run_slice]
            first = int(run_indices[0])
            after_gap = self._last_index is not None and first != self._last_index + 1
            if after_gap:
                self.close()
            if self.anchor_ns is None or (self._last_index is not None and (
                    first <= self._last_index or
                    first - self._last_index > self.restart_samples)):
                self._anchor(first)
            elif self._clock_pending:
                self._settle_clock(first)
            self._last_index = int(run_indices[-1])
            runs.append(Run(run_indices, run_values, bool(after_gap)))
            start = 0
            while start < run_indices.size:
                room = int(math.ceil(full)) - self._current_count
                part = slice(start, start + max(room, 1))
                with self._lock:
                    self._current.append((run_indices[part], run_values[part]))
                    self._current_count += run_indices[part].size
                start = part.stop
                if self._current_count >= full - 0.5:
                    self.close()
        return runs

    def _anchor(self, index: int) -> None:
        """Stamp sample ``index`` now (after the last sample stamped) and the rest from it."""
        stamp = int(self._clock_ns())
        if self._last_stamp_ns is not None:
            stamp = max(stamp, self._last_stamp_ns + int(math.ceil(self._period_ns)))
            self.restarts += 1
        self._reference = (int(index), stamp)
        self.anchor_ns = stamp - int(round(index * self._period_ns))
        self._clock_pending = stamp <= 0 and self._last_stamp_ns is None

    def _settle_clock(self, index: int) -> None:
        """
        Anchor sample ``index`` anew once a clock that had no time yet has one.

        A node on simulated time (``use_sim_time``) reads 0 until its first ``/clock``
        message, which may come after the first samples: they are stamped from the first
        time the clock gives, as long as no window was stamped before.
        """
        stamp = int(self._clock_ns())
        if stamp > 0 and self._last_stamp_ns is None:
            self._clock_pending = False
            self._reference = (int(index), stamp)
            self.anchor_ns = stamp - int(round(index * self._period_ns))

    def close(self, keep_short: bool = False) -> Optional[Window]:
        """
        Turn the samples of the current window into a window (None when there are none).

        Too few samples are dropped, or with ``keep_short`` left to be continued.
        """
        with self._lock:
            if not self._current:
                return None
            if self._current_count < self.min_samples:
                if keep_short:
                    return None
                self.discarded_samples += self._current_count
                self._current = []
                self._current_count = 0
                return None
            indices = np.concatenate([part[0] for part in self._current])
            values = np.vstack([part[1] for part in self._current])
            self._current = []
            self._current_count = 0
            reference_index, reference_ns = self._reference
            stamps = reference_ns + np.rint((indices - reference_index) * self._period_ns
                                            ).astype(np.int64)
            self._last_stamp_ns = int(stamps[-1])
            window = Window(stamps, {name: values[:, k].copy()
                                     for k, name in enumerate(self.channels)})
            self._windows.append(window)
            keep_s = 3.0 * self.window_s
            while sum(w.duration_s for w in self._windows) - self._windows[0].duration_s \
                    >= keep_s:
                self._windows.popleft()
            self._closed.append(window)
        return window

    def pop_closed(self) -> list[Window]:
        """Return the windows closed since the last call, oldest first."""
        with self._lock:
            closed, self._closed = self._closed, []
        return closed

    def select(self) -> list[Window]:
        """Return the most recent windows, newest last, until they hold ``window_s`` of data."""
        chosen = []
        total = 0.0
        with self._lock:
            for window in reversed(self._windows):
                if window.size < self.min_samples:
                    continue
                chosen.append(window)
                total += window.duration_s
                if total >= self.window_s - 0.5 * (1.0 / self.sample_rate_hz):
                    break
        return list(reversed(chosen))
