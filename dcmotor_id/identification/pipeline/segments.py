"""
Test segments: a recording of several tests with idle or braked stretches in between.

A SysId routine or a day of lab tests logs the stretches between the tests too, where the
drive is disabled or brakes with its windings shorted while the logged voltage and current
read 0: the model (the logged voltage drives the motor) does not hold there, and a fit over
the whole record is pulled off by them.  :func:`find_tests` finds those stretches (voltage
and current both exactly 0 for at least :data:`IDLE_MIN_SAMPLES` samples while the speed
changes beyond its noise: the model would keep the motor coasting on its friction alone, so
a braking it cannot explain shows a drive that is not in the log) and :func:`split_tests` cuts
the records into their tests, each fitted as a record of its own.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.records import MIN_SAMPLES
from dcmotor_id.signals.filters import noise_std

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: Fewest consecutive samples with voltage and current exactly 0 that make an idle stretch.
IDLE_MIN_SAMPLES = 3


@dataclass(frozen=True)
class Tests:
    """The records cut into their tests, and the text naming them (empty: nothing was cut)."""

    records: tuple
    note: str


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Return the ``(start, stop)`` of every run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def idle_samples(record: Record) -> np.ndarray | None:
    """
    Return the samples of a record's idle or braked stretches, or None when it has none.

    Voltage and current exactly 0 for :data:`IDLE_MIN_SAMPLES` samples or more; None unless
    the speed changes beyond its noise in at least one of them (a brake the log does not
    show), so that a record merely standing still between its tests is left whole.
    """
    if record.voltage is None or record.current is None or record.speed is None:
        return None
    voltage = np.asarray(record.voltage, dtype=float)
    current = np.asarray(record.current, dtype=float)
    speed = np.asarray(record.speed, dtype=float)
    zero = (voltage == 0.0) & (current == 0.0)
    idle = np.zeros(zero.shape[0], dtype=bool)
    braked = False
    noise = max(noise_std(speed), 1e-12)
    for start, stop in _runs(zero):
        if stop - start >= IDLE_MIN_SAMPLES:
            idle[start:stop] = True
            braked |= float(np.ptp(speed[start:stop])) > 10.0 * noise
    return idle if braked else None


def _cut(record: Record, tests: np.ndarray, index: int) -> tuple[list, list[str]]:
    """Cut one record at its non-test samples; return the pieces and their names."""
    pieces: list = []
    names: list[str] = []
    time_s = np.asarray(record.time_s, dtype=float)
    for start, stop in _runs(tests):
        if stop - start < MIN_SAMPLES:
            continue
        name = (f'{record.source or f"record {index + 1}"} [test {len(pieces) + 1}: '
                f'{time_s[start]:.4g}-{time_s[stop - 1]:.4g} s]')
        pieces.append(record.slice(start, stop).replace(source=name))
        names.append(name)
    return pieces, names


def split_tests(records: Sequence[Record]) -> Tests:
    """Cut every record that has idle or braked stretches (:func:`idle_samples`) into its tests."""
    out: list = []
    named: list[str] = []
    for index, record in enumerate(records):
        idle = idle_samples(record)
        pieces, names = ([], []) if idle is None else _cut(record, ~idle, index)
        out += pieces if pieces else [record]
        named += names
    if not named:
        return Tests(tuple(records), '')
    return Tests(tuple(out), (
        'stretches with the logged voltage and current at 0 while the speed changes (a drive '
        'disabled or braking with its windings shorted, which the log does not show) lie '
        f'between tests: fitted as {len(named)} separate records (tests of fewer than '
        f'{MIN_SAMPLES} samples left out): ' + '; '.join(named)))
