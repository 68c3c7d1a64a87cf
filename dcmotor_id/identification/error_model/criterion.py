"""
The fit criterion: which measured channels the output-error fit compares with the simulation.

``speed``: the current (unless mechanical-only) and the speed, as before.  ``position``: the
current and the position, the integral of the simulated speed from an estimated initial
position (:func:`integrate_speed`); the speed is not compared (it was derived from the
position, so its noise and filter lag are the position's).  ``both``: current, speed and
position.  Each compared channel is weighted by its own noise level (re-estimated from its
residual).  ``auto`` (the default of ``identify``) picks ``position`` when every record has a
position and some speed was derived from it, else ``speed`` (a measured speed keeps the speed
criterion: ``both`` finds the same effects on simulated records with a measured speed and an
exact angle, but the residual analysis reads the position's drift as structure left over,
and it costs about three times the time, so it is only used when asked for).

The position error's model (:data:`POSITION_ERROR_MODELS`, an argument of the refined
estimator and of :func:`position_ar`): ``white`` weights the position
sample by sample by its sensor noise, which is what an open-loop validation scores.
``adaptive`` (the estimators' default) models a position residual far above the position's
noise (:data:`POSITION_MISFIT_FACTOR`) as AR(1) (:func:`position_ar`, :func:`whiten`): such a
residual is the integral of a force the model lacks, it drifts, and weighted as white it can
make the fit bend the physical parameters to cancel an offset a local misfit left; the AR(1)
model weights the error's increments for a drift.  ``identify`` chooses between the two
against model-free evidence (:mod:`~dcmotor_id.identification.pipeline.position_error`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.noise import noise_level

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
#: Largest AR(1) coefficient of the position's error model (a random walk is its limit).
MAX_POSITION_AR = 1.0 - 1e-9
#: Refits beyond the usual passes while the AR(1) coefficient of the position error moves.
AR_PASSES = 4
#: Models of the position error (:func:`check_position_error_model`).
POSITION_ERROR_MODELS = ('adaptive', 'white')


def check_position_error_model(model: str) -> str:
    """
    Return ``model`` when it names a model of the position error, else raise ``ValueError``.

    ``adaptive`` (the default): AR(1) when the residual misfits (:func:`position_ar`);
    ``white``: the sensor's noise only, whatever the residual.
    """
    if model not in POSITION_ERROR_MODELS:
        raise ValueError(f'position error model must be one of {POSITION_ERROR_MODELS}, '
                         f'not {model!r}')
    return model


def whiten(error: np.ndarray, rho: float) -> np.ndarray:
    """
    Return the AR(1)-whitened ``error`` (along the first axis; Prais-Winsten).

    ``e'[0] = sqrt(1 - rho^2) e[0]``, ``e'[k] = e[k] - rho e[k - 1]``: white when ``e`` is an
    AR(1) sequence with coefficient ``rho`` (``rho = 0``: ``error`` itself, not copied).  The
    same rule applies to the rows of the error's sensitivities.
    """
    if rho == 0.0:
        return error
    out = np.empty_like(error)
    out[0] = np.sqrt(1.0 - rho * rho) * error[0]
    out[1:] = error[1:] - rho * error[:-1]
    return out


def position_ar(error: np.ndarray, sensor_noise: float, model: str = 'adaptive') -> float:
    """
    Return the AR(1) coefficient of a position residual that misfits, else 0.

    A residual within :data:`POSITION_MISFIT_FACTOR` of the sensor noise is the sensor's
    (white: the position is compared sample by sample).  Beyond it the model lacks something
    (a friction varying along the travel, a transient it cannot follow), and the position
    error is the integral of that missing force: it drifts.  Weighting such an error as
    white makes the fit bend the physical parameters to cancel an offset that a local misfit
    left for the rest of the record; its AR(1) model (coefficient near 1 for a drift) weights
    the error's increments instead, as the maximum-likelihood fit under that error does.
    Always 0 under the ``white`` model of the position error (``model``,
    :func:`check_position_error_model`).
    """
    error = np.asarray(error, dtype=float)
    if check_position_error_model(model) == 'white':
        return 0.0
    if error.shape[0] < 3 or np.sqrt(np.mean(error ** 2)) <= POSITION_MISFIT_FACTOR * max(
            sensor_noise, 0.0):
        return 0.0
    lagged = float(error[:-1] @ error[:-1])
    if lagged <= 0.0:
        return 0.0
    return float(np.clip(float(error[1:] @ error[:-1]) / lagged, 0.0, MAX_POSITION_AR))


def ar_settled(old: float, new: float) -> bool:
    """Whether an AR(1) coefficient has settled: ``1 - rho`` moved by under 25 %."""
    if old == new:
        return True
    if old <= 0.0 or new <= 0.0:
        return False
    return abs(np.log((1.0 - new) / (1.0 - old))) <= 0.25


def with_position_states(estimate: Any, records: Sequence[Any]) -> Any:
    """
    Return a fit on the speed as one on the position: each record's first position appended.

    The base model fitted on the speed, to be judged on the position (the initial position
    is the first sample, the position's noise its sensor's); ``info['base_from']`` says so.
    """
    states = [tuple(state) + (float(rec.position[0]),)
              for state, rec in zip(estimate.initial_states, records)]
    noise = float(np.sqrt(np.mean([noise_level(rec.position) ** 2 for rec in records])))
    info = {**estimate.info, 'noise_std': {**estimate.info.get('noise_std', {}),
                                           'position': noise},
            'base_from': 'the speed fit (the base model cannot follow the position)'}
    return replace(estimate, initial_states=states, info=info)
