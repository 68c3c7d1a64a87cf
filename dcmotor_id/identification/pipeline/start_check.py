"""
Stages 4 and 6, the start check: the base, then where discovery led, against model-free evidence.

A base fit that misfits far above the noise or lies far from the evidence is fitted again
from further starts, the best kept
(:func:`~dcmotor_id.identification.pipeline.further_starts.several_starts`).  A base in a
wrong basin misleads the effect screen; when a second start explains the data better it is
the base, and it ran its own discovery
(:func:`~dcmotor_id.identification.pipeline.second_start.check_start`).  When the base looked
sound, where discovery led is checked the same way (:func:`check_final_start`).
"""

from __future__ import annotations

from dataclasses import replace

from dcmotor_id.identification.error_model.residuals import model_errors
from dcmotor_id.identification.pipeline.discovery import time_warnings
from dcmotor_id.identification.pipeline.further_starts import (ambiguity_warning,
                                                               several_starts, with_starts)
from dcmotor_id.identification.pipeline.second_start import check_start, start_warning
from dcmotor_id.identification.pipeline.state import Fit, Inputs


def check_base_start(inputs: Inputs, fit: Fit) -> Fit:
    """Return the fit with its base checked against model-free evidence before the loop."""
    if not inputs.checkable:
        return fit
    estimate, starts = several_starts(fit.estimate, fit.models, inputs.progress,
                                      inputs.evidence, inputs.on.earlier,
                                      inputs.on.position_error, fit.simulation)
    started = estimate
    found, estimate, info, check = check_start(inputs, replace(fit, estimate=estimate))
    first = check['chosen'] == 'first start'
    # The errors of the base the loop starts from, measured once: the second start's, or the
    # further starts' when one of them won, or the base fit's as they were.
    errors = fit.errors
    if not first or (starts is not None and starts['chosen'] != 'default'):
        chosen = started if first else estimate
        errors = model_errors(fit.models.measured, dict(chosen.parameters),
                              chosen.initial_states)
    fit = replace(fit, estimate=estimate, starts=starts, errors=errors, found=found,
                  discovery_info=info)
    if first:
        return replace(fit, start_check=None if not check['doubts'] else check)
    return replace(fit, start_check=check,
                   warnings=fit.warnings + time_warnings(found, info, inputs.progress))


def check_final_start(inputs: Inputs, fit: Fit) -> Fit:
    """Return the fit with where discovery led checked (when the base looked sound), said."""
    warnings = fit.warnings
    if inputs.checkable and fit.start_check is None:
        found, estimate, info, start_check = check_start(inputs, fit)
        if found is not fit.found:  # the second start's own loop
            warnings += time_warnings(found, info, inputs.progress)
        fit = replace(fit, found=found, estimate=estimate, discovery_info=info,
                      start_check=start_check)
    account = with_starts(fit.start_check, fit.starts)
    warnings += tuple(warning for warning in (start_warning(account),
                                              ambiguity_warning(fit.starts))
                      if warning is not None)
    return replace(fit, start_check=account, warnings=warnings)
