"""
Fitting a structure: on the training parts, a candidate's refit and its problems, all the data.

:func:`fit_structure` fits on the training parts (:func:`training_stops`) and simulates the
whole records; :func:`refit_candidate` adds a candidate from its screened start (a sensor delay
by Gauss-Newton on the integer shift) and says why it is not admissible (:func:`problem`);
:func:`refit_all` and :func:`refit_all_data` refit on all of the records.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import parameter_names
from dcmotor_id.identification.checks.start import far_from_evidence, regression_evidence
from dcmotor_id.identification.discovery.parts import excited_stop
from dcmotor_id.identification.discovery.probe import fails_on_an_excerpt
from dcmotor_id.identification.discovery.screening import (base_sensitivities, delay_estimate,
                                                           projector)
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import (Candidate, Fit, slice_terms, Structure,
                                                           with_initial)
from dcmotor_id.identification.effects import SensorDelay, torque_spread
from dcmotor_id.identification.error_model.criterion import with_position_states
from dcmotor_id.identification.error_model.residuals import simulate_records
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.validate import Model, simulate

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate


#: Bound on the Jacobian evaluations of a candidate's refit (per parameter, as in
#: :class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`).
CANDIDATE_MAX_NFEV = 30


def training_stops(loop: LoopState, records: Sequence[Record]) -> list[int]:
    """
    End of every record's training part (:func:`excited_stop`).

    The held-out part carries the held-out share of the record's *excitation*, not of its
    samples: a record that ends at standstill or in a steady-speed tail would otherwise
    hold out a part where nothing happens, which cannot judge a model.
    """
    return [excited_stop(rec, loop.holdout_fraction, loop.outputs) for rec in records]


def make_estimator(loop: LoopState, **options: Any) -> RefinedEstimator:
    """Return the loop's output-error estimator (initial states, armature, criterion)."""
    return RefinedEstimator(initial_state=loop.initial_state, progress=loop.progress,
                            quasi_static=loop.quasi_static, criterion=loop.criterion,
                            position_error=loop.position_error, **options)


def fit_structure(loop: LoopState, structure: Structure, start: dict | None = None,
                  initial: dict | None = None, max_nfev: int = 100,
                  initial_states: Sequence[Sequence[float]] | None = None,
                  retry: bool = True) -> Fit:
    """
    Fit a structure on the training parts and simulate the whole records.

    ``initial_states`` (one per record, e.g. of an earlier fit) warm-start the fit's
    initial states; the training parts start where the records do.  ``retry`` false: a fit
    with effect terms that does not converge within ``max_nfev`` is not retried with more
    (a candidate's refit; the estimator's ``retry``).
    """
    records = structure.transformed(loop.records)
    stops = training_stops(loop, records)
    base = start or {}
    terms = with_initial(structure.terms(records, base, loop.torque_constant, initial),
                         initial or {})
    train = [rec.slice(0, stop) for rec, stop in zip(records, stops)]
    estimator = make_estimator(loop, max_nfev=max_nfev, initial=start or None,
                               initial_states=initial_states, position_ar=loop.position_ar,
                               retry=retry)
    if not start and terms:
        raise ValueError('a structure with effects needs a start point')
    estimate = estimator.fit(train, torque_constant=loop.torque_constant,
                             terms=slice_terms(terms, stops))
    return judged_fit(loop, structure, estimate, records, stops, terms)


def noise_weights(loop: LoopState, estimate: Estimate) -> dict[str, float]:
    """Return the loop's error weights; a fit's noise levels when the loop has none yet."""
    if loop.weights is not None:
        return dict(loop.weights)
    return {channel: max(estimate.info['noise_std'][channel], 1e-300)
            for channel in loop.outputs}


def taught(loop: LoopState, base: Fit) -> LoopState:
    """
    Return the loop with what its base fit taught it: the error weights, the position AR.

    Both are kept when the loop has them already: the base's error model warm-starts the
    candidates' fits, its noise levels weigh every fit's errors.
    """
    position_ar = loop.position_ar
    if position_ar is None:
        position_ar = base.estimate.info.get('position_ar')
    return replace(loop, weights=noise_weights(loop, base.estimate), position_ar=position_ar)


def judged_fit(loop: LoopState, structure: Structure, estimate: Estimate,
               records: list[Record], stops: list[int], terms: tuple) -> Fit:
    """Simulate a fit's whole records and cost its training and held-out parts."""
    model = OutputErrorModel(records, loop.torque_constant, terms, loop.quasi_static,
                             loop.criterion)
    simulated = simulate_records(model, estimate.parameters, estimate.initial_states)
    if loop.criterion != 'speed' and len(structure) and not loop.quasi_static:
        simulated = open_loop_outputs(structure, estimate, records, loop.torque_constant)
    fitted = Fit(structure, estimate, records, stops, simulated, terms)
    if loop.weights is None:  # the loop's first fit: weighed by its own noise levels
        loop = replace(loop, weights=noise_weights(loop, estimate))
    fitted.train_cost = cost(loop, fitted, 'train')
    fitted.heldout_cost = cost(loop, fitted, 'heldout')
    fitted.n_train = int(sum(stops)) * len(loop.outputs)
    return fitted


def cost(loop: LoopState, fitted: Fit, part: str) -> float:
    """Weighted mean squared simulation error of a fit on a part, summed over the outputs."""
    total = 0.0
    for channel in loop.outputs:
        error = fitted.channel_residual(channel, part)
        value = float(np.mean(error ** 2)) / loop.fitted_weights[channel] ** 2
        total += value if np.isfinite(value) else np.inf
    return total


def base_start(loop: LoopState, fitted: Fit) -> dict[str, float]:
    """Start of a refit from a fit's base values (:func:`refit_start`)."""
    return refit_start(fitted.values, loop.records, loop.torque_constant)


def try_candidate(loop: LoopState, current: Fit, cls: type[Effect], inner: dict,
                  start_terms: dict) -> Fit | None:
    """
    Refit the structure with a candidate from the screen's start; return the Fit or None.

    The screen's start is a linearisation at the current fit: from a poor base it can
    overshoot so far that the refit does not converge, so a failed refit is tried once
    more from the candidate's own neutral start (its terms at their defaults).  A costly
    refit on many records is first tried on an excerpt of them
    (:func:`~dcmotor_id.identification.discovery.probe.fails_on_an_excerpt`).
    """
    structure = current.structure.plus(cls, inner)
    fitted, initial = None, dict(current.values)
    starts: tuple[dict, ...] = (start_terms, {}) if start_terms else ({},)
    initials = [{**current.values, **terms} for terms in starts]
    if fails_on_an_excerpt(loop, current, structure, base_start(loop, current), initials,
                           _try_from):
        initials = []
    for initial in initials:
        fitted = _try_from(loop, structure, base_start(loop, current), initial,
                           current.estimate.initial_states)
        if fitted is not None:
            break
    if loop.anchor is None or len(current.structure):
        return fitted
    # The position criterion: the integral of a model that lacks an effect drifts, and
    # its fit may end far from the physical values (EMPS without its force offset: the
    # mass doubles, the Coulomb friction vanishes).  The candidate is also fitted from the
    # speed-criterion values; the lower training cost wins (a fit's local minimum, not a
    # selection: the held-out part is not looked at).  Only from the base model: once an
    # effect is in, the fit starts from a model that follows the position.
    anchored = _try_from(loop, structure, base_start(loop, loop.anchor), {
        **initial, **{name: value for name, value in loop.anchor.values.items()
                      if name in loop.anchor.estimate.parameters}}, None)
    return min((fit for fit in (fitted, anchored) if fit is not None),
               key=lambda fit: fit.train_cost, default=None)


def _try_from(loop: LoopState, structure: Structure, start: dict, initial: dict,
              initial_states: Sequence[Sequence[float]] | None) -> Fit | None:
    """Fit a structure from a start point; None when the fit fails."""
    try:
        with np.errstate(all='ignore'):  # a wild candidate may overflow; it is scored
            return fit_structure(loop, structure, start=start, initial=initial,
                                 max_nfev=CANDIDATE_MAX_NFEV, initial_states=initial_states,
                                 retry=False)
    except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None


def anchor_fit(loop: LoopState) -> Fit | None:
    """Fit the base model on the speed (training parts) when the criterion is not the speed."""
    if loop.criterion == 'speed':
        return None
    speed = LoopState(loop.records, loop.torque_constant, loop.candidates,
                      loop.holdout_fraction, progress=loop.progress,
                      initial_state=loop.initial_state, quasi_static=loop.quasi_static)
    try:
        return fit_structure(speed, Structure())
    except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None


def base_unsound(loop: LoopState, base: Fit) -> bool:
    """
    Whether a base fit's J or b lies beyond the start check's factor from the regression.

    :func:`~dcmotor_id.identification.checks.start.regression_evidence`: a base on the
    position that lacks a force offset can run to an inertia or a friction many times the
    data's (an axis driven both ways: b 1e10 N m s/rad), a basin no effect screen recovers
    from.
    """
    evidence = regression_evidence(loop.records, loop.torque_constant)
    return bool(far_from_evidence(base.values, evidence))


def speed_base_on_the_position(loop: LoopState) -> tuple[LoopState, Fit] | None:
    """
    Fit the base model on the speed, judged on the position; None when that fails too.

    A base model that lacks the very effect the loop is there to find (a force offset on an
    axis driven both ways) may have no fit on the position at all: its integral drifts, and
    the fit runs to an infinite inertia.  The speed fit of the same model is sound; the loop
    starts from it, and its candidates are fitted on the position.  Returns the loop with
    the speed fit as its anchor and its weights, and the base.
    """
    anchor = anchor_fit(loop)
    if anchor is None:
        return None
    records = list(loop.records)
    estimate = with_position_states(anchor.estimate, records)
    base = judged_fit(loop, Structure(), estimate, records, training_stops(loop, records), ())
    loop = replace(loop, anchor=anchor, weights=noise_weights(loop, estimate))
    null = null_refit(loop, base)
    if null is not None:
        base.info['null_refit'] = null
    return loop, base


def null_refit(loop: LoopState, current: Fit) -> Fit | None:
    """
    Refit the current structure on the loop's criterion as a candidate is; None if it fails.

    A candidate's refit (:func:`try_candidate`) fits the position from the current fit's
    values (friction lifted off zero, :func:`refit_start`) and from the anchor's.  When the
    current fit is not a fit of the position (the base fitted on the speed,
    :func:`speed_base_on_the_position`), every candidate would gain by that refit alone, the
    effect or not: on one voltage step from rest logged by an encoder angle, cogging,
    current offset and brush drop gained 96-98 % of the held-out error, within 0.05 % of
    each other.  This fit, with the same starts, evaluations and criterion and no effect, is
    the null model a candidate is judged against (:func:`judging_reference`).
    """
    fits = [_try_from(loop, current.structure, base_start(loop, current),
                      dict(current.values), current.estimate.initial_states)]
    if loop.anchor is not None:
        fits.append(_try_from(loop, current.structure, base_start(loop, loop.anchor),
                              dict(loop.anchor.values), None))
    found = [fit for fit in fits if fit is not None and np.isfinite(fit.heldout_cost)]
    return min(found, key=lambda fit: fit.train_cost, default=None)


def judging_reference(current: Fit) -> Fit:
    """Return the fit a candidate's held-out gain is measured from: the null refit, or it."""
    null = current.info.get('null_refit')
    return current if null is None else null


def refit_candidate(loop: LoopState, current: Fit, candidate: Candidate) -> Candidate:
    """
    Refit all parameters with the candidate added; return it with its fit and problem.

    A data effect whose screened inner parameters are already not admissible (an early
    sensor: a negative delay, which the Gauss-Newton on the integer shift moved further on
    twelve HSM150 records, -56 to -203 samples, four refits) is not refitted: its problem
    is said as it is.
    """
    if candidate.effect.TRANSFORM:
        reason = candidate.effect.from_fit({}, candidate.inner).problem({}, loop.records)
        if reason:
            return replace(candidate, problem=f'{reason} (by the screen, not refitted)')
        fitted = _refit_delay(loop, current, candidate.inner['channel'],
                              candidate.inner['samples'])
    else:
        fitted = try_candidate(loop, current, candidate.effect, candidate.inner, candidate.start)
    if fitted is None or not np.isfinite(fitted.heldout_cost):
        return candidate
    return replace(candidate, fit=fitted, inner=fitted.structure.items[-1][1],
                   problem=problem(loop, current, fitted))


def problem(loop: LoopState, current: Fit, fitted: Fit) -> str | None:
    """Why a candidate's fit is not acceptable (physics, collapse), or None."""
    effect = fitted.structure.effects(fitted.values)[-1]
    reason = effect.problem(fitted.values, fitted.records)
    if reason:
        return reason
    floor = friction_floors(current.values, loop.records, loop.torque_constant)
    for name in ('b', 'Mc'):
        before, after = current.values[name], fitted.values[name]
        # A friction already at zero cannot collapse (it was 5e-193 in a lab record).
        if before > 0.05 * floor[name] and after < 0.01 * before:
            return (f'{name} collapses from {before:.4g} to {after:.3g}: the candidate '
                    'takes over the base friction instead of adding to it')
    return None


def _refit_delay(loop: LoopState, current: Fit, channel: str, samples: int) -> Fit | None:
    """Gauss-Newton on the integer delay: shift, refit, re-estimate the remainder."""
    fitted = None
    tried = set()
    for _ in range(4):
        if samples == 0 or samples in tried:
            break
        tried.add(samples)
        attempt = try_candidate(loop, current, SensorDelay,
                                {'channel': channel, 'samples': samples}, {})
        if attempt is None:
            break
        if fitted is not None and attempt.train_cost >= fitted.train_cost:
            break
        fitted = attempt
        res, matrix, nom = base_sensitivities(loop, fitted)
        _, more = delay_estimate(loop, fitted, channel, res, projector(matrix), nom)
        step = int(np.round(more))
        if step == 0:
            break
        samples += step
    return fitted


def refit_all(loop: LoopState, fitted: Fit) -> tuple[list[Record], tuple, Estimate]:
    """Refit a structure on all the data (no hold-out), from the training values."""
    return refit_all_data(fitted.structure, loop.records, loop.torque_constant,
                          fitted.values, base_start(loop, fitted), progress=loop.progress,
                          initial_states=fitted.estimate.initial_states,
                          initial_state=loop.initial_state,
                          quasi_static=loop.quasi_static, criterion=loop.criterion,
                          position_ar=loop.position_ar, position_error=loop.position_error)


def open_loop_outputs(structure: Structure, estimate: Estimate, records: Sequence[Record],
                      torque_constant: float | None = None) -> list[dict[str, np.ndarray]]:
    """
    Simulate a fitted structure open loop, as ``dcmotor-id validate`` does; per record.

    The fit's effect terms are regressors of *measured* signals (the speed's magnitude, the
    measured position's angle), which on the held-out part would feed the measurement into
    the prediction; here every effect is driven by the simulated state
    (:func:`dcmotor_id.identification.validate.simulate`), so that a candidate is judged as
    the model will be used.  The position starts at the fitted initial position.
    """
    values = estimate.parameters
    effects = [{'name': effect.name, 'parameters': dict(effect.parameters)}
               for effect in structure.effects(values) if not type(effect).TRANSFORM]
    mechanical = torque_constant is not None
    model = Model({name: float(values[name]) for name in parameter_names(mechanical)},
                  'mechanical' if mechanical else 'full', torque_constant, effects)
    n_dynamic = 1 if mechanical else 2
    outputs = []
    for rec, state in zip(records, estimate.initial_states):
        with np.errstate(all='ignore'):
            out = simulate(model, rec, np.asarray(state[:n_dynamic], dtype=float))
        if len(state) > n_dynamic and rec.position is not None:
            out['position'] = out['position'] + (float(state[n_dynamic]) - float(rec.position[0]))
        outputs.append(out)
    return outputs


def refit_start(values: dict, records: Sequence[Record],
                torque_constant: float | None = None) -> dict[str, float]:
    """
    Start point of a refit: the fitted base values, with b and Mc lifted off zero.

    The fit works on logarithms, so a friction that a missing effect drove to zero would
    stay there; a floor of 2 % of the driving torque's spread lets it come back.
    """
    names = [name for name in parameter_names(torque_constant is not None) if name in values]
    start = {name: float(values[name]) for name in names}
    floors = friction_floors(start, records, torque_constant)
    start['Mc'] = max(start['Mc'], floors['Mc'])
    start['b'] = max(start['b'], floors['b'])
    return start


def friction_floors(values: dict, records: Sequence[Record],
                    torque_constant: float | None = None) -> dict[str, float]:
    """Return the least start of Mc and b in a refit: 2 % of the driving torque's spread."""
    spread = torque_spread(records, values, torque_constant)
    speed = max(float(np.std(np.concatenate([rec.speed for rec in records]))), 1e-12)
    return {'Mc': 0.02 * spread, 'b': 0.02 * spread / speed}


def refit_all_data(structure: Structure, records: Sequence[Record],
                   torque_constant: float | None, values: dict, start: dict,
                   **options: Any) -> tuple[list[Record], tuple, Estimate]:
    """
    Fit a structure on all of the records (no hold-out).

    The effects' coefficients start from ``values``, the base parameters from ``start``
    (:func:`refit_start`); return the (transformed) records, the terms and the estimate.
    ``options`` go to the :class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`.
    """
    prepared = structure.transformed(records)
    terms = with_initial(structure.terms(prepared, values, torque_constant), values)
    estimator = RefinedEstimator(initial=start, **options)
    return prepared, terms, estimator.fit(prepared, torque_constant=torque_constant,
                                          terms=terms)
