"""
Stage 2: the base model (no effects) fitted on all data by the estimator ``--method`` names.

Non-physical values are refused
(:func:`~dcmotor_id.identification.pipeline.fit_outcome.check_physical`).  A base with no fit
on the position starts from its fit on the speed.
"""

from __future__ import annotations

from dataclasses import replace

from dcmotor_id.core.errors import FitError, NotIdentifiableError
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.core.records import record_names
from dcmotor_id.identification.checks.identifiability import ONE_DIRECTION_CONFOUNDED
from dcmotor_id.identification.error_model.criterion import with_position_states
from dcmotor_id.identification.estimators.base import Estimate, Estimator
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.identification.pipeline.fit_outcome import physical_simulation
from dcmotor_id.identification.pipeline.state import Fit, Inputs, Models
from dcmotor_id.identification.prepare import one_level_reason, single_current_level

#: Estimators by the name the CLI's ``--method`` takes.
METHODS: dict[str, type[Estimator]] = {'refined': RefinedEstimator, 'paper': PaperEstimator}


def base_fit(inputs: Inputs) -> tuple[Inputs, Fit]:
    """
    Fit the base model on all data; return the inputs with their estimator, and the fit.

    On records in one direction only, the effects that direction confounds leave the
    vocabulary.
    """
    vocabulary = inputs.vocabulary
    if inputs.excitation.one_direction:
        vocabulary = [cls for cls in vocabulary if cls.name not in ONE_DIRECTION_CONFOUNDED]
    estimator = inputs.estimator or make_estimator(inputs.method, inputs.initial_state,
                                                   inputs.progress, inputs.criterion,
                                                   inputs.on.position_error)
    inputs = replace(inputs, vocabulary=vocabulary, estimator=estimator)
    inputs.progress.set_stage('base fit', record_names(inputs.records))
    warnings = inputs.warnings
    try:
        estimate = estimator.fit(inputs.records, torque_constant=inputs.torque_constant)
    except FitError as error:
        level = single_current_level(inputs.records) if inputs.mechanical_only else None
        if level is not None:
            raise NotIdentifiableError(one_level_reason(level, str(error))) from None
        estimate, warning = _speed_base(inputs, error)
        warnings += (warning,)
    except TimeBudgetExceeded:
        raise FitError(f'no fit finished within the time budget '
                       f'({inputs.progress.max_time_s:g} s): give more time with --max-time, '
                       'or shorten or decimate the records') from None
    _one_level_corner(inputs, estimate)
    models = Models(inputs.records, inputs.torque_constant, False, inputs.criterion)
    simulation = physical_simulation(estimate, models.measured)
    return inputs, Fit(estimate, simulation.errors, models, warnings, simulation=simulation)


def _one_level_corner(inputs: Inputs, estimate: Estimate) -> None:
    """
    Refuse a fit of one constant current in one direction that ran to b or Mc = 0.

    One current level shows two numbers in the speed (J/b and the final speed); a fit that
    ends on the bound of b or Mc took the corner where the three trade off, not an answer
    the current's fluctuations gave (its standard errors would claim one).  Records that turn
    both ways at that level (a load driving one of them back) are left to the discovery of
    the load, which separates them.
    """
    if not (inputs.mechanical_only and inputs.excitation.one_direction):
        return
    level = single_current_level(inputs.records)
    at_zero = [name for name in ('b', 'Mc') if not estimate.parameters.get(name, 1.0) > 0.0]
    if level is not None and at_zero:
        raise NotIdentifiableError(one_level_reason(
            level, f'it ran to {" and ".join(at_zero)} = 0, a corner where J, b and Mc trade '
            'off'))


def make_estimator(method: str, initial_state: str, progress: Progress,
                   criterion: str = 'speed', position_error: str = 'adaptive') -> Estimator:
    """Return the estimator named by ``method`` (the refined one with its options)."""
    if method == 'refined':
        return RefinedEstimator(initial_state=initial_state, progress=progress,
                                criterion=criterion, position_error=position_error)
    return METHODS[method]()


def _speed_base(inputs: Inputs, error: FitError) -> tuple[Estimate, str]:
    """
    Fit the base model on the speed when it has no fit on the position (else raise ``error``).

    A model that lacks the very effect the loop is there to find (a force offset on an axis
    driven both ways) may have no fit on the position: its integral drifts and the fit runs
    to an infinite inertia.  Its speed fit is the base the loop starts from
    (:func:`~dcmotor_id.identification.error_model.criterion.with_position_states`); returned with
    the
    warning that says so.
    """
    if inputs.criterion == 'speed' or not isinstance(inputs.estimator, RefinedEstimator):
        raise error
    speed = make_estimator(inputs.method, inputs.initial_state, inputs.progress)
    estimate = with_position_states(speed.fit(inputs.records,
                                              torque_constant=inputs.torque_constant),
                                    inputs.records)
    reason = str(error).split(': the motor model')[0]
    return estimate, (f'the base model (no effects) has no fit on the position ({reason}): '
                      'the effect search started from its fit on the speed')
