"""
Stages 7 and 8: the final fit, refused when it does not reproduce the data; its uncertainty.

The final fit is the loop's, else the base.  Its standard errors are data-based
(:func:`~dcmotor_id.identification.estimators.uncertainty.with_robust_stderr`); under the
quasi-static armature La is given by its upper bound
(:func:`~dcmotor_id.identification.pipeline.armature.with_la_bound`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import DERIVED_NAMES, MECHANICAL_NAMES, PARAMETER_NAMES
from dcmotor_id.core.records import Record
from dcmotor_id.identification.error_model.residuals import simulated, Simulation
from dcmotor_id.identification.estimators.uncertainty import with_robust_stderr
from dcmotor_id.identification.pipeline.armature import la_reason, with_la_bound
from dcmotor_id.identification.pipeline.fit_outcome import NO_FIT_NRMSE_PCT
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs, Models


def final_fit(inputs: Inputs, fit: Fit) -> Answer:
    """
    Return the final fit (the loop's, else the base); refuse it when it does not fit.

    Its simulation over the records travels in the answer: the later stages measure it there
    (the base fit's, ``fit.simulation``, when the final fit is the base).
    """
    final, terms, fitted_records = fit.estimate, (), list(inputs.records)
    if fit.found is not None:
        final, terms, fitted_records = fit.found.estimate, fit.found.terms, fit.found.records
    model = Models(fitted_records, inputs.torque_constant, fit.quasi, terms=tuple(terms))
    simulation = simulated(model.measured, final.parameters, final.initial_states,
                           fit.simulation)
    judged, said = refusal_errors(simulation)
    worst = max(value for value in judged.values() if value is not None) \
        if any(value is not None for value in judged.values()) else float('inf')
    if not np.isfinite(worst) or worst > NO_FIT_NRMSE_PCT:
        raise FitError(
            f'the identified model does not reproduce the data (simulation error {worst:.3g} % '
            'of the signal spread). ' + _likely_unit(inputs.records) + 'Check that the '
            'columns are what their names say (units, signs) and that the data come from a DC '
            'motor drive.')
    return Answer(final, terms, fitted_records, fit.warnings + said, dict(fit.not_identifiable),
                  simulation=simulation)


def _likely_unit(records: Sequence[Record]) -> str:
    """Name a position in degrees read as radians (it wraps at 360), or nothing."""
    # Imported here: only a refusal needs it, and the formats package loads its readers.
    from dcmotor_id.formats.quality import degrees_wrap

    for rec in records:
        if rec.position is not None and rec.speed_derived:
            found = degrees_wrap(rec.position)
            if found is not None:
                return (f'{rec.source or "The record"}: {found}, read here as radians: pass '
                        '--position-unit deg. ')
    return ''


def refusal_errors(simulation: Simulation) -> tuple[dict[str, float | None], tuple[str, ...]]:
    """
    Return the simulation errors the refusal judges, and a warning when they differ.

    A speed derived from the position is judged over the sample periods
    (:meth:`~dcmotor_id.identification.error_model.residuals.Simulation.period_mean_speed_error`):
    its low-pass smooths a motion as fast as the sample rate, and the model that reproduces
    the position would be refused for the filter's lag.  The warning says so when the derived
    speed's own error is beyond the refusal's limit.
    """
    errors = dict(simulation.errors)
    over_periods = simulation.period_mean_speed_error()
    derived = errors.get('speed_nrmse_pct')
    if over_periods is None or derived is None:
        return errors, ()
    errors['speed_nrmse_pct'] = over_periods
    if derived <= NO_FIT_NRMSE_PCT:
        return errors, ()
    return errors, (
        f'the speed derived from the position is smoother than the motion (its simulation '
        f'error is {derived:.3g} %, the mean speed over each sample period, from the '
        f"position's increments, {over_periods:.3g} %): the motion is faster than the "
        'differentiating low-pass; give a higher --speed-cutoff (below the Nyquist frequency) '
        'to see the speed, or sample faster',)


def uncertainty(inputs: Inputs, fit: Fit, answer: Answer) -> Answer:
    """Return the answer with data-based standard errors; La by its upper bound if quasi-static."""
    final = with_robust_stderr(answer.final)
    stderr_model = dict(final.info.get('stderr_model', final.stderr))
    upper_bounds, not_identifiable = dict(answer.upper_bounds), dict(answer.not_identifiable)
    if fit.quasi and fit.full_la is not None:
        dt = inputs.records[0].sample_period_s
        final, upper_bounds = with_la_bound(final, *fit.full_la, dt)
        stderr_model = dict(final.info['stderr_model'])
        not_identifiable['La'] = la_reason(*fit.full_la, dt, upper_bounds['La'])
    names = MECHANICAL_NAMES if inputs.mechanical_only else PARAMETER_NAMES + DERIVED_NAMES
    stderr = {name: float(final.stderr.get(name, np.nan)) for name in names}
    of_model = {name: float(stderr_model.get(name, np.nan)) for name in names}
    for name in upper_bounds:
        stderr[name] = of_model[name] = float('nan')
    return replace(answer, final=final, names=tuple(names),
                   parameters={name: float(final.parameters[name]) for name in names},
                   stderr=stderr, stderr_model=of_model, upper_bounds=upper_bounds,
                   not_identifiable=not_identifiable)
