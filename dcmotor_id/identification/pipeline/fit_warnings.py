"""
Stage 10: what the effects found did to the base, and the spread between records.

How far the effects found moved the base parameters, when beyond their standard errors
(:func:`structure_shift`), and the spread between records.  (The final fit's correlations,
initial states and misfit are checks of the answer, run from the registry by stage 9.)
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.estimators.uncertainty import between_record_warnings
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs


def fit_warnings(inputs: Inputs, fit: Fit, answer: Answer) -> Answer:
    """Return the answer with how far the effects moved the base, and the records' spread."""
    warnings = answer.warnings
    if fit.found is not None and fit.found.effects:
        shift = structure_shift(fit.found.base_estimate, answer.parameters, answer.stderr)
        if shift:
            warnings += (shift,)
    warnings += tuple(between_record_warnings(answer.final.info.get('between_records')))
    return replace(answer, warnings=warnings)


def final_rms(answer: Answer, outputs: Sequence[str]) -> dict[str, float]:
    """Return the RMS of each output channel's simulation residual of the final fit."""
    assert answer.simulation is not None, 'the final fit stage simulates the final fit'
    return answer.simulation.residual_rms(outputs)


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
