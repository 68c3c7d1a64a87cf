"""
Held samples: a sensor that refreshes slower than the log, each value repeated on later rows.

A logger at 1 kHz reading sensors that refresh at about 500 Hz writes every value on two rows
(sometimes one or three as the phases drift).  The repeated rows are not measurements: fitted
as they are, they act as a varying delay of up to a refresh period, which the model explains
with a wrong inductance or not at all.  :func:`held_channels` recognises such channels (runs
of exactly equal values of nearly constant length, whose successive values are not steps of
a quantiser), and :func:`restore_held` keeps the first row of each run (a real update) and
interpolates the held rows linearly between those updates, so the fit sees the samples that
are real.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from dcmotor_id.core.records import Record

#: Channels that are measured (the voltage is the input: a held step is a real input).
MEASURED = ('current', 'speed')
#: Fewest runs of equal values a channel must have to be judged.
MIN_RUNS = 50
#: Largest share of runs of a single row in a held channel.
SINGLE_SHARE = 0.2
#: Smallest share of distinct steps between successive run values (a quantiser has few).
DISTINCT_SHARE = 0.5
#: Longest typical hold (rows) restored; longer runs are standstill or a dead sensor.
MAX_HOLD = 10


def _runs(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the first row and the length of every run of exactly equal values."""
    change = np.flatnonzero(np.diff(values) != 0.0) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [values.shape[0]]]))
    return starts, lengths


def hold_length(values: np.ndarray) -> Optional[float]:
    """
    Return the mean number of rows a value is held for, or None for a channel not held.

    Held: at least :data:`MIN_RUNS` runs, most longer than one row (at most
    :data:`SINGLE_SHARE` single rows), a typical length of 2 to :data:`MAX_HOLD` rows, and
    successive values that differ by many distinct amounts (not the steps of a quantiser).
    """
    values = np.asarray(values, dtype=float)
    if values.shape[0] < 2 * MIN_RUNS or not np.all(np.isfinite(values)):
        return None
    starts, lengths = _runs(values)
    if starts.shape[0] < MIN_RUNS:
        return None
    typical = float(np.median(lengths))
    if not 2 <= typical <= MAX_HOLD or np.mean(lengths == 1) > SINGLE_SHARE:
        return None
    steps = np.abs(np.diff(values[starts]))
    distinct = np.unique(np.round(steps / max(float(np.max(steps)), 1e-300), 9)).shape[0]
    if distinct < DISTINCT_SHARE * steps.shape[0]:
        return None
    short = lengths[lengths <= MAX_HOLD]
    return float(np.mean(short)) if short.size else typical


def held_channels(record: Record) -> dict[str, float]:
    """Return measured channel -> mean rows a value is held for, for the held channels."""
    out = {}
    for name in MEASURED:
        values = getattr(record, name)
        if values is None:
            continue
        rows = hold_length(values)
        if rows is not None:
            out[name] = rows
    return out


def restore(values: np.ndarray) -> np.ndarray:
    """
    Return a held channel with its held rows interpolated between the real updates.

    Each value is placed at the first row it appears on, half a row early (it was measured
    at some instant since the row before); runs longer than :data:`MAX_HOLD` rows (the
    shaft at rest, a constant current) are kept as they are.
    """
    values = np.asarray(values, dtype=float)
    starts, lengths = _runs(values)
    rows = np.arange(values.shape[0], dtype=float)
    # a long run is real: the sensor reads the same value; keep both of its ends
    ends = (starts + lengths - 1)[lengths > MAX_HOLD]
    anchors = np.concatenate([np.maximum(starts - 0.5, 0.0), ends.astype(float)])
    anchor_values = np.concatenate([values[starts], values[ends]])
    order = np.argsort(anchors, kind='stable')
    return np.interp(rows, anchors[order], anchor_values[order])


def restore_held(records: list[Record]) -> tuple[list[Record], list[str]]:
    """
    Return the records with held channels restored, and a warning naming each.

    Records without held channels are returned as they are.
    """
    out, warnings = [], []
    for record in records:
        held = held_channels(record)
        if not held:
            out.append(record)
            continue
        out.append(record.replace(**{name: restore(getattr(record, name)) for name in held}))
        period = record.sample_period_s
        described = ', '.join(
            f"'{name}' (each value on {rows:.2g} rows: the sensor refreshes about every "
            f'{rows * period:.3g} s)' for name, rows in held.items())
        warnings.append(
            f"{record.source or 'record'}: held samples in {described}: the repeated rows are "
            'not measurements, so the fit used the real updates only (the held rows '
            'interpolated between them). Log at the sensor refresh rate, or read the sensors '
            "on the logger's clock, to avoid it")
    return out, warnings
