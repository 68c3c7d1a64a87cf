"""
Sensor noise of a measured channel: the white noise on a smooth signal, and its floor.

Two pure functions of a numpy array, below the signal processing
(:mod:`dcmotor_id.signals.filters` re-exports :func:`noise_std`,
:mod:`dcmotor_id.identification.error_model.criterion` :func:`noise_level`) so that a
:class:`~dcmotor_id.core.records.Record` can measure its own channels once
(:meth:`~dcmotor_id.core.records.Record.noise_std`): the checks around a fit ask for the same
channel's noise about twenty times per ``identify`` call.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def noise_std(values: ArrayLike) -> float:
    """
    Robust standard deviation of white noise on a smooth signal.

    Second differences remove a smooth signal up to its curvature; for white noise of variance
    ``s^2`` they have variance ``6 s^2``.  The median absolute deviation makes the estimate
    insensitive to jumps (switching inputs, speed reversals).
    """
    values = np.asarray(values, dtype=float)
    if values.shape[0] < 5:
        return 0.0
    second = np.diff(values, 2)
    second -= np.median(second)  # in place: one N-sized temporary
    mad = np.median(np.abs(second, out=second))
    return float(mad / 0.6745 / np.sqrt(6.0))


def noise_level(values: ArrayLike, std: float | None = None) -> float:
    """
    Noise level of a channel, at least the rounding noise of a quantised signal.

    :func:`noise_std` reads zero on a quantised signal (its second differences are mostly
    zero); the quantisation step ``q`` (the small end of the nonzero differences between
    samples) gives the floor ``q / sqrt(12)``.  ``std``: :func:`noise_std` of ``values`` when
    the caller has it (else measured here).
    """
    values = np.asarray(values, dtype=float)
    level = noise_std(values) if std is None else std
    steps = np.abs(np.diff(values))
    steps = steps[steps > 0]
    if steps.shape[0]:
        level = max(level, float(np.percentile(steps, 5)) / np.sqrt(12.0))
    return level
