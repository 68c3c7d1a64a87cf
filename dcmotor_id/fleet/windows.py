"""
Cutting one motor's record into the windows identified as separate tasks.

The cutting is :class:`dcmotor_id.streaming.windowing.WindowCutter`'s, the node's own: a window
holds ``window_s`` of samples, the last one what remains if that is at least ``min_window_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dcmotor_id.core.records import Record, record_from_stamps
from dcmotor_id.streaming.windowing import WindowCutter

#: Channels carried by a fleet window (those of a record).
CHANNELS = ('voltage', 'current', 'speed', 'position')


@dataclass(frozen=True)
class FleetWindow:
    """
    One window of one motor's recording: the unit of work of the fleet job.

    Attributes
    ----------
    motor_id : str
        The motor.
    index : int
        Position of the window in the recording (0, 1, ...).
    start_ns, end_ns : int
        Instants of its first and last sample [ns] (bag time).
    record : Record
        Its samples (time from 0 at ``start_ns``).

    """

    motor_id: str
    index: int
    start_ns: int
    end_ns: int
    record: Record


def cut_windows(record: Record, start_ns: int, motor_id: str, window_s: float,
                min_window_s: float) -> list[FleetWindow]:
    """
    Cut a record into windows of ``window_s``; a shorter rest is kept from ``min_window_s``.

    Parameters
    ----------
    record : Record
        One motor's samples, time from 0.
    start_ns : int
        Bag time of its first sample [ns].
    motor_id : str
        The motor, copied into every window.
    window_s, min_window_s : float
        Window length and the shortest rest kept [s].

    """
    # the period on whole nanoseconds, as the bag's stamps: 1/period is then exact enough
    # that a window of window_s holds window_s/period samples, not one more
    period_ns = round(record.sample_period_s * 1e9)
    period_s = period_ns * 1e-9
    present = [name for name in CHANNELS if getattr(record, name) is not None]
    cutter = WindowCutter(present, 1e9 / period_ns, window_s, min_window_s, min_samples=2,
                          clock_ns=lambda: int(start_ns))
    indices = np.rint(record.time_s / period_s).astype(np.int64)
    cutter.add(indices, np.column_stack([getattr(record, name) for name in present]))
    cutter.close()
    windows = []
    for number, window in enumerate(cutter.pop_closed()):
        stamps = window.stamps_ns
        source = f'{record.source} [{number}]' if record.source else f'window {number}'
        windows.append(FleetWindow(motor_id, number, int(stamps[0]), int(stamps[-1]),
                                   record_from_stamps(stamps, window.channels, source)))
    return windows
