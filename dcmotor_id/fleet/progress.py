"""
The fleet job's progress line on stderr: bags, windows and failures.

Written by hand rather than with a progress-bar library because it counts three things at
once and must also behave in a log file; the line itself is the package's one status-line
writer (:class:`dcmotor_id.core.progress.StatusLine`): on a terminal redrawn at most every 0.2 s,
elsewhere (a pipe, a CI log) a plain line every 10 s and a last one at the end.
"""

from __future__ import annotations

import sys
import time
from typing import Optional, TextIO

from dcmotor_id.core.progress import StatusLine


class Progress:
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
