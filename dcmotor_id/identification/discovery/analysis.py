"""Residual analysis of a fit on a part: whiteness, predictable share, one-step errors."""

from __future__ import annotations

from typing import Any, Iterator

import numpy as np

from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Fit, join_part
from dcmotor_id.identification.error_model.criterion import noise_level
from dcmotor_id.identification.error_model.residuals import (analyse_channel, correlation_summary,
                                                             ljung_box, one_step_error,
                                                             residual_nrmse_pct)


#: Share of the residual an AR predictor must explain for structure to count as material.
MATERIAL_FRACTION = 0.05
#: Held-out error (percent of the signal spread) below which the model is exact.
NEGLIGIBLE_NRMSE_PCT = 1e-6
#: Held-out residual RMS above this multiple of the sensor noise is a misfit.
MISFIT_FACTOR = 3.0
#: Term channels the one-step error represents, and its argument for each (a ``state`` term,
#: an effect simulated inside the model, has no one-step form there).
ONE_STEP_TERMS = {'voltage': 'voltage_extra', 'torque': 'torque_extra',
                  'current': 'current_offset', 'speed': 'speed_offset'}


def _inputs(loop: LoopState, fitted: Fit, part: str) -> dict[str, np.ndarray]:
    """Return the measured input on a part: the voltage, or the current (mechanical-only)."""
    name = 'current' if loop.mechanical_only else 'voltage'
    return {name: join_part([getattr(rec, name) for rec in fitted.records], fitted.stops, part)}


def _candidate_regressors(loop: LoopState, fitted: Fit,
                          part: str) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(effect name, regressor on the part)``, one candidate at a time."""
    base = fitted.values
    for cls in loop.candidates:
        if cls.TRANSFORM:
            continue
        grid = cls.inner_grid(fitted.records, base, loop.torque_constant)
        if not grid:
            continue
        inner = grid[len(grid) // 2]
        terms = cls.terms(fitted.records, inner, base, loop.torque_constant)
        if not terms:
            continue
        joined = join_part(terms[0].regressors, fitted.stops, part)
        del terms
        if np.std(joined) > 0:
            yield cls.name, joined
        del joined


def analyse(loop: LoopState, fitted: Fit, part: str = 'heldout') -> dict[str, dict[str, Any]]:
    """
    Residual analysis of a fit on a part: per output channel (JSON-ready).

    Each channel's :func:`~dcmotor_id.identification.error_model.residuals.analyse_channel` of the
    output
    error, plus
    ``one_step_nrmse_pct``, the one-step prediction error on the same part (None when the
    structure has an effect the one-step model does not represent).  The loop decides on
    the output error alone; the one-step error is reported beside it.  The candidates'
    regressors are built and correlated one at a time (memory: one regressor at once).
    """
    inputs = _inputs(loop, fitted, part)
    one_step = one_step_errors(loop, fitted, part)
    residuals = {channel: fitted.channel_residual(channel, part) for channel in loop.outputs}
    analysis = {}
    for channel in loop.outputs:
        analysis[channel] = analyse_channel(
            residuals[channel], fitted.channel_measured(channel, part), inputs, None,
            loop.max_lag, loop.alpha)
    del inputs
    level = 1.0 - loop.alpha
    for name, regressor in _candidate_regressors(loop, fitted, part):
        for channel in loop.outputs:
            analysis[channel]['regressors'][name] = correlation_summary(
                residuals[channel], regressor, loop.max_lag, level)
    for channel in loop.outputs:
        analysis[channel]['one_step_nrmse_pct'] = one_step.get(channel)
    return analysis


def one_step_errors(loop: LoopState, fitted: Fit,
                    part: str = 'heldout') -> dict[str, float | None]:
    """
    One-step prediction error of a fit on a part, percent of the signal spread, by channel.

    :func:`~dcmotor_id.identification.error_model.residuals.one_step_error` on every record with
    the fit's
    linear
    effect terms; a prediction belongs to the part of the sample it predicts.  Empty when
    the structure has a term the one-step model does not represent.
    """
    if loop.quasi_static or any(term.channel not in ONE_STEP_TERMS
                                for term in fitted.terms):
        return {}
    values = fitted.values
    channels = [channel for channel in loop.outputs if channel != 'position']
    errors: dict[str, list[np.ndarray]] = {channel: [] for channel in channels}
    for index, rec in enumerate(fitted.records):
        extras: dict[str, Any] = {}
        for term in fitted.terms:
            key = ONE_STEP_TERMS[term.channel]
            contribution = values[term.name] * term.regressors[index]
            extras[key] = extras[key] + contribution if key in extras else contribution
        with np.errstate(all='ignore'):
            predicted = one_step_error(values, rec, loop.torque_constant, **extras)
        for channel in channels:
            errors[channel].append(predicted[channel])
    # Prediction k is of sample k + 1: the parts start one sample earlier.
    stops = [max(stop - 1, 0) for stop in fitted.stops]
    return {channel: residual_nrmse_pct(
        join_part(errors[channel], stops, part),
        join_part([getattr(rec, channel)[1:] for rec in fitted.records], stops, part))
        for channel in channels}


def misfit(loop: LoopState, fitted: Fit) -> bool:
    """Whether the held-out residual is far above the sensor noise on some channel."""
    for channel in loop.outputs:
        residual = fitted.channel_residual(channel, 'heldout')
        noise = np.sqrt(np.mean([noise_level(getattr(rec, channel)) ** 2
                                 for rec in fitted.records]))
        if residual.shape[0] and noise > 0 and \
                np.sqrt(np.mean(residual ** 2)) > MISFIT_FACTOR * noise:
            return True
    return False


def negligible(analysis: dict) -> bool:
    """Whether the held-out error is nil on every channel (the model reproduces the data)."""
    return all(item['nrmse_pct'] is not None and item['nrmse_pct'] < NEGLIGIBLE_NRMSE_PCT
               for item in analysis.values())


def explained(loop: LoopState, analysis: dict) -> bool:
    """White residual on every channel (Bonferroni over channels), or an exact model."""
    if negligible(analysis):
        return True
    level = loop.alpha / len(analysis)
    return all(item['ljung_box']['p_value'] >= level for item in analysis.values())


#: Rules under which the loop judges every round: a white held-out residual does not stop it
#: (the held-out t test is the stop; ``bench/discovery_results.md``, round 11).
JUDGED_ALWAYS = ('judged-always', 'blocked-cv')
#: Rules under which the loop stops only when the residual is white on the held-out part and
#: on the whole records (:func:`white_on_whole_records`; round 11).
WHOLE_RECORD_WHITENESS = ('whole-record-white', 'blocked-cv-white')


def white_on_whole_records(loop: LoopState, fitted: Fit) -> bool:
    """
    Whether a fit's residual over the whole records is white on every output channel.

    The Ljung-Box test (``loop.max_lag`` lags) of each channel's residual over the training
    and the held-out parts together, at ``loop.alpha`` Bonferroni over the channels, as
    :func:`explained` tests the held-out part: three times the samples, where an effect the
    held-out end shows too faintly (a one-sample speed delay) colours the residual
    (``bench/discovery_results.md``, round 11).  The fit's training part adapts to its
    residual, which can only whiten it: the test stays at or below its size.
    """
    level = loop.alpha / len(loop.outputs)
    for channel in loop.outputs:
        residual = np.concatenate([np.asarray(sim[channel] - getattr(rec, channel), dtype=float)
                                   for rec, sim in zip(fitted.records, fitted.simulated)])
        residual = residual[np.isfinite(residual)]
        if residual.shape[0] > 2 * loop.max_lag and \
                ljung_box(residual, loop.max_lag, loop.alpha)['p_value'] < level:
            return False
    return True


def stops_before_judging(loop: LoopState, fitted: Fit, analysis: dict) -> bool:
    """
    Whether the loop stops before a round: a residual that shows nothing left to judge.

    An exact model (:func:`negligible`) stops it under every rule.  Otherwise a white
    held-out residual (:func:`explained`) stops it, except under the rules of
    :data:`JUDGED_ALWAYS` (the held-out t test of every round's winner is the stop: a
    residual white at the whiteness test's lags may hold an effect that many samples
    resolve) and, under those of :data:`WHOLE_RECORD_WHITENESS`, unless the residual over the
    whole records is not white (:func:`white_on_whole_records`).  A loop that goes on judges
    its candidates by the held-out t test as ever: this test decides how often a round is
    run (its cost), that one what is added.  An empty analysis (a model without one) never
    stops it.
    """
    if not analysis:
        return False
    if negligible(analysis):
        return True
    if loop.acceptance in JUDGED_ALWAYS or not explained(loop, analysis):
        return False
    if loop.acceptance in WHOLE_RECORD_WHITENESS:
        return white_on_whole_records(loop, fitted)
    return True


def material(loop: LoopState, analysis: dict) -> bool:
    """Structure that matters: not white and at least 5 % predictable from its past."""
    if explained(loop, analysis):
        return False
    level = loop.alpha / len(analysis)
    return any(item['ljung_box']['p_value'] < level and
               item['predictable_fraction'] >= MATERIAL_FRACTION
               for item in analysis.values())
