"""
Isolated dropouts and outliers of the measured channels, found, named and repaired.

A current sensor that drops single samples to 0 (or to 1e-300) among good ones biased Ra by
35 % and was taken for an amplifier current limit (issue 21).  A dropout or a spike is one
sample far off both its neighbours while the neighbours agree with each other: the second
difference ``x[k-1] - 2 x[k] + x[k+1]`` is large at ``k`` and the neighbours differ by little
against it (a step of the signal moves the neighbours apart; a spike does not).  Such samples
of the measured outputs (current, speed) are replaced by the mean of their neighbours, and
every repair is reported by channel, count and first place, so the fit runs without them.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from dcmotor_id.core.checks import Check, register
from dcmotor_id.core.records import Record

#: Channels searched (the measured outputs; the voltage is the commanded input).
CHANNELS = ('current', 'speed')
#: A spike is this many robust noise levels of the second difference...
NOISE_FACTOR = 40.0
#: ... and at least this share of the channel's 99th percentile of magnitude.
LEVEL_SHARE = 0.05

__all__ = ['find_isolated', 'repair_dropouts']


def find_isolated(values: np.ndarray,
                  guard: np.ndarray | Sequence[np.ndarray | None] | None = None) -> np.ndarray:
    """
    Return the indices of isolated samples far off both neighbours that agree.

    Parameters
    ----------
    values : numpy.ndarray
        One channel.
    guard : numpy.ndarray or sequence of them, optional
        Other channels (the voltage; the other measured output): a sample where one of them
        also jumps is left alone.  A one-sample pulse of the input moves the output
        legitimately, and so does a current that spins the shaft up within a sample or two
        (a step from rest on a motor as fast as the sample rate): the speed bends there too,
        where a sensor's glitch leaves it smooth.

    """
    x = np.asarray(values, dtype=float)
    if x.size < 5:
        return np.array([], dtype=int)
    second = x[:-2] - 2.0 * x[1:-1] + x[2:]
    spread = x[2:] - x[:-2]
    noise = 1.4826 * float(np.median(np.abs(second))) / np.sqrt(6.0)
    level = float(np.percentile(np.abs(x), 99))
    threshold = max(NOISE_FACTOR * noise, LEVEL_SHARE * level, 1e-300)
    candidates = (np.abs(second) > threshold) & (np.abs(spread) < 0.25 * np.abs(second))
    guards = [guard] if isinstance(guard, np.ndarray) else list(guard or [])
    for other in guards:
        if other is not None:
            candidates &= _quiet_around(np.asarray(other, dtype=float))
    return np.flatnonzero(candidates) + 1


def _quiet_around(channel: np.ndarray) -> np.ndarray:
    """Return, per inner sample, whether ``channel`` does not jump at it or its neighbours."""
    second = np.abs(channel[:-2] - 2.0 * channel[1:-1] + channel[2:])
    level = max(float(np.percentile(np.abs(channel), 99)), 1e-300)
    quiet = second < LEVEL_SHARE * level
    return quiet & np.roll(quiet, 1) & np.roll(quiet, -1)


def repair_dropouts(record: Record) -> tuple[Record, list[str]]:
    """
    Replace isolated dropouts and spikes of the current and speed by their neighbours' mean.

    Returns the record (the same object when nothing was found) and one warning per channel
    repaired, naming the channel, the count and the first sample.
    """
    notes: list[str] = []
    changes = {}
    for channel in CHANNELS:
        values = getattr(record, channel, None)
        if values is None:
            continue
        other = getattr(record, 'speed' if channel == 'current' else 'current', None)
        found = find_isolated(values, [record.voltage, other])
        if found.size == 0:
            continue
        x = np.array(values, dtype=float)
        first = int(found[0])
        before = float(x[first])
        x[found] = 0.5 * (x[found - 1] + x[found + 1])
        changes[channel] = x
        zeros = int(np.sum(np.abs(np.asarray(values)[found]) <= 1e-12 * max(
            float(np.percentile(np.abs(values), 99)), 1e-300)))
        kind = 'dropout(s) to zero' if zeros == found.size else (
            'outlier(s)' if zeros == 0 else f'dropout(s) or outlier(s) ({zeros} to zero)')
        notes.append(
            f'{record.source or "record"}: the {channel} has {found.size} isolated {kind} '
            f'(single samples far off both neighbours, the first at sample {first}, t = '
            f'{float(record.time_s[first]):.4g} s: {before:.4g} between {x[first - 1]:.4g} and '
            f'{x[first + 1]:.4g}); they were replaced by the mean of their neighbours before '
            'the fit: check the sensor and its wiring')
    if not changes:
        return record, notes
    return record.replace(**changes), notes


def repair_all(records: Sequence[Record]) -> tuple[list[Record], list[str]]:
    """Apply :func:`repair_dropouts` to every record; return them and all warnings."""
    repaired, notes = [], []
    for record in records:
        fixed, found = repair_dropouts(record)
        repaired.append(fixed)
        notes += found
    return repaired, notes


register(Check('dropouts', 'before_fit', 'records', repair_all,
               'isolated dropouts and spikes of the current and speed, repaired and named'))
