"""
The pipeline's control flow: the stages in order, the criterion, the position error's model.

:func:`identify_checked` runs one identification: on the resolved criterion
(:func:`~dcmotor_id.identification.error_model.criterion.resolve_criterion`), falling back to the
speed when the fit on the position fails under ``--criterion auto``; a refusal names a channel
that looks reversed.  One run (:func:`identify_with`) is :func:`begin` (stages 1-4, or the
current-limited path) then :func:`~dcmotor_id.identification.pipeline.stages.finish` (stages
5-12), each stage a function of the frozen state
(:mod:`~dcmotor_id.identification.pipeline.state`).  On the position the white and the
adaptive (AR(1)) model of the position error are chosen between as data and branches
(:func:`on_the_position`), the decisions in
:mod:`~dcmotor_id.identification.pipeline.position_error`.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from dcmotor_id.core.errors import DcMotorIdError, FitError, InputDataError, NotIdentifiableError
from dcmotor_id.identification.checks.units import sign_problem
from dcmotor_id.identification.error_model.criterion import resolve_criterion
from dcmotor_id.identification.pipeline.armature import armature
from dcmotor_id.identification.pipeline.base_fit import base_fit
from dcmotor_id.identification.pipeline.current_limited import (electrical_part,
                                                                with_electrical_part)
from dcmotor_id.identification.pipeline.position_error import (adaptive_after_white_failed,
                                                               adaptive_agreeing, ADAPTIVE_RUN,
                                                               after_a_far_white,
                                                               after_a_far_white_base,
                                                               white_base_far, white_if_agreeing,
                                                               WHITE_RUN_RESUMED)
from dcmotor_id.identification.pipeline.prepare import current_limit, prepare
from dcmotor_id.identification.pipeline.stages import attempt as _attempt, Begun, finish
from dcmotor_id.identification.pipeline.start_check import check_base_start
from dcmotor_id.identification.pipeline.state import Request, RunOn
from dcmotor_id.identification.result import IdentificationResult


def identify_checked(criterion: str, request: Request) -> IdentificationResult:
    """Run :func:`identify_on`; a refusal names a channel that looks reversed, if one does."""
    try:
        return identify_on(criterion, request)
    except FitError as error:
        found = None if 'time budget' in str(error) else sign_problem(request.records,
                                                                      request.torque_constant)
        if found is None:
            raise
        raise FitError(f'{str(error).rstrip(".")}. {found[0].upper()}{found[1:]}') from None


def identify_on(criterion: str, request: Request) -> IdentificationResult:
    """
    Run the pipeline on the resolved criterion; ``auto`` falls back to the speed.

    On the position, the position error's model is chosen against model-free evidence
    (:func:`on_the_position`).
    """
    resolved = criterion_of(request.records, criterion, request.method, request.estimator)
    try:
        if resolved == 'speed' or request.method != 'refined' or request.estimator is not None:
            return identify_with(request, RunOn(resolved))
        return on_the_position(request, resolved)
    except (FitError, NotIdentifiableError) as error:
        if criterion != 'auto' or resolved == 'speed' or 'time budget' in str(error):
            raise
        return _on_the_speed(request, error)


def criterion_of(records, criterion: str, method: str, estimator: Any) -> str:
    """Return the criterion the fit uses: resolved for the refined method, else speed."""
    resolved = resolve_criterion(records, criterion)
    if estimator is not None:
        return getattr(estimator, 'criterion', 'speed')
    if method != 'refined':
        if criterion not in ('auto', 'speed'):
            raise InputDataError(f'--criterion {criterion} needs the refined method (the '
                                 f'{method} method fits the speed)')
        return 'speed'
    return resolved


def _on_the_speed(request: Request, error: DcMotorIdError) -> IdentificationResult:
    """Identify on the speed after the fit on the position failed (``--criterion auto``)."""
    # The position integrates every force the model lacks over the whole record: a base
    # model that cannot follow it (a load the loop did not find) is refused there, and
    # ``auto`` falls back to the speed, as before the position criterion.
    found = identify_with(request, RunOn('speed'))
    reason = str(error).split('. Check')[0].split('. Use')[0]
    found.warnings.insert(0, f'the fit on the position failed ({reason}): the integral '
                             'of a force the model lacks drifts over the record (the loop '
                             'looks for it unless --no-discover); the result is the fit '
                             'on the speed (--criterion speed)')
    return found


def identify_with(request: Request, on: RunOn) -> IdentificationResult:
    """Run the stages in order on one criterion and model of the position error."""
    begun = begin(request, on)
    return begun if isinstance(begun, IdentificationResult) else finish(begun)


def begin(request: Request, on: RunOn) -> Begun | IdentificationResult:
    """
    Run stages 1-4: prepare, base fit, armature, start check.

    A drive at an amplifier's current limit takes its own path to a result
    (:mod:`~dcmotor_id.identification.pipeline.current_limited`: the electrical part off the
    limit, :func:`~dcmotor_id.identification.pipeline.current_limited.electrical_part`; the
    mechanical part identified as in the mechanical-only mode;
    :func:`~dcmotor_id.identification.pipeline.current_limited.with_electrical_part`).
    """
    inputs = prepare(request, on)
    limited = current_limit(inputs)
    if limited is not None:
        # The model has no current limit: the electrical part off the limit, then the
        # mechanical part as in the mechanical-only mode, with the measured current and that
        # CPhi as the torque constant.
        values, robust = electrical_part(inputs.records, limited)
        mechanical = identify_checked('auto', Request(
            inputs.records, 'refined', values['CPhi'], inputs.discover, None,
            inputs.vocabulary, inputs.progress, inputs.initial_state))
        return replace(with_electrical_part(mechanical, values, robust, inputs.records,
                                            inputs.progress), criterion='speed')
    inputs, fit = base_fit(inputs)
    fit = armature(inputs, fit)
    return Begun(inputs, check_base_start(inputs, fit))


def on_the_position(request: Request, criterion: str) -> IdentificationResult:
    """
    Identify on the position with the white error model, else the adaptive one (AR(1)).

    The white run is left after its start check when its base contradicts the regression
    (:func:`~dcmotor_id.identification.pipeline.position_error.white_base_far`): the adaptive
    run comes first, and the white run is finished from its state only when that one
    disagrees too.  A white result that disagrees (or fails) runs the adaptive model; the
    result closer to the evidence is kept.  The runs share the further starts of the base
    (the first run's account, ``earlier``); the status line names each run after the first
    (``RunOn.name``).
    """
    try:
        begun = _attempt(begin, request, RunOn(criterion, 'white'))
        earlier = begun.fit.starts if isinstance(begun, Begun) else None
        adaptive = RunOn(criterion, 'adaptive', earlier, ADAPTIVE_RUN)
        if isinstance(begun, Begun):
            inputs = begun.inputs
            left = white_base_far(begun.fit.estimate.parameters, inputs.records,
                                  inputs.torque_constant, inputs.evidence)
            if left is not None:
                return _adaptive_first(request, adaptive, begun, left)
        white = _attempt(finish, begun) if isinstance(begun, Begun) else begun
        if isinstance(white, DcMotorIdError):
            return adaptive_after_white_failed(identify_with(request, adaptive), white)
        kept = white_if_agreeing(white)
        if kept is not None:
            return kept
        return after_a_far_white(white, _attempt(identify_with, request, adaptive,
                                                 budget_too=True))
    finally:
        request.progress.set_run('')  # a later identification on the Progress starts unnamed


def _adaptive_first(request: Request, adaptive: RunOn, white: Begun, left) -> Any:
    """Run the adaptive model after a white base that disagrees; finish the white if needed."""
    found = _attempt(identify_with, request, adaptive, budget_too=True)
    found = found if isinstance(found, IdentificationResult) else None
    agreeing = adaptive_agreeing(found, left)
    if agreeing is not None:
        return agreeing
    return after_a_far_white_base(found, _attempt(finish, replace(white,
                                                                  name=WHITE_RUN_RESUMED)))
