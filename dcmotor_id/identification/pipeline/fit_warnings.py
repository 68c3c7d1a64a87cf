"""
Stage 10: the final fit's warnings (correlations, initial states, misfit) and the effects' pull.

How far the effects found moved the base parameters, when beyond their standard errors
(:func:`structure_shift`), and the spread between records.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from dcmotor_id.identification.checks.identifiability import (correlated_pairs,
                                                              initial_state_warnings,
                                                              misfit_warning)
from dcmotor_id.identification.error_model.residuals import output_channels, simulate_records
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.estimators.uncertainty import between_record_warnings
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs


def fit_warnings(inputs: Inputs, fit: Fit, answer: Answer) -> Answer:
    """Return the answer with the final fit's warnings and how far the effects moved the base."""
    outputs = output_channels(inputs.mechanical_only)
    warnings = answer.warnings + tuple(result_warnings(
        answer.final, answer.fitted_records, answer.terms, outputs, inputs.torque_constant,
        fit.quasi, list(answer.bound) + list(answer.upper_bounds), inputs.initial_state))
    if fit.found is not None and fit.found.effects:
        shift = structure_shift(fit.found.base_estimate, answer.parameters, answer.stderr)
        if shift:
            warnings += (shift,)
    warnings += tuple(between_record_warnings(answer.final.info.get('between_records')))
    return replace(answer, warnings=warnings)


def result_warnings(estimate, records, terms, outputs, torque_constant, quasi, skip,
                    initial_state):
    """Warnings of the final fit: correlations, initial states, misfit, current limit."""
    warnings = correlated_pairs(estimate, skip=skip)
    if initial_state == 'estimate':
        warnings += initial_state_warnings(estimate, records, outputs)
    rms = residual_rms(estimate, records, terms, outputs, torque_constant, quasi)
    misfit = misfit_warning(estimate, records, outputs, rms, torque_constant)
    if misfit:
        warnings.append(misfit)
    return warnings


def residual_rms(estimate: Estimate, records, terms, outputs, torque_constant,
                 quasi: bool) -> dict[str, float]:
    """Return the RMS of each output channel's simulation residual over all records."""
    model = OutputErrorModel(records, torque_constant, terms, quasi)
    simulated = simulate_records(model, estimate.parameters, estimate.initial_states)
    return {channel: float(np.sqrt(np.mean(np.concatenate(
        [out[channel] - getattr(rec, channel) for out, rec in zip(simulated, records)]) ** 2)))
        for channel in outputs}


def structure_shift(base: Estimate, parameters: dict[str, float],
                    stderr: dict[str, float]) -> str | None:
    """Say how far the effects found moved the base parameters, when beyond 3 stderr."""
    moved = {}
    for name in ('Ra', 'CPhi', 'J', 'b', 'Mc'):
        if name in base.parameters and np.isfinite(stderr.get(name, np.nan)) and \
                stderr[name] > 0:
            ratio = abs(parameters[name] - base.parameters[name]) / stderr[name]
            if ratio > 3.0:
                moved[name] = (_relative_change(parameters[name], base.parameters[name]), ratio)
    if not moved:
        return None
    listing = ', '.join(f'{name} {change} ({ratio:.0f} stderr)'
                        for name, (change, ratio) in moved.items())
    return (f'the effects found move the base parameters beyond their standard errors ({listing}'
            '): the structure matters more than the noise here, and the standard errors do not '
            'cover the choice of structure; compare with --no-discover')


def _relative_change(value: float, base: float) -> str:
    """Change from ``base`` to ``value`` in percent, or absolute when the base is zero."""
    if base == 0.0 or not np.isfinite(base):
        return f'{base:.3g} -> {value:.3g}'
    return f'{100.0 * (value / base - 1.0):+.3g} %'
