"""Judging on the held-out parts: the noise of a candidate's gain; never worse than the base."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from dcmotor_id.identification.discovery.structure import Fit


#: Contiguous blocks of the held-out part whose error drops give the noise of the gain.
HELDOUT_BLOCKS = 8
#: Standard errors of the held-out drop a candidate's gain must exceed.
GAIN_NOISE_FACTOR = 2.0


def heldout_gain_noise(current: Fit, candidate: Fit, outputs: Sequence[str],
                       weights: dict[str, float]) -> float:
    """
    Noise of a candidate's relative held-out gain: two standard errors of the error drop.

    The weighted squared held-out errors of both fits (the held-out cost's terms) are
    subtracted sample by sample and summed over :data:`HELDOUT_BLOCKS` contiguous blocks;
    the blocks' spread gives the standard error of the total drop (blocks far longer than the
    residual's correlation are nearly independent; shorter ones make it conservative).
    Returns ``GAIN_NOISE_FACTOR`` times it relative to the current held-out cost (``inf``
    when it cannot be computed).
    """
    drop = None
    for channel in outputs:
        before = current.channel_residual(channel, 'heldout')
        after = candidate.channel_residual(channel, 'heldout')
        # A data effect (a sensor delay) shifts the records by a few samples: the common end.
        common = min(before.shape[0], after.shape[0])
        before, after = before[before.shape[0] - common:], after[after.shape[0] - common:]
        if common < 2 * HELDOUT_BLOCKS:
            return float('inf')
        term = (before ** 2 - after ** 2) / (max(weights.get(channel, 1.0), 1e-300) ** 2
                                             * before.shape[0])
        drop = term if drop is None else drop + term
    if drop is None or not np.all(np.isfinite(drop)) or current.heldout_cost <= 0.0:
        return float('inf')
    sums = np.array([part.sum() for part in np.array_split(drop, HELDOUT_BLOCKS)])
    stderr = float(np.sqrt(HELDOUT_BLOCKS) * np.std(sums, ddof=1))
    return GAIN_NOISE_FACTOR * stderr / current.heldout_cost


def never_worse(base: Fit, final: Fit, reason: str) -> tuple[Fit, str]:
    """Return the final structure, or the base one when it is not better on the held-out part."""
    if final is base or final.heldout_cost < base.heldout_cost:
        return final, reason
    return base, (reason + '; the effects found did not lower the held-out error of the base '
                  'model, which is kept')
