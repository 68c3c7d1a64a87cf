"""
The fit criterion: which measured channels the output-error fit compares with the simulation.

``speed``: the current (unless mechanical-only) and the speed, as before.  ``position``: the
current and the position, the integral of the simulated speed from an estimated initial
position (:func:`integrate_speed`); the speed is not compared (it was derived from the
position, so its noise and filter lag are the position's).  ``both``: current, speed and
position.  Each compared channel is weighted by its own noise level (re-estimated from its
residual).  ``auto`` (the default of ``identify``) picks ``position`` when every record has a
position and some speed was derived from it, else ``speed`` (a measured speed keeps the speed
criterion: ``both`` on simulated records with speed, position and a Stribeck friction missed
the friction in the discovery loop, so it is only used when asked for).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from dcmotor_id.core.errors import InputDataError

#: Choices of ``--criterion``.
CRITERIA = ('auto', 'speed', 'position', 'both')


def resolve_criterion(records: Sequence[Any], criterion: str = 'auto') -> str:
    """
    Return the criterion a fit of ``records`` uses: ``speed``, ``position`` or ``both``.

    Raises
    ------
    InputDataError
        An unknown criterion, or ``position`` / ``both`` asked for a record without position.

    """
    if criterion not in CRITERIA:
        raise InputDataError(f'unknown criterion {criterion!r}; choose one of '
                             f'{", ".join(CRITERIA)}')
    has_position = bool(records) and all(rec.position is not None for rec in records)
    if criterion == 'auto':
        if not has_position:
            return 'speed'
        derived = any(getattr(rec, 'speed_derived', False) for rec in records)
        return 'position' if derived else 'speed'
    if criterion != 'speed' and not has_position:
        missing = next(rec for rec in records if rec.position is None)
        raise InputDataError(
            f'{missing.source or "a record"}: --criterion {criterion} needs a position channel, '
            'and this record has none: name its column with --column position=NAME, or use '
            '--criterion speed')
    return criterion


def fitted_outputs(mechanical_only: bool, criterion: str = 'speed') -> tuple[str, ...]:
    """Return the channels the fit compares, in order (the electrical one first)."""
    dynamic = ('speed',) if mechanical_only else ('current', 'speed')
    if criterion == 'speed':
        return dynamic
    if criterion == 'position':
        return dynamic[:-1] + ('position',)
    if criterion == 'both':
        return dynamic + ('position',)
    raise ValueError(f'criterion must be speed, position or both, not {criterion!r}')


def integrate_speed(speed: np.ndarray, sample_period_s: float,
                    initial_position: float = 0.0) -> np.ndarray:
    """
    Return the position: the trapezoidal running integral of the sampled speed.

    ``p[0] = p0``, ``p[k + 1] = p[k] + dt (w[k] + w[k + 1]) / 2``; the same rule integrates
    the speed sensitivities (along the first axis of a 2-D array) into the position's.
    """
    speed = np.asarray(speed, dtype=float)
    out = np.empty_like(speed)
    out[0] = initial_position
    np.cumsum(0.5 * sample_period_s * (speed[:-1] + speed[1:]), axis=0, out=out[1:])
    out[1:] += initial_position
    return out
