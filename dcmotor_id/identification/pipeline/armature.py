"""
Stage 3, the armature: La below what the data resolve makes the quasi-static armature the model.

When the electrical time constant La/Ra is below the sample period, or La is undetermined
(:func:`la_unresolved`), the model is refitted with the quasi-static armature
(:func:`quasi_static_fit`), and kept unless its current simulation error is much worse than
the full fit's (:func:`quasi_kept`; the likelihood ratio of the two equations on the
current's effective samples, :func:`full_resolved`, is the measured alternative,
:data:`ARMATURE_CHOICES`).  Kept, it is the model of everything that follows, and the final
estimate gives La by its upper bound (:func:`with_la_bound`) with the reason
(:func:`la_reason`).  The data do not decide between the two equations (a speed averaged over
the sample passes for La as well as a real La does), so the standard errors of the parameters
both fit cover the difference between their fits (:func:`with_structure_stderr`), and a
warning names those it dominates (:func:`structure_warning`).  :func:`armature` is the stage
(3), and :func:`structure_stderr` the standard errors' part of it (after stage 10, the
checks).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import derived_values, parameter_names
from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.checks.identifiability import IDENTIFIABLE_REL_STDERR
from dcmotor_id.identification.checks.start import correlation_time
from dcmotor_id.identification.discovery.judging import HELDOUT_ALPHA
from dcmotor_id.identification.error_model.residuals import model_errors, simulate_records
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.identification.estimators.uncertainty import with_robust_stderr
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs, Models

if TYPE_CHECKING:
    from dcmotor_id.identification.error_model.residuals import ChannelErrors
    from dcmotor_id.identification.estimators.base import Estimate


#: How the quasi-static refit is kept or not (:func:`quasi_kept`'s ``choice``): by the margin on
#: its current simulation error (what the stage uses), or by the likelihood ratio of the full
#: equation (:func:`full_resolved`).  Measured side by side by ``bench/bench_armature_choice.py``
#: (``bench/armature_results.md``, wave 10): the ratio resolves a La of a fifth of a sample in
#: the current (the simulator is exact) and keeps the full equation on 39 of 150 records whose
#: La/Ra is below the sample period where the margin kept the quasi-static one (issue 29 asks
#: for the static form and La's upper bound there), and slows the run after it (+29 % on the
#: random motors); not what the stage uses.
ARMATURE_CHOICES = ('current-error-margin', 'likelihood-ratio')
#: The margin of ``current-error-margin``: the refit's current error at most ``factor`` times
#: the full fit's plus ``points`` percentage points.
QUASI_MARGIN = (1.25, 0.5)
#: The parameters both armature equations fit (quasi-static and full).
SHARED_NAMES = ('Ra', 'CPhi', 'J', 'b', 'Mc')
#: What the account of the standard errors says when they cover the armature's choice.
STRUCTURE_METHOD = ("; Ra, CPhi, J, b, Mc: at least the full armature equation's own, with "
                    "the difference between its fit and the quasi-static one's (the data do "
                    'not decide between them)')


def armature(inputs: Inputs, fit: Fit) -> Fit:
    """
    Return the fit with La first: the quasi-static armature when the data cannot resolve La.

    Kept (:func:`quasi_kept`), the quasi-static armature is the model of everything
    that follows (discovery included); refused, La is said not identifiable.
    """
    if inputs.mechanical_only or not isinstance(inputs.estimator, RefinedEstimator):
        return fit
    dt = inputs.records[0].sample_period_s
    robust = with_robust_stderr(fit.estimate)
    full_la = (robust.parameters['La'], robust.stderr['La'], robust.parameters['Ra'])
    fit = replace(fit, full_la=full_la)
    if not la_unresolved(*full_la, dt):
        return fit
    models = replace(fit.models, quasi_static=True)
    refit = quasi_static_fit(fit.estimate, models, inputs.initial_state, inputs.progress,
                             inputs.on.position_error)
    if refit is None or not quasi_kept(fit, refit, models, inputs.initial_state):
        return replace(fit, not_identifiable={**fit.not_identifiable,
                                              'La': la_reason(*full_la, dt, None)})
    estimate, errors = refit
    full = fit.estimate
    if not full_reached_its_limit(fit.errors, errors) or beyond_its_bound(full, estimate, dt):
        # The full fit ran off (an La of 1e4 H, its current 100 % off) where its own limit
        # La -> 0 fits the data, or its La lies beyond the upper bound the answer gives La:
        # its values are no equation the data leave open.  The full equation with La at its
        # upper bound is one (:func:`la_at_its_bound`).
        bounded = la_at_its_bound(estimate, fit.models, dt, inputs)
        if bounded is None:
            return replace(fit, estimate=estimate, quasi=True, errors=errors, models=models)
        full, robust = bounded, with_robust_stderr(bounded)
    return replace(fit, estimate=estimate, quasi=True, errors=errors, models=models,
                   structure_spread=structure_spread(full, estimate),
                   full_stderr={name: float(robust.stderr[name]) for name in SHARED_NAMES
                                if name in robust.stderr})


def la_at_its_bound(quasi: Estimate, full_models: Models, dt: float,
                    inputs: Inputs) -> Estimate | None:
    """
    Fit the full armature equation with La pinned at its upper bound ``Ra dt``; None if it fails.

    Where the free full fit did not converge, or its La lies beyond that bound
    (:func:`beyond_its_bound`), this is the other end of what the data leave open (La between
    0 and its bound; the bound from the quasi-static refit ``quasi``).  It
    starts from the estimator's own search: the refit's values can hold b or Mc at exactly 0,
    which the search of positive parameters (on their logarithms) cannot leave.
    """
    bound = float(quasi.parameters['Ra']) * dt
    inputs.progress.set_stage('full armature with La at its upper bound')
    try:
        return refined_fit(full_models, inputs.initial_state, inputs.progress,
                           inputs.on.position_error, pinned={'La': bound})
    except (DcMotorIdError, np.linalg.LinAlgError, ValueError):
        return None


def beyond_its_bound(full: Estimate, quasi: Estimate, dt: float) -> bool:
    """
    Whether the full fit's La lies beyond the upper bound the answer gives La.

    The bound of :func:`with_la_bound`: ``Ra dt`` of the quasi-static refit, or the full fit's
    ``La + 2 stderr`` where its La/Ra is below the sample period.  A full fit beyond it (a
    spin-up at one voltage level after a start ramp is cut leaves La free to trade with Ra:
    ``Ra - La / tau_m`` is what the current holds) is not an equation the answer leaves open,
    and covering it would widen Ra's error by ``La / (Ra tau_m)`` for an La the answer rules
    out.
    """
    la, ra_full = float(full.parameters['La']), abs(float(full.parameters['Ra']))
    return not (la < ra_full * dt or la <= float(quasi.parameters['Ra']) * dt)


def full_reached_its_limit(full: ChannelErrors, quasi: ChannelErrors) -> bool:
    """
    Whether the full fit's current is not far worse than the quasi-static refit's.

    The quasi-static equation is the full one's limit La -> 0, so a full fit at its optimum
    fits at least as well; one whose current simulation error exceeds the refit's beyond the
    margin the refit is kept by (:data:`QUASI_MARGIN`, the other way round) did not converge.
    """
    factor, points = QUASI_MARGIN
    full_current = full.get('current_nrmse_pct')
    quasi_current = quasi.get('current_nrmse_pct')
    if full_current is None or quasi_current is None:
        return True
    return bool(full_current <= factor * quasi_current + points)


def la_unresolved(la: float, la_stderr: float, ra: float, dt: float) -> bool:
    """Whether La is below what the sample period resolves, or undetermined."""
    return bool(la / ra < dt or la_stderr > IDENTIFIABLE_REL_STDERR * la)


def quasi_kept(fit: Fit, refit: tuple[Estimate, ChannelErrors], quasi_models: Models,
               initial_state: str, choice: str = 'current-error-margin') -> bool:
    """
    Whether the quasi-static refit is kept, by ``choice`` (one of :data:`ARMATURE_CHOICES`).

    ``current-error-margin``: its current simulation error is at most 25 % (and 0.5 points)
    worse than the full model's (:data:`QUASI_MARGIN`); ``likelihood-ratio``: the full
    equation does not fit the current significantly better (:func:`full_resolved`).
    """
    if choice == 'likelihood-ratio':
        return not full_resolved(fit, refit[0], quasi_models, initial_state)
    factor, points = QUASI_MARGIN
    full_current = fit.errors.get('current_nrmse_pct') or 0.0
    quasi_current = refit[1].get('current_nrmse_pct')
    return quasi_current is not None and quasi_current <= factor * full_current + points


def full_resolved(fit: Fit, quasi: Estimate, quasi_models: Models, initial_state: str) -> bool:
    """
    Whether the full armature equation fits the current significantly better than La -> 0.

    The likelihood ratio on the current's effective samples beyond its chi-square threshold
    (:func:`armature_likelihood_ratio`): under ``likelihood-ratio`` the quasi-static equation
    is kept unless the data reject it.
    """
    ratio, needed = armature_likelihood_ratio(fit.estimate, quasi, fit.models, quasi_models,
                                              initial_state == 'estimate')
    return ratio > needed


def armature_likelihood_ratio(full: Estimate, quasi: Estimate, full_models: Models,
                              quasi_models: Models, free_states: bool = True,
                              channels: tuple[str, ...] = ('current',)
                              ) -> tuple[float, float]:
    """
    Return the full armature equation's likelihood ratio over the quasi-static one, and its test.

    Both are Gaussian maximum-likelihood fits with a noise level per record and channel, so
    twice the log-likelihood ratio is ``sum n ln(SSE_quasi / SSE_full)`` over the records'
    ``channels`` (the current, where La acts; a speed derived from an angle has lags of its
    own that La takes up, ``bench/armature_results.md``).  Each record's and channel's
    samples count as many as they are worth independently: ``n`` over the correlation time
    of the full fit's residual
    (:func:`~dcmotor_id.identification.checks.start.correlation_time`, as the discovery
    loop's held-out t counts them).  The quasi-static equation is nested in the full one (La
    and, with ``free_states``, each record's initial current are the extra freedom); the
    second value is the ratio chi-square exceeds with probability
    :data:`~dcmotor_id.identification.discovery.judging.HELDOUT_ALPHA` under it.
    """
    from scipy.stats import chi2

    ratio = 0.0
    runs = [simulate_records(models.measured, estimate.parameters, estimate.initial_states)
            for estimate, models in ((full, full_models), (quasi, quasi_models))]
    for index, rec in enumerate(full_models.measured.records):
        for channel in (name for name in full_models.measured.outputs if name in channels):
            measured = getattr(rec, channel)
            errors = [run[index][channel] - measured for run in runs]
            kept = np.isfinite(errors[0]) & np.isfinite(errors[1])
            sums = [float(error[kept] @ error[kept]) for error in errors]
            if kept.sum() < 3 or not sums[0] > 0.0:
                continue
            effective = kept.sum() / correlation_time(errors[0][kept])
            ratio += effective * float(np.log(max(sums[1], 1e-300) / sums[0]))
    extra = 1 + (len(full.initial_states) if free_states else 0)
    return ratio, float(chi2.isf(HELDOUT_ALPHA, extra))


def quasi_static_fit(estimate: Estimate, models: Models, initial_state: str,
                     progress: Progress, position_error: str = 'adaptive'
                     ) -> tuple[Estimate, ChannelErrors] | None:
    """
    Fit the quasi-static armature (La -> 0) from ``estimate``; its errors; None if it fails.

    ``models``: the quasi-static base model on the records (the refit's criterion is theirs);
    ``position_error``: the model of the position error of the refit.
    """
    values = estimate.parameters
    start = {name: values[name] for name in parameter_names(False) if name != 'La'}
    progress.set_stage('quasi-static armature refit')
    try:
        quasi = refined_fit(models, initial_state, progress, position_error, initial=start,
                            quasi_static=True)
        quasi_errors = model_errors(models.measured, dict(quasi.parameters),
                                    quasi.initial_states)
    except (DcMotorIdError, np.linalg.LinAlgError, ValueError):
        return None
    return quasi, quasi_errors


def refined_fit(models: Models, initial_state: str, progress: Progress, position_error: str,
                initial: Mapping[str, float] | None = None, quasi_static: bool = False,
                pinned: Mapping[str, float] | None = None) -> Estimate:
    """
    Fit the refined estimator on ``models``' records under their criterion.

    The armature's two refits differ only in the estimator's ``initial`` and ``quasi_static``
    (:func:`quasi_static_fit`) or ``pinned`` (:func:`la_at_its_bound`).
    """
    estimator = RefinedEstimator(initial=initial, quasi_static=quasi_static, pinned=pinned,
                                 initial_state=initial_state, progress=progress,
                                 criterion=models.criterion, position_error=position_error)
    return estimator.fit(models.records)


def with_la_bound(quasi: Estimate, la: float, la_stderr: float, ra_full: float,
                  dt: float) -> tuple[Estimate, dict[str, float]]:
    """
    Give a quasi-static estimate La, Ka and Ta: La by its upper bound, Ta from it.

    The bound is the larger of ``Ra dt`` (a time constant below the sample period) and the
    full fit's ``La + 2 stderr`` where that La is inside the range the sample period does not
    resolve (as the regression's bound, :func:`~dcmotor_id.identification.pipeline.floor.
    regression_floor`): a full fit's La beyond it, which the quasi-static refit does without,
    ran off where the data hold no trace of it (a diverged fit: La/Ra of 1e5 s on a 1 s
    record) and bounds nothing.  ``stderr`` of La and Ta is NaN, Ka's follows Ra's.
    """
    resolved = 0.0 < la < abs(ra_full) * dt
    bound = max(quasi.parameters['Ra'] * dt, la + 2.0 * la_stderr if resolved else 0.0)
    parameters = dict(quasi.parameters)
    parameters['La'] = bound
    parameters.update(derived_values(parameters))
    ra = parameters['Ra']
    stderr = dict(quasi.stderr)
    stderr.update({'La': float('nan'), 'Ta': float('nan'), 'Ka': quasi.stderr['Ra'] / ra ** 2})
    model = dict(quasi.info.get('stderr_model', quasi.stderr))
    model.update({'La': float('nan'), 'Ta': float('nan'),
                  'Ka': model.get('Ra', np.nan) / ra ** 2})
    info = {**quasi.info, 'stderr_model': model}
    result = replace(quasi, parameters=parameters, stderr=stderr, info=info)
    return result, {'La': bound, 'Ta': parameters['Ta']}


def structure_spread(full: Estimate, quasi: Estimate) -> dict[str, float]:
    """Return ``full - quasi`` of each parameter both armature equations fit."""
    return {name: float(full.parameters[name]) - float(quasi.parameters[name])
            for name in SHARED_NAMES if name in full.parameters and name in quasi.parameters}


def structure_stderr(inputs: Inputs, fit: Fit, answer: Answer) -> Answer:
    """
    Return the answer with standard errors that cover the armature equation's choice.

    Under the quasi-static armature only: :func:`with_structure_stderr` on the answer's
    standard errors (as the checks left them: a J range, a bound), and
    :func:`structure_warning` naming the parameters the choice moves beyond their own errors.
    After the checks of what the data determine (they judge the data's own precision, the
    warning says the structure's).
    """
    if not fit.quasi or not fit.structure_spread:
        return answer
    stderr, named = with_structure_stderr(answer.stderr, answer.parameters,
                                          fit.structure_spread, fit.full_stderr or {})
    final = answer.final
    info = dict(final.info)
    info['uncertainty_method'] = str(info.get(
        'uncertainty_method', f"the {final.method} estimator's own")) + STRUCTURE_METHOD
    info['armature_structure_spread'] = dict(fit.structure_spread)
    final = replace(final, info=info, stderr={**final.stderr, **{
        name: value for name, value in stderr.items() if name in final.stderr}})
    warnings = answer.warnings + ((structure_warning(named, inputs.records[0].sample_period_s),)
                                  if named else ())
    return replace(answer, final=final, stderr=stderr, warnings=warnings)


def with_structure_stderr(stderr: Mapping[str, float], parameters: Mapping[str, float],
                          spread: Mapping[str, float], full_stderr: Mapping[str, float]
                          ) -> tuple[dict[str, float], dict[str, float]]:
    """
    Return standard errors that cover the armature equation's choice.

    Both equations fit the data: the quasi-static one (kept) and the full one, whose La
    absorbs what else lags the current by a fraction of a sample (a speed averaged over the
    sample, a delay) as readily as a real La.  Which is right the data do not tell, so each
    shared parameter's finite standard error becomes ``sqrt(max(stderr, full)**2 +
    spread**2)``: ``full`` is the full fit's own (La pinned at 0 no longer hides what La's
    freedom leaves open), ``spread`` the full fit's value less the quasi-static one's
    (:func:`structure_spread`).  Ka's follows Ra's; a NaN (a bound, an upper bound) stays.
    Also returned: the parameters whose error the choice more than doubles (a warning names
    them), with the spread relative to the value.
    """
    widened = dict(stderr)
    named: dict[str, float] = {}
    for name, difference in spread.items():
        own = float(widened.get(name, np.nan))
        if not np.isfinite(own) or not np.isfinite(difference):
            continue
        full = float(full_stderr.get(name, np.nan))
        widened[name] = float(np.hypot(max(own, full) if np.isfinite(full) else own,
                                       difference))
        if widened[name] > 2.0 * own and parameters[name] != 0.0:
            named[name] = difference / float(parameters[name])
    if np.isfinite(widened.get('Ka', np.nan)) and 'Ra' in spread:
        widened['Ka'] = widened['Ra'] / parameters['Ra'] ** 2
    return widened, named


def structure_warning(named: dict[str, float], dt: float) -> str:
    """Say which parameters the choice of the armature equation moves beyond their error."""
    moved = ', '.join(f'{name} {100.0 * relative:+.2g} %' for name, relative in named.items())
    names = ', '.join(named)
    return (f'{names}: the armature equation is not decided by these data (La is not '
            f'resolved at the sample period {dt:.2g} s): the full equation (with La) moves '
            f'them by {moved} '
            'from the quasi-static one given; their standard errors, more than doubled, cover '
            "the full equation's fit too (a speed averaged over the sample or a "
            'delay can pass for La: sample faster, or log the speed at the sample instant, '
            'to decide)')


def la_reason(la: float, la_stderr: float, ra: float, dt: float, bound: float | None) -> str:
    """Say why La is not identified; with the bound, how the others were identified."""
    ta = la / ra
    why = (f'the electrical time constant La/Ra = {ta:.2g} s is below the sample period '
           f'{dt:.2g} s' if ta < dt else
           f'La = {la:.3g} +/- {la_stderr:.2g} H is not determined')
    if bound is None:
        return why + ': La is not identifiable from these data (sample faster to see it)'
    return (why + f': La < {bound:.3g} H (upper bound, given as its value); Ra, CPhi, J, b and '
            'Mc come from the quasi-static armature equation (La -> 0): '
            'J dw/dt = CPhi (u - CPhi w)/Ra - b w - Mc sgn w, i = (u - CPhi w)/Ra')
