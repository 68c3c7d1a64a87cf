"""The training and held-out parts of a record: the held-out part carries its share of motion."""

from __future__ import annotations

from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.error_model.criterion import noise_level

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record


#: Share of each record held out for selection.
HOLDOUT_FRACTION = 0.3


#: Blocks of the excitation measure of :func:`excited_stop`.
EXCITATION_BLOCKS = 200
#: Bounds of the training part as shares of the moving extent: enough to fit (a record of
#: two steps keeps part of the second level to train on), enough to judge.
TRAIN_SHARE_BOUNDS = (0.6, 0.85)


def excited_stop(record: Record, holdout_fraction: float = HOLDOUT_FRACTION,
                 channels: Sequence[str] = ('speed',)) -> int:
    """
    End of a record's training part: the rest carries the held-out share of its excitation.

    Within the moving extent (:func:`moving_extent`) the excitation is the change of each
    channel's block means beyond their noise (:data:`EXCITATION_BLOCKS` blocks; standstill and
    steady speed add nothing), each channel normalised to its total.  The training part ends
    at the last block boundary before which at most ``1 - holdout_fraction`` of it lies,
    within :data:`TRAIN_SHARE_BOUNDS` of the moving extent; without measurable excitation,
    at ``1 - holdout_fraction`` of the extent.
    """
    first, last = moving_extent(np.asarray(record.speed, dtype=float),
                                record.noise_std('speed'))
    size = last - first
    fallback = first + size * (1.0 - holdout_fraction)
    blocks = min(EXCITATION_BLOCKS, size // 5)
    stop = fallback
    if blocks >= 4:
        edges = np.linspace(0, size, blocks + 1).astype(int)
        weight = np.zeros(blocks - 1)
        for channel in channels:
            values = np.asarray(getattr(record, channel), dtype=float)[first:last]
            means = np.add.reduceat(values, edges[:-1]) / np.diff(edges)
            # The record's own level when the extent is the whole record (measured once).
            level = record.noise_level(channel) if (first, last) == (0, len(record)) \
                else noise_level(values)
            floor = 4.0 * level * np.sqrt(2.0 / max(int(np.min(np.diff(edges))), 1))
            change = np.abs(np.diff(means))
            change[change <= floor] = 0.0
            if change.sum() > 0:
                weight += change / change.sum()
        if weight.sum() > 0:
            share = np.cumsum(weight) / weight.sum()
            below = np.flatnonzero(share <= 1.0 - holdout_fraction)
            stop = first + (edges[int(below[-1]) + 1] if below.shape[0] else edges[1])
    low, high = TRAIN_SHARE_BOUNDS
    stop = min(max(stop, first + low * size), first + high * size)
    return min(max(int(round(stop)), 1), len(record) - 1)


def moving_extent(speed: np.ndarray, noise: float | None = None) -> tuple[int, int]:
    """
    Return the first and one past the last sample where a speed moves beyond its noise.

    The whole record when it never leaves the noise band (the caller decides then).
    ``noise``: the speed's :func:`~dcmotor_id.signals.filters.noise_std` when the caller has
    it (a record's :meth:`~dcmotor_id.core.records.Record.noise_std`; else measured here).
    """
    from dcmotor_id.signals.filters import low_pass, noise_std

    speed = np.asarray(speed, dtype=float)
    smooth = low_pass(speed, 0.05, order=2)
    noise = noise_std(speed) if noise is None else noise
    level = max(min(10.0 * noise, 0.2 * float(np.max(np.abs(smooth)))), 1e-300)
    moving = np.flatnonzero(np.abs(smooth - smooth[0]) > level)
    if moving.shape[0] < 2:
        return 0, speed.shape[0]
    # Keep a little standstill after the motion ends: the stop is part of the dynamics.
    margin = max(speed.shape[0] // 50, 1)
    return 0, min(int(moving[-1]) + 1 + margin, speed.shape[0])
