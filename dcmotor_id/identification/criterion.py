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

from typing import Any, Callable, Sequence

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError, InputDataError

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


#: A position residual this many times its sensor noise (quantisation included) is a misfit:
#: the integral of a force the model lacks, which the position criterion spreads over the rest
#: of the record.
POSITION_MISFIT_FACTOR = 3.0
#: Differences between the position and the speed criterion's values, in their combined
#: standard errors, beyond which the two disagree.
DISAGREEMENT_Z = 2.0


def position_misfit(noise_std: dict[str, float], records: Sequence[Any]) -> float:
    """
    Return the fit's position residual over the position's sensor noise (0: not compared).

    ``noise_std`` is the fit's own (its residual level per compared channel); the sensor noise
    is :func:`~dcmotor_id.identification.identifiability.noise_level` of the positions (at
    least the quantisation's, ``LSB / sqrt(12)``).
    """
    from dcmotor_id.identification.identifiability import noise_level

    residual = noise_std.get('position')
    if residual is None or not records or any(rec.position is None for rec in records):
        return 0.0
    sensor = float(np.sqrt(np.mean([noise_level(rec.position) ** 2 for rec in records])))
    return float(residual) / max(sensor, 1e-300)


def disagreement(position: Any, speed: Any, names: Sequence[str]) -> list[str]:
    """
    Return the parameters on which two fits of the same records disagree, described.

    ``position`` and ``speed`` are identification results (``parameters``, ``stderr``,
    ``not_identifiable``).  Disagree: the values differ by more than :data:`DISAGREEMENT_Z`
    combined standard errors; a standard error that is not a number (a parameter at a bound)
    counts as zero, so a parameter the speed determines and the position leaves at its bound
    disagrees.
    """
    out = []
    for name in names:
        first, second = position.parameters.get(name), speed.parameters.get(name)
        if first is None or second is None or name in speed.not_identifiable:
            continue
        spread = np.hypot(*(np.nan_to_num(result.stderr.get(name, np.nan), nan=0.0)
                            for result in (position, speed)))
        gap = abs(first - second)
        if gap > DISAGREEMENT_Z * spread and gap > 0:
            z = gap / spread if spread > 0 else np.inf
            out.append(f'{name} {first:.4g} vs {second:.4g} ({z:.3g} stderr)')
    return out


def checked_against_speed(result: Any, refit_speed: Callable[[], Any],
                          names: Sequence[str]) -> Any:
    """
    Return the position criterion's ``result``, or the speed's when the position misfits.

    The position criterion is the maximum-likelihood one only when the model follows the
    motion: a local misfit (a start-up transient the model cannot follow, a stiction or
    amplifier limit) then shifts the integral of the speed for the rest of the record, and
    the fit bends the physical parameters to cancel that offset (a Coulomb friction traded for
    viscous friction at one speed level).  The speed criterion confines a local misfit to its
    time.  So when the position residual is far above its noise
    (:data:`POSITION_MISFIT_FACTOR`) the records are also fitted on the speed
    (``refit_speed()``); if the two fits disagree beyond their standard errors
    (:func:`disagreement`), the speed's result is kept, with a warning that says why.
    Otherwise ``result`` is returned unchanged.
    """
    ratio = position_misfit(result.noise_std, result.input_records)
    if ratio <= POSITION_MISFIT_FACTOR:
        return result
    try:
        speed = refit_speed()
    except DcMotorIdError:
        return result
    differ = disagreement(result, speed, names)
    if not differ:
        return result
    speed.warnings.insert(0, f'the fit on the position misfits ({ratio:.3g}x its sensor noise) '
                             'and disagrees with the fit on the speed derived from it ('
                             + ', '.join(differ) + '): a misfit the model cannot follow '
                             'drifts the integral of the speed, so the result is the fit on '
                             'the speed (--criterion speed; --criterion position forces the '
                             'position)')
    return speed
