"""
Several starts of the base fit when its misfit is large or it disagrees with the evidence.

An output-error fit from one start point can settle in a local minimum: a friction run to its
bound (no gradient leads back from there), or a mechanical time constant far from the one the
data show.  When the base fit (the motor model without effects) misfits far above the sensor
noise, or lies far from the model-free regression
(:func:`~dcmotor_id.identification.checks.start.far_from_evidence`), :func:`several_starts`
fits the same model again from a few further starts:

* the regression's values (:func:`~dcmotor_id.identification.checks.start.regression_start`);
* the same with J times 1/3 and times 3 (b kept): the mechanical time constant ``J / b``
  spread over a decade around the regression's, unless the regression's start already led
  back to the default's fit (one basin: the spread is not paid for).

It keeps the best by the criterion of the start check
(:func:`~dcmotor_id.identification.checks.start.bic` over the samples the residuals are
worth) and accounts for every start in the JSON (``start_check.starts``).  Two starts that
score alike (within :data:`SIMILAR_BIC`) in different basins make the answer ambiguous:
:func:`ambiguity_warning` says so.  The further starts are base fits only (not discovery
loops), at most :data:`MAX_STARTS`, and take at most :data:`BUDGET_SHARE` of the time left.

They are fitted once per identification.  A fit on the position may run the identification
twice (:mod:`~dcmotor_id.identification.pipeline.position_error`: the position error as white
noise,
then as a drift), with the same records and the same regression, hence the same further
starts.  The first run that needs them fits them all; a later run, given the first one's
account (``earlier``), fits again only the start the first one chose (none when that was its
default: the further starts led nowhere better) and those it found ambiguous, under its own
error model, and keeps the best of them and its own default fit.  The others are accounted as
``skipped`` (:data:`NOT_CHOSEN_EARLIER`).
"""

from __future__ import annotations

from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.core.records import record_names
from dcmotor_id.identification.checks.start import (bic_scores, FROM_RECORDS, known_evidence,
                                                    regression_start, start_doubts)
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.pipeline.fit_outcome import check_physical
from dcmotor_id.identification.pipeline.state import Models

if TYPE_CHECKING:
    from dcmotor_id.identification.error_model.residuals import Simulation
    from dcmotor_id.identification.estimators.base import Estimate

#: Most further starts (base fits) after the default one.
MAX_STARTS = 3
#: Factors on the regression's J (b kept) that spread the mechanical time constant.
TIME_CONSTANT_FACTORS = (1.0 / 3.0, 3.0)
#: Most of the time left (budget) the further starts may take.
BUDGET_SHARE = 0.25
#: BIC improvement a later start must bring to replace an earlier one's fit (not round-off).
TIE_BIC = 0.01
#: Relative difference under which two fits' base values are the same point.
SAME_POINT = 1e-3
#: The base values compared by :func:`_same_point` (the mechanical ones, always fitted).
START_NAMES = ('J', 'b', 'Mc')
#: BIC difference within which two results explain the data alike.
SIMILAR_BIC = 2.0
#: Relative difference of J or b beyond which two results lie in different basins ...
BASIN_SHARE = 0.25
#: ... when it also exceeds this many of their combined standard errors.
BASIN_STDERR = 3.0


def further_starts(evidence: dict[str, float] | None, fitted: dict[str, float],
                   names: Sequence[str]) -> list[tuple[str, dict[str, float]]]:
    """
    Return the further starts ``(name, values)``: the regression's, then J spread around it.

    Without evidence, J is spread around the fitted values (``fitted``), which also fill in
    what the regression lacks.
    """
    base = regression_start(evidence, fitted, names)
    starts = [('regression', base)] if evidence is not None else []
    starts += [(f'regression, J x {factor:.3g}' if evidence is not None else
                f'fit, J x {factor:.3g}', {**base, 'J': base['J'] * factor})
               for factor in TIME_CONSTANT_FACTORS]
    return starts[:MAX_STARTS]


#: What a later run of one identification says of a further start it does not fit again.
NOT_CHOSEN_EARLIER = 'not chosen in an earlier run of this identification (fitted there)'


def several_starts(estimate: Estimate, models: Models, progress: Progress,
                   evidence: dict[str, float] | None | str = FROM_RECORDS,
                   earlier: dict[str, Any] | None = None, position_error: str = 'adaptive',
                   carried: Simulation | None = None
                   ) -> tuple[Estimate, dict[str, Any] | None]:
    """
    Fit the base model from further starts when the default's fit is doubted; keep the best.

    Returns the best base fit and the account (None when no further start was needed):
    ``reasons``, ``starts`` (per start its ``name``, ``start`` values, the fitted ``J`` and
    ``b``, its ``bic``, or why it ``failed`` or was ``skipped``, and ``chosen``; the default's
    entry has the ``effective_samples``), ``chosen`` (the name), ``ambiguous``
    (:func:`ambiguous_starts`) and ``cpu_s`` (the cost of the further starts on the budget's
    clock).  ``models``: the base model on the records (quasi-static or not) and the run's
    criterion, whose ``compared`` model scores the fits.  ``evidence``: the model-free
    regression on the records when the caller has it
    (:func:`~dcmotor_id.identification.checks.start.known_evidence`).  ``earlier``: the
    account of an earlier run of the same identification (the records and the regression
    the same), whose chosen start alone is fitted again.  ``position_error``: the model of
    the position error of the fits.  ``carried``: the default's simulation when a stage ran
    it (:attr:`~dcmotor_id.identification.pipeline.state.Fit.simulation`).
    """
    records, torque_constant, model = models.records, models.torque_constant, models.compared
    evidence = known_evidence(records, torque_constant, evidence)
    reasons = start_doubts(estimate, records, model, evidence, carried).further_starts
    if not reasons:
        return estimate, None
    began = progress.now()
    entries: list[dict[str, Any]] = [{'name': 'default',
                                      'start': dict(estimate.info.get('start', {}))}]
    fits: list[Estimate | None] = [estimate]
    deadline = progress.deadline
    share = None if deadline is None else began + BUDGET_SHARE * max(deadline - began, 0.0)
    try:
        progress.deadline = share
        _fit_starts(models, progress, position_error,
                    _starts_of(evidence, estimate, model, earlier), entries, fits)
    finally:
        progress.deadline = deadline
    best = _score(fits, entries, records, model, estimate)
    account = {'reasons': reasons, 'starts': entries, 'chosen': entries[best]['name'],
               'ambiguous': ambiguous_starts(fits, entries, best),
               'cpu_s': float(progress.now() - began)}
    return fits[best] or estimate, account


def _starts_of(evidence: dict[str, float] | None, estimate: Estimate, model: OutputErrorModel,
               earlier: dict[str, Any] | None) -> list[tuple[str, dict[str, float], bool]]:
    """
    Return the further starts ``(name, values, fitted)``; not fitted: an earlier run did.

    Without an earlier run's account, :func:`further_starts`, all fitted; with it, that run's
    further starts, fitted (from the same values) only the one it chose and those it found
    ambiguous (:func:`ambiguous_starts`), whose warning this run then gives as well.
    """
    if earlier is None:
        return [(name, start, True) for name, start in
                further_starts(evidence, estimate.parameters, model.base_names)]
    return [(entry['name'], dict(entry['start']),
             bool(entry['chosen']) or entry['name'] in earlier['ambiguous'])
            for entry in earlier['starts'][1:]]


def _fit_starts(models, progress, position_error, starts, entries, fits):
    """Fit the base model from each start in turn (appending to ``entries`` and ``fits``)."""
    estimate = fits[0]
    for name, start, fitted in starts:
        entries.append({'name': name, 'start': start})
        if not fitted:
            entries[-1]['skipped'] = NOT_CHOSEN_EARLIER
            fits.append(None)
            continue
        if _same_start(start, entries[0]['start']):
            entries[-1]['skipped'] = 'the default start (not fitted again)'
            fits.append(None)
            continue
        fits.append(_fit_from(models, progress, position_error, start, entries[-1]))
        if fits[-1] is None and entries[-1].get('failed', '').startswith('time budget'):
            break
        if name == 'regression' and fits[-1] is not None and _same_point(fits[-1], estimate):
            break  # the model-free start leads to the default's fit: one basin, no spread


def _same_start(start: dict[str, float], default: dict[str, float]) -> bool:
    """Whether a further start is the default one (every value within round-off)."""
    return bool(default) and all(
        name in default and np.isclose(value, default[name], rtol=1e-9, atol=0.0)
        for name, value in start.items())


def _same_point(one: Estimate, other: Estimate) -> bool:
    """Whether two base fits reached the same point (every base value within SAME_POINT)."""
    return all(np.isclose(float(value), float(other.parameters.get(name, np.nan)),
                          rtol=SAME_POINT, atol=0.0)
               for name, value in one.parameters.items() if name in START_NAMES)


def _fit_from(models, progress, position_error, start, entry):
    """
    Fit the base model from ``start``; None (and ``entry['failed']``) when it fails.

    ``models``: the records, the quasi-static armature or not and the criterion of the fit;
    ``position_error``: the model of its position error.
    """
    try:
        progress.set_stage(f'base fit from a further start ({entry["name"]})',
                           record_names(models.records))
        fit = RefinedEstimator(initial=start, quasi_static=models.quasi_static,
                               progress=progress, criterion=models.criterion,
                               position_error=position_error).fit(
            models.records, torque_constant=models.torque_constant)
        check_physical(fit)
    except TimeBudgetExceeded:
        entry['failed'] = 'time budget: the further starts may take ' \
                          f'{100 * BUDGET_SHARE:.0f} % of the time left'
        return None
    except (DcMotorIdError, np.linalg.LinAlgError, FloatingPointError) as error:
        entry['failed'] = str(error) or type(error).__name__
        return None
    return fit


def _score(fits, entries, records, model, first) -> int:
    """Score the fits (BIC on the fewest effective samples); fill the entries; return the best."""
    noise = dict(first.info.get('noise_std', {}))
    done = [index for index, fit in enumerate(fits) if fit is not None]
    scores, effective = bic_scores({index: (fits[index], records, model, True)
                                    for index in done}, noise)
    # The first start (the default first) within TIE_BIC of the lowest: a point reached again
    # from a later start does not replace it on round-off.
    low = min(scores.values())
    best = next(index for index in done if scores[index] <= low + TIE_BIC)
    for index in done:
        entries[index].update({'J': float(fits[index].parameters['J']),
                               'b': float(fits[index].parameters['b']),
                               'bic': float(scores[index]), 'chosen': index == best})
    for entry in entries:
        entry.setdefault('chosen', False)
    entries[0]['effective_samples'] = float(effective)
    return best


def different_basins(one: Estimate, other: Estimate) -> bool:
    """
    Whether two fits of the same model lie in different basins.

    J or b differs by more than :data:`BASIN_SHARE` of the larger and by more than
    :data:`BASIN_STDERR` of their combined standard errors.
    """
    for name in ('J', 'b'):
        a, b = float(one.parameters[name]), float(other.parameters[name])
        spread = np.hypot(float(one.stderr.get(name, np.nan)),
                          float(other.stderr.get(name, np.nan)))
        apart = abs(a - b) > BASIN_SHARE * max(abs(a), abs(b))
        if apart and not abs(a - b) <= BASIN_STDERR * spread:  # NaN errors count as apart
            return True
    return False


def ambiguous_starts(fits: Sequence[Estimate | None], entries: Sequence[dict[str, Any]],
                     best: int) -> list[str]:
    """Name the starts that land in another basin than the best, scoring alike (the BIC)."""
    chosen = fits[best]
    if chosen is None:
        return []
    return [entries[index]['name'] for index, fit in enumerate(fits)
            if fit is not None and index != best
            and entries[index]['bic'] - entries[best]['bic'] < SIMILAR_BIC
            and different_basins(fit, chosen)]


def ambiguity_warning(account: dict[str, Any] | None) -> str | None:
    """Return the warning of starts that land in different basins with similar scores."""
    if account is None or not account.get('ambiguous'):
        return None
    by_name = {entry['name']: entry for entry in account['starts']}
    best = by_name[account['chosen']]
    others = '; '.join(f'from the {name} start J = {by_name[name]["J"]:.4g}, '
                       f'b = {by_name[name]["b"]:.4g}' for name in account['ambiguous'])
    return (f'the base fit is ambiguous: from the {account["chosen"]} start it gives '
            f'J = {best["J"]:.4g}, b = {best["b"]:.4g}, and {others}, which explain the data '
            f'about as well (BIC within {SIMILAR_BIC:g}); the data do not tell these apart: '
            'record a richer excitation (steps of several sizes, both directions)')


def with_starts(check: dict[str, Any] | None, account: dict[str, Any] | None
                ) -> dict[str, Any] | None:
    """Return the start check with the further starts' account (``starts`` and the rest)."""
    if account is None:
        return check
    base = dict(check) if check is not None else {'doubts': [], 'chosen': 'first start'}
    base.update({'starts': account['starts'], 'starts_chosen': account['chosen'],
                 'starts_reasons': account['reasons'],
                 'starts_ambiguous': account['ambiguous'], 'starts_cpu_s': account['cpu_s']})
    return base
