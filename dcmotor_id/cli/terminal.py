"""
The terminal's status lines: one writer, the identification's line and the fleet's bar.

:class:`StatusLine` is the one writer of a status line on stderr (redrawn in place on a
terminal, plain lines in a log). :func:`terminal_progress` is what ``dcmotor-id identify``
reports to (the identification's :class:`~dcmotor_id.core.progress.Progress` on stderr when
it is a terminal), and :class:`FleetProgressBar` shows ``dcmotor-id fleet``'s bags, windows
and failures.

The fleet's bar is written by hand rather than with a progress-bar library because it counts
three things at once and must also behave in a log file: on a terminal redrawn at most every
0.2 s, elsewhere (a pipe, a CI log) a plain line every 10 s and a last one at the end.
"""

from __future__ import annotations

import sys
import time
from typing import Optional, TextIO

from dcmotor_id.core.progress import Progress


class StatusLine:
    """
    Write a status line at most every ``interval_s``.

    On a terminal the line is redrawn in place; elsewhere (a pipe, a CI log) each update is a
    plain line, identical texts not repeated.

    Parameters
    ----------
    stream : file-like
        Where the line goes.
    interval_s : float
        Least time between two writes [s] (``final`` and ``force`` writes ignore it).
    redraw : bool or None
        Redraw in place; None: when ``stream`` is a terminal.

    """

    def __init__(self, stream: TextIO, interval_s: float, redraw: bool | None = None) -> None:
        self.stream = stream
        if redraw is None:
            redraw = bool(getattr(stream, 'isatty', lambda: False)())
        self.tty = redraw
        self.interval_s = interval_s
        self._last = -float('inf')
        self._shown = ''

    def due(self, now: float | None = None) -> bool:
        """Whether ``interval_s`` has passed since the last write."""
        return (time.monotonic() if now is None else now) - self._last >= self.interval_s

    def show(self, text: str, final: bool = False, force: bool = False) -> None:
        """Write ``text`` if due (always when ``final`` or ``force``); end the line if final."""
        now = time.monotonic()
        if not (final or force or self.due(now)):
            return
        self._last = now
        if self.tty:
            padding = ' ' * max(0, len(self._shown) - len(text))
            self.stream.write('\r' + text + padding + ('\n' if final else ''))
        elif final or text != self._shown:
            self.stream.write(text + '\n')
        self._shown = '' if final else text
        self.stream.flush()

    def clear(self) -> None:
        """Blank a line drawn on a terminal, so the next output starts clean."""
        if self.tty and self._shown:
            self.stream.write('\r' + ' ' * len(self._shown) + '\r')
            self.stream.flush()
        self._shown = ''


#: Least time between two progress lines when stderr is not a terminal (a pipe, a CI log) [s].
LOG_INTERVAL_S = 5.0


def terminal_progress(max_time_s: float | None, quiet: bool = False,
                      stream: TextIO | None = None) -> Progress:
    """
    Return the CLI's progress on ``stream`` (default stderr); nothing when ``quiet``.

    On a terminal a line redrawn in place a few times a second; elsewhere (a pipe, a CI log,
    where a run was silent for up to its time budget) a plain line every
    :data:`LOG_INTERVAL_S` seconds.
    """
    stream = sys.stderr if stream is None else stream
    if quiet:
        return Progress(max_time_s, stream=None)
    tty = bool(getattr(stream, 'isatty', lambda: False)())
    return Progress(max_time_s, stream=stream, enabled=True,
                    interval_s=0.25 if tty else LOG_INTERVAL_S)


class FleetProgressBar:
    """
    Show ``bags done/total, windows done/known, failures`` as a bar.

    Parameters
    ----------
    stream : file, optional
        Where to write (default ``sys.stderr``).
    interval_s : float, optional
        Least time between two updates (default 0.2 s on a terminal, 10 s otherwise).
    width : int
        Characters of the bar.

    """

    def __init__(self, stream: Optional[TextIO] = None, interval_s: Optional[float] = None,
                 width: int = 24) -> None:
        self.stream = stream if stream is not None else sys.stderr
        tty = bool(getattr(self.stream, 'isatty', lambda: False)())
        self.status = StatusLine(self.stream, interval_s if interval_s is not None
                                 else (0.2 if tty else 10.0))
        self.width = width
        self.started = time.monotonic()

    def line(self, bags_done: int, bags_total: int, windows_done: int, windows_known: int,
             failures: int, planning: bool) -> str:
        """Return the progress text (without line ends)."""
        share = bags_done / bags_total if bags_total else 1.0
        filled = int(round(share * self.width))
        bar = '#' * filled + '.' * (self.width - filled)
        elapsed = int(time.monotonic() - self.started)
        more = '+' if planning else ''
        return (f'fleet [{bar}] bags {bags_done}/{bags_total}  windows '
                f'{windows_done}/{windows_known}{more}  failures {failures}  '
                f'{elapsed // 3600}:{elapsed // 60 % 60:02d}:{elapsed % 60:02d}')

    def update(self, bags_done: int, bags_total: int, windows_done: int, windows_known: int,
               failures: int, planning: bool = False, final: bool = False) -> None:
        """Write the counts, at most every ``interval_s`` (always when ``final``)."""
        if final or self.status.due():
            self.status.show(self.line(bags_done, bags_total, windows_done, windows_known,
                                       failures, planning), final=final)
