"""
Stage 9: what the data do not determine, and the answer against the data's own scales.

One direction only, parameters at a bound, loose ones
(:mod:`~dcmotor_id.identification.checks.identifiability`); plausibility
(:mod:`~dcmotor_id.identification.checks.plausibility`) and units
(:mod:`~dcmotor_id.identification.checks.units`); refused when nothing useful is left.
"""

from __future__ import annotations

from dataclasses import replace

from dcmotor_id.core.errors import NotIdentifiableError
from dcmotor_id.core.model import POSITIVE_NAMES
from dcmotor_id.identification.checks.identifiability import (at_bound, loose,
                                                              one_direction_note, useful)
from dcmotor_id.identification.checks.plausibility import check_plausibility
from dcmotor_id.identification.checks.units import unit_warnings
from dcmotor_id.identification.pipeline.state import Answer, Inputs


def identifiability(inputs: Inputs, answer: Answer) -> Answer:
    """Return the answer with what the data do not determine; refuse when nothing is useful."""
    final, parameters = answer.final, answer.parameters
    not_identifiable, stderr = dict(answer.not_identifiable), dict(answer.stderr)
    combined = dict(answer.combined)
    bound = at_bound(final, answer.fitted_records, inputs.torque_constant)
    if inputs.excitation.one_direction:
        note = one_direction_note(inputs.excitation, parameters['Mc'])
        not_identifiable['Mc'] = note
        not_identifiable['load_torque'] = note
        combined['friction_torque_Nm'] = {
            'value': parameters['Mc'], 'stderr': stderr['Mc'],
            'direction': inputs.excitation.direction, 'of': ['Mc', 'load_torque']}
        bound.pop('Mc', None)
    for name, reason in bound.items():
        not_identifiable[name] = reason
        stderr[name] = float('nan')
    checked = [name for name in answer.names if name not in not_identifiable and name not in
               answer.upper_bounds and name not in ('Ka',)]
    not_identifiable.update(loose(final, [name for name in checked if name in POSITIVE_NAMES
                                          or name == 'Ta']))
    # Orders of magnitude against the data's own scales: refused there, else warnings (the
    # parameters already said to be at a bound are not repeated).
    warnings = answer.warnings + tuple(
        text for text in check_plausibility(final.parameters, final.stderr, inputs.records,
                                            inputs.torque_constant)
        if not any(text.startswith(f'{name} = ') for name in not_identifiable))
    warnings += tuple(unit_warnings(final.parameters, inputs.records, inputs.mechanical_only))
    if not useful(list(parameters), not_identifiable, inputs.mechanical_only):
        raise NotIdentifiableError(
            'nothing useful is identifiable from these data: '
            + '; '.join(f'{name}: {reason}' for name, reason in not_identifiable.items())
            + '. Use a richer excitation (faster changes for La, larger speed changes for J) '
            'or a longer record.')
    return replace(answer, bound=bound, not_identifiable=not_identifiable, stderr=stderr,
                   combined=combined, warnings=warnings)
