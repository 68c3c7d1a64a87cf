"""
Progress and time budget of long work: what runs now, and a deadline.

The estimators and the discovery loop call a :class:`Progress` with what they are doing
(stage, record, iteration, cost); it rewrites one line on a terminal (stderr by default) at
most a few times a second and only once the work has run for ``delay_s`` (short runs print
nothing), and it raises :class:`TimeBudgetExceeded` once the deadline has passed, which the
callers turn into "the best result so far, with a warning".  The node passes its own
callback or none; :data:`SILENT` writes nothing and has no deadline; the command line's
progress and its other status lines are in :mod:`dcmotor_id.cli.terminal`.

The budget is counted in CPU seconds of the process (:func:`budget_clock`), not on the wall
clock: on a machine shared with other work a wall-clock budget ran out at a third of the
computation (HSM150, twelve records: 120 s of wall clock, 40 s of CPU) and the result then
depended on the load.  The status line and :meth:`Progress.elapsed` show the wall clock.
"""

from __future__ import annotations

import time
from typing import Callable, TextIO


def budget_clock() -> float:
    """
    Return the clock of the time budget: CPU seconds of this process, all its threads [s].

    Only the work done counts, whatever else the machine runs; a process that waits (for a
    subprocess, a lock) spends none of its budget meanwhile.
    """
    return time.process_time()


class TimeBudgetExceeded(Exception):
    """The time budget (``--max-time``) ran out; the caller keeps its best result so far."""


class _LineInPlace:
    """
    The progress line (:class:`Progress` throttles it).

    On a terminal it is redrawn in place; elsewhere (a pipe, a CI log) each text is a plain line.
    """

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.tty = bool(getattr(stream, 'isatty', lambda: False)())
        self._shown = ''

    def show(self, text: str) -> None:
        """Draw ``text`` over the line shown before (a new line when not a terminal)."""
        if not self.tty:
            self.stream.write(text + '\n')
            self.stream.flush()
            return
        padding = ' ' * max(0, len(self._shown) - len(text))
        self.stream.write('\r' + text + padding)
        self._shown = text
        self.stream.flush()

    def clear(self) -> None:
        """Blank the line, so the next output starts clean."""
        if self._shown:
            self.stream.write('\r' + ' ' * len(self._shown) + '\r')
            self.stream.flush()
        self._shown = ''


class Progress:
    """
    A progress report and a deadline, called by the fits as they go.

    Parameters
    ----------
    max_time_s : float or None
        Time budget from construction [s of CPU time, :func:`budget_clock`]; None: no
        deadline.
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
        # On the budget's clock (:meth:`now`), like every deadline set on a Progress.
        self.deadline = None if max_time_s is None else self.now() + float(max_time_s)
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
        self.run = ''  # which run of several (:meth:`set_run`); empty: the first
        self._last = 0.0
        # (its own throttle below: interval_s and delay_s; a forced write ignores them)
        # Redrawn in place on a terminal; plain lines elsewhere (a pipe, a CI log).
        self.line = _LineInPlace(stream) if self.enabled and stream is not None else None
        self.evaluations = 0

    @staticmethod
    def now() -> float:
        """Return the reading of the budget's clock (:func:`budget_clock`) [s]."""
        return budget_clock()

    def elapsed(self) -> float:
        """Return the wall-clock seconds since construction."""
        return time.monotonic() - self.start

    def remaining(self) -> float:
        """Return the seconds left of the budget (infinite without one)."""
        if self.deadline is None:
            return float('inf')
        return self.deadline - self.now()

    def expired(self) -> bool:
        """Whether the time budget has run out."""
        return self.deadline is not None and self.now() >= self.deadline

    def set_stage(self, stage: str, record: str | None = None) -> None:
        """Name what runs now (e.g. ``base fit``, ``candidate load_torque``)."""
        self.stage = stage
        self.record = record
        self.update(force=True)

    def set_run(self, run: str) -> None:
        """
        Say that another run of the identification starts (its stages follow, named after it).

        An empty ``run`` ends the naming (nothing is written).

        E.g. the identification on the position run again with another error model
        (:mod:`dcmotor_id.identification.pipeline.position_error`): without it the line would
        go back
        to ``base fit`` without saying why.
        """
        self.run = run
        if not run:
            return
        self.stage = 'starting'
        self.record = None
        self._show(None, None, force=True)  # (no budget check: the run's own stages do it)

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
        if self.expired():
            raise TimeBudgetExceeded(f'time budget of {self.max_time_s:g} s (CPU) used up')
        self._show(iteration, cost, force)

    def _show(self, iteration: int | None, cost: float | None, force: bool) -> None:
        """Write the line (or call back) when due."""
        now = time.monotonic()
        if not (self.enabled or self.callback):
            return
        # In a log (plain lines) even a new stage waits for the interval: a line every few
        # seconds, not one per candidate of the discovery loop.
        throttled = not force or (self.line is not None and not self.line.tty)
        if now - self.start < self.delay_s or (throttled and now - self._last < self.interval_s):
            return
        self._last = now
        text = f'dcmotor-id: {now - self.start:5.1f} s  ' + (f'{self.run}: ' if self.run else '') \
            + self.stage
        if self.record:
            text += f'  [{self.record}]'
        text += f'  evaluation {self.evaluations if iteration is None else iteration}'
        if cost is not None:
            text += f'  cost {cost:.4g}'
        if self.callback is not None:
            self.callback(text)
        if self.line is not None:
            self.line.show(text)

    def __call__(self, iteration: int | None = None, cost: float | None = None) -> None:
        """Report one step (same as :meth:`update`)."""
        self.update(iteration, cost)

    def close(self) -> None:
        """Clear the line (a terminal's next output starts on a clean line)."""
        if self.line is not None:
            self.line.clear()


#: No output, no deadline.
SILENT = Progress()
