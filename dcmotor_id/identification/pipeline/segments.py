"""
Test segments: a recording of several tests with idle or braked stretches in between.

A SysId routine or a day of lab tests logs the stretches between the tests too, where the
drive is disabled or brakes with its windings shorted while the logged voltage and current
read 0: the model (the logged voltage drives the motor) does not hold there, and a fit over
the whole record is pulled off by them.  :func:`find_tests` finds those stretches (voltage
and current both exactly 0 for at least :data:`IDLE_MIN_SAMPLES` samples while the speed
changes beyond its noise: the model would keep the motor coasting on its friction alone, so
a braking it cannot explain shows a drive that is not in the log) and :func:`split_tests` cuts
the records into their tests, each fitted as a record of its own.  A record that carries its
tests as logged (``--segment-column NAME``: :attr:`~dcmotor_id.core.records.Record.segment`,
values > 0 in a test, 0 between tests, a change of value starting another test) is cut where
the column says instead (:func:`marked_tests`), and not searched.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import MIN_SAMPLES

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
    noise = max(record.noise_std('speed'), 1e-12)
    for start, stop in _runs(zero):
        if stop - start >= IDLE_MIN_SAMPLES:
            idle[start:stop] = True
            braked |= float(np.ptp(speed[start:stop])) > 10.0 * noise
    return idle if braked else None


def marked_tests(segment: np.ndarray) -> list[tuple[int, int]]:
    """
    Return the ``(start, stop)`` of every test a segment column marks.

    A test is a run of samples with one value > 0; a change of value starts the next one
    (tests logged back to back with their numbers), 0 or less is between tests.
    """
    values = np.asarray(segment, dtype=float)
    runs = []
    for start, stop in _runs(values > 0.0):
        changes = np.flatnonzero(np.diff(values[start:stop])) + start + 1
        bounds = [start, *changes.tolist(), stop]
        runs += [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
    return runs


def _cut(record: Record, tests: np.ndarray | list[tuple[int, int]],
         index: int) -> tuple[list, list[str]]:
    """Cut one record into its tests (a mask or their runs); return the pieces and names."""
    pieces: list = []
    names: list[str] = []
    time_s = np.asarray(record.time_s, dtype=float)
    for start, stop in (_runs(tests) if isinstance(tests, np.ndarray) else tests):
        if stop - start < MIN_SAMPLES:
            continue
        name = (f'{record.source or f"record {index + 1}"} [test {len(pieces) + 1}: '
                f'{time_s[start]:.4g}-{time_s[stop - 1]:.4g} s]')
        pieces.append(record.slice(start, stop).replace(source=name))
        names.append(name)
    return pieces, names


def split_tests(records: Sequence[Record]) -> Tests:
    """
    Cut every record into its tests: as its segment column marks them, else as found.

    A record with a segment column (:func:`marked_tests`) is cut where it says (a record whose
    column marks one test spanning it is left whole); one without is cut at its idle or braked
    stretches (:func:`idle_samples`).
    """
    if any(record.segment is not None for record in records):
        return _split_marked(records)
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


def _split_marked(records: Sequence[Record]) -> Tests:
    """Cut the records with a segment column where it says; the others stay whole."""
    out: list = []
    named: list[str] = []
    for index, record in enumerate(records):
        if record.segment is None:
            out.append(record)
            continue
        runs = marked_tests(record.segment)
        if runs == [(0, len(record))]:
            out.append(record)
            continue
        pieces, names = _cut(record, runs, index)
        if not pieces:
            raise InputDataError(
                f'{record.source or f"record {index + 1}"}: the segment column marks no test '
                f'of {MIN_SAMPLES} samples or more (values > 0 mark a test, 0 the samples '
                'between tests); check the column given with --segment-column')
        out += pieces
        named += names
    if not named:
        return Tests(tuple(out), '')
    return Tests(tuple(out), (
        f'the segment column marks the tests: fitted as {len(named)} separate records (tests '
        f'of fewer than {MIN_SAMPLES} samples left out): ' + '; '.join(named)))
