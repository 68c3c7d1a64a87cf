"""
What the fleet job reports its progress to: bags, windows and failures.

The command line's bar (:class:`dcmotor_id.cli.terminal.FleetProgressBar`) is one; a caller
of :func:`dcmotor_id.fleet.run_fleet` may pass its own, or none.
"""

from __future__ import annotations

from typing import Protocol


class Progress(Protocol):
    """Receives the counts of a fleet job as it goes (and once more at the end)."""

    def update(self, bags_done: int, bags_total: int, windows_done: int, windows_known: int,
               failures: int, planning: bool = False, final: bool = False) -> None:
        """Take the counts: bags done of all, windows done of those known, failures."""
