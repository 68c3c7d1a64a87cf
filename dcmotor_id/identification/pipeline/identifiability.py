"""
Stage 9: what the data do not determine, and the registered checks of the answer.

One direction only, parameters at a bound, an inertia the samples do not resolve
(:mod:`~dcmotor_id.identification.checks.inertia`), loose ones
(:mod:`~dcmotor_id.identification.checks.identifiability`); then every check of the answer
in the registry (:func:`~dcmotor_id.identification.checks.answer.answer_warnings`: the
answer against the data's own scales, units, refused when nothing useful is left,
correlations, initial states, misfit).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from dcmotor_id.core.model import POSITIVE_NAMES
from dcmotor_id.identification.checks.answer import answer_warnings, FinalFit
from dcmotor_id.identification.checks.armature_profile import (armature_profile,
                                                               armature_reason)
from dcmotor_id.identification.checks.identifiability import (at_bound, loose,
                                                              one_direction_note)
from dcmotor_id.identification.checks.inertia import (inertia_half_range, inertia_reason,
                                                      inertia_unresolved, one_level_range,
                                                      one_level_reason)
from dcmotor_id.identification.checks.inertia_profile import (inertia_profile, profile_needed,
                                                              profile_reason, ProfileSpec,
                                                              rejected_reason, shared_la)
from dcmotor_id.identification.error_model.residuals import output_channels
from dcmotor_id.identification.estimators.refined import RefinedEstimator
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
    inertia: str | None = None
    profiles: dict[str, Any] = {}  # J's (and La's) likelihood profiles, for the final fit's info
    if 'J' not in not_identifiable and inputs.mechanical_only:
        inertia = unresolved_inertia(inputs, answer, stderr)
    elif 'J' not in not_identifiable:
        inertia, profiles = unsettled_inertia(inputs, answer, stderr, not_identifiable)
    checked = [name for name in answer.names if name not in not_identifiable and name not in
               answer.upper_bounds and name not in ('Ka',) and not (name == 'J' and inertia)]
    not_identifiable.update(loose(final, [name for name in checked if name in POSITIVE_NAMES
                                          or name == 'Ta']))
    assert answer.simulation is not None, 'the final fit stage simulates the final fit'
    warnings = answer.warnings + answer_warnings(FinalFit(
        final, inputs.records, answer.fitted_records, inputs.torque_constant,
        inputs.initial_state, answer.simulation.residual_rms(output_channels(
            inputs.mechanical_only)), not_identifiable, list(bound) + list(answer.upper_bounds),
        list(parameters)))
    if inertia is not None:  # b and Mc from the steady speeds stay useful: said after the checks
        not_identifiable['J'] = inertia
        warnings += (inertia,)
        if (profiles.get('armature_profile') or {}).get('unresolved'):
            warnings += (not_identifiable['La'],)  # La's profile: La shares J's lag
    elif 'J' not in not_identifiable:
        warnings += one_level_inertia(inputs, answer, stderr)
    if profiles:
        final = replace(final, info={**final.info, **profiles})
    return replace(answer, final=final, bound=bound, not_identifiable=not_identifiable,
                   stderr=stderr, combined=combined, warnings=warnings)


def unresolved_inertia(inputs: Inputs, answer: Answer, stderr: dict[str, float]) -> str | None:
    """
    Say why J is not determined when the current is the input and the speed settles in a sample.

    The test of :func:`~dcmotor_id.identification.checks.inertia.inertia_half_range`; J's
    standard error in ``stderr`` is raised to the half range at its upper bound.  None: the
    full model (the voltage is the input), no measured speed, or J resolved.
    """
    if not inputs.mechanical_only or not answer.fitted_records:
        return None
    constant = inputs.torque_constant or 1.0
    half = inertia_half_range(answer.fitted_records, answer.parameters['b'] / constant)
    if half is None or not inertia_unresolved(half):
        return None
    j = answer.parameters['J']
    stderr['J'] = max(stderr['J'], half.upper * abs(j))
    return inertia_reason(half, answer.fitted_records[0].sample_period_s, constant, j,
                          stderr['J'])


def unsettled_inertia(inputs: Inputs, answer: Answer, stderr: dict[str, float],
                      not_identifiable: dict[str, str]) -> tuple[str | None, dict[str, Any]]:
    """
    Say why J is not determined when the voltage is the input and the lags settle in a sample.

    The likelihood-ratio test on J's profile
    (:func:`~dcmotor_id.identification.checks.inertia_profile.inertia_profile`), computed
    when the fitted model's slowest time constant is below two sample periods; J's standard
    error in ``stderr`` is raised to reach the profile's upper bound.  La, when J is not
    determined, is tested by its own profile at the same level (:func:`unsettled_armature`).
    Returns the reason (None: J resolved, the profile not needed, or the estimator not the
    refined one) and the profiles computed, by their key in the final fit's ``info``
    (``inertia_profile``, ``armature_profile``).
    """
    final = answer.final
    quasi = bool(final.info.get('quasi_static'))
    dt = answer.fitted_records[0].sample_period_s if answer.fitted_records else 0.0
    if not isinstance(inputs.estimator, RefinedEstimator) or not answer.fitted_records or \
            not profile_needed(final.parameters, quasi, dt):
        return None, {}
    inputs.progress.set_stage("J's likelihood profile")
    estimator = inputs.estimator
    spec = ProfileSpec(answer.fitted_records, tuple(answer.terms), quasi, estimator.criterion,
                       estimator.position_error, estimator.initial_state, inputs.progress)
    profile = inertia_profile(spec, final)
    if profile is None:
        return None, {}
    profiles: dict[str, Any] = {'inertia_profile': profile.as_dict()}
    j = answer.parameters['J']
    if not profile.unresolved:
        if not profile.fitted_rejected:
            return None, profiles
        low, high = profile.accepted
        stderr['J'] = max(stderr['J'], j - low, high - j)
        return rejected_reason(profile, j, stderr['J']), profiles
    stderr['J'] = max(stderr['J'], profile.bound - j) if profile.bound is not None \
        else float('nan')
    if not quasi:
        inputs.progress.set_stage("La's likelihood profile")
        la, armature = unsettled_armature(spec, answer, stderr)
        if armature is not None:
            profiles['armature_profile'] = armature
        la = la or shared_la(profile, answer.parameters, stderr)
        if la is not None:
            not_identifiable['La'] = la
    return profile_reason(profile, dt, j, stderr['J']), profiles


def unsettled_armature(spec: ProfileSpec, answer: Answer, stderr: dict[str, float]
                       ) -> tuple[str | None, dict[str, Any] | None]:
    """
    Say why La is not determined when J is not and La's profile accepts a settled La.

    :func:`~dcmotor_id.identification.checks.armature_profile.armature_profile`: La's and Ta's
    standard errors in ``stderr`` are raised to reach the profile's bound.  Returns the reason
    (None: La determined, or no profile) and the profile's figures (None: not computed).
    """
    profile = armature_profile(spec, answer.final)
    if profile is None:
        return None, None
    if not profile.unresolved:
        return None, profile.as_dict()
    return armature_reason(profile, answer.parameters, stderr), profile.as_dict()


def one_level_inertia(inputs: Inputs, answer: Answer, stderr: dict[str, float]) -> tuple:
    """
    Say J's range when one voltage level in one direction leaves the friction's split open.

    :func:`~dcmotor_id.identification.checks.inertia.one_level_range`; J's standard error in
    ``stderr`` is raised to reach the farther end of the range.  Empty: the mechanical mode
    (the current is the input), or the voltage takes more than one level or both directions.
    """
    if inputs.mechanical_only or not answer.fitted_records:
        return ()
    span = one_level_range(answer.fitted_records, answer.parameters)
    if span is None:
        return ()
    j = answer.parameters['J']
    stderr['J'] = max(stderr['J'], abs(span.high - j), abs(j - span.low))
    return (one_level_reason(span, j, stderr['J']),)
