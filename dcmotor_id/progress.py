"""
Progress and time budget of a long identification: a throttled one-line writer and a deadline.

The estimators and the discovery loop call a :class:`Progress` with what they are doing
(stage, record, iteration, cost); it rewrites one line on a terminal (stderr by default) at
most a few times a second and only once the work has run for ``delay_s`` (short runs print
nothing), and it raises :class:`TimeBudgetExceeded` once the deadline has passed, which the
callers turn into "the best result so far, with a warning".  The node passes its own
callback or none; :data:`SILENT` writes nothing and has no deadline.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO


class TimeBudgetExceeded(Exception):
    """The time budget (``--max-time``) ran out; the caller keeps its best result so far."""


class Progress:
    """
    A progress report and a deadline, called by the fits as they go.

    Parameters
    ----------
    max_time_s : float or None
        Time budget from construction [s]; None: no deadline.
    stream : file-like or None
        Where the line goes (stderr); None writes nothing.
    enabled : bool or None
        Write at all; None: only when ``stream`` is a terminal.
    delay_s : float
        Nothing is written before the work has run this long [s].
    interval_s : float
        Least time between two writes [s].
    callback : callable, optional
        Called with the line's text instead of (or besides) writing it (the node's logger).

    """

    def __init__(self, max_time_s: float | None = None, stream: TextIO | None = None,
                 enabled: bool | None = None, delay_s: float = 2.0, interval_s: float = 0.25,
                 callback: Callable[[str], None] | None = None) -> None:
        self.start = time.monotonic()
        self.deadline = None if max_time_s is None else self.start + float(max_time_s)
        self.max_time_s = max_time_s
        self.stream = stream
        if enabled is None:
            enabled = bool(stream is not None and getattr(stream, 'isatty', lambda: False)())
        self.enabled = enabled and stream is not None
        self.delay_s = delay_s
        self.interval_s = interval_s
        self.callback = callback
        self.stage = ''
        self.record: str | None = None
        self._last = 0.0
        self._width = 0
        self.evaluations = 0

    def elapsed(self) -> float:
        """Return the seconds since construction."""
        return time.monotonic() - self.start

    def remaining(self) -> float:
        """Return the seconds left of the budget (infinite without one)."""
        if self.deadline is None:
            return float('inf')
        return self.deadline - time.monotonic()

    def expired(self) -> bool:
        """Whether the time budget has run out."""
        return self.deadline is not None and time.monotonic() > self.deadline

    def set_stage(self, stage: str, record: str | None = None) -> None:
        """Name what runs now (e.g. ``base fit``, ``candidate load_torque``)."""
        self.stage = stage
        self.record = record
        self.update(force=True)

    def update(self, iteration: int | None = None, cost: float | None = None,
               force: bool = False) -> None:
        """
        Report one step (an evaluation of the fit); raise when the budget has run out.

        Raises
        ------
        TimeBudgetExceeded
            Past the deadline.

        """
        self.evaluations += 1
        now = time.monotonic()
        if self.deadline is not None and now > self.deadline:
            raise TimeBudgetExceeded(f'time budget of {self.max_time_s:g} s used up')
        if not (self.enabled or self.callback):
            return
        if now - self.start < self.delay_s or (not force and now - self._last < self.interval_s):
            return
        self._last = now
        text = f'dcmotor-id: {now - self.start:5.1f} s  {self.stage}'
        if self.record:
            text += f'  [{self.record}]'
        text += f'  evaluation {self.evaluations if iteration is None else iteration}'
        if cost is not None:
            text += f'  cost {cost:.4g}'
        if self.callback is not None:
            self.callback(text)
        if self.enabled:
            assert self.stream is not None
            self.stream.write('\r' + text.ljust(self._width))
            self.stream.flush()
            self._width = len(text)

    def __call__(self, iteration: int | None = None, cost: float | None = None) -> None:
        """Report one step (same as :meth:`update`)."""
        self.update(iteration, cost)

    def close(self) -> None:
        """Clear the line (a terminal's next output starts on a clean line)."""
        if self.enabled and self._width:
            assert self.stream is not None
            self.stream.write('\r' + ' ' * self._width + '\r')
            self.stream.flush()
            self._width = 0


#: No output, no deadline.
SILENT = Progress()


def terminal_progress(max_time_s: float | None, quiet: bool = False) -> Progress:
    """Return the CLI's progress: on stderr when it is a terminal and not ``quiet``."""
    return Progress(max_time_s, stream=None if quiet else sys.stderr)
