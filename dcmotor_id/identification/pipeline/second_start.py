"""
The second start: a fit in a wrong basin fitted again from the regression's values.

One step of the start check (:mod:`~dcmotor_id.identification.pipeline.start_check`); the
evidence and the doubts it uses are :mod:`~dcmotor_id.identification.checks.start`'s.

A fit from the default start can settle in a wrong basin (e.g. the initial speeds moved by a
misfit); the regression on the data (:mod:`~dcmotor_id.identification.checks.start`) sees that
without a model.  :func:`check_start` compares the fit with it; when doubted, it fits again
from the regression's values with the initial states pinned to the first samples (holding
the effects the regression sees, :func:`evidence_structure`: a torque offset between the
directions), searches the effects from there, frees the initial states, and keeps whichever
of the first start and these candidates explains all of the data best (BIC on the samples
the residuals are worth).  :func:`start_warning` says what happened.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import parameter_names
from dcmotor_id.core.progress import TimeBudgetExceeded
from dcmotor_id.core.records import record_names
from dcmotor_id.identification.checks.start import (bic_scores,
                                                    offset_supported, regression_start,
                                                    start_doubts)
from dcmotor_id.identification.discovery import refit_all_data, refit_start, Structure
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.pipeline.discovery import run_discovery
from dcmotor_id.identification.pipeline.fit_outcome import check_physical
from dcmotor_id.identification.pipeline.state import Fit, Inputs, Models

if TYPE_CHECKING:
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate


def check_start(inputs: Inputs, fit: Fit
                ) -> tuple[DiscoveryResult | None, Estimate, dict[str, Any] | None,
                           dict[str, Any]]:
    """
    Check the fit against model-free evidence; when doubted, try a second start, keep the best.

    The fit checked is the discovery loop's (``fit.found``) when it ran, else the base
    (``fit.estimate``).  Returns ``(found, base estimate, discovery summary, start_check)``,
    the fit's own unless the second start explains all of the data better (lower BIC).
    ``start_check`` is the JSON account (:mod:`dcmotor_id.identification.checks.start`).
    Every fit and score of the check is on the run's criterion (the channels compared), its
    position error's model, against the run's model-free regression (``inputs.evidence``).
    """
    found, estimate, discovery_info = fit.found, fit.estimate, fit.discovery_info
    evidence = inputs.evidence
    first = found.estimate if found is not None else estimate
    first_records = found.records if found is not None else list(inputs.records)
    model = fit.models.compared if found is None else Models(
        found.records, inputs.torque_constant, fit.quasi, inputs.criterion,
        tuple(found.terms)).compared
    doubts = start_doubts(first, first_records, model, evidence, fit.simulation).second_start
    check: dict[str, Any] = {'evidence': evidence, 'doubts': doubts, 'chosen': 'first start'}
    if not doubts:
        return found, estimate, discovery_info, check
    seed = evidence_structure(evidence, inputs.vocabulary) if inputs.discover else Structure()
    pinned, seed = _pinned_fit(inputs, fit, check, seed)
    if pinned is None:
        return found, estimate, discovery_info, check
    second = _second_start(inputs, fit, pinned, check, seed)
    if second.found is None and len(second.structure):
        # The loop did not finish from the seeded base: its effects have no result to go in.
        check['second_start'] = f'failed: {(second.info or {}).get("skipped", "no result")}'
        return found, estimate, discovery_info, check
    chosen = _choose(check, first, first_records, model, second)
    if chosen == 'first start':
        return found, estimate, discovery_info, check
    final = second.freed if chosen == 'second start' and second.freed is not None else \
        second.pinned_final
    if second.found is None:
        return None, final, discovery_info, check
    found = replace(second.found, estimate=final,
                    effects=second.structure.effects(final.parameters))
    return found, pinned, second.info, check


@dataclass
class _SecondStart:
    """The candidates of a second start and what they are measured on."""

    found: DiscoveryResult | None  # the discovery loop's result from the pinned fit
    info: dict[str, Any] | None  # its summary
    structure: Structure  # the effects it found (none without discovery)
    pinned_final: Estimate  # the pinned fit, after the effects were searched
    records: list  # the records as that structure sees them
    model: OutputErrorModel
    freed: Estimate | None = None  # the refit with the initial states freed


def evidence_structure(evidence: dict[str, float] | None,
                       vocabulary: Sequence[type[Effect]]) -> Structure:
    """
    Return the effects the model-free regression sees, which a sound base holds from the start.

    On records in both directions a constant torque offset
    (:func:`~dcmotor_id.identification.checks.start.offset_supported`) is the ``load_torque``
    effect: without it no basin of the base model balances both steady states, and a fit
    from there (pinned or not) settles at a huge J that never reaches them.
    """
    names = {cls.name: cls for cls in vocabulary}
    if offset_supported(evidence) and 'load_torque' in names:
        return Structure([(names['load_torque'], {})])
    return Structure()


def _pinned_fit(inputs: Inputs, fit: Fit, check: dict[str, Any],
                seed: Structure) -> tuple[Estimate | None, Structure]:
    """
    Fit from the regression's values with the initial states pinned; return it and its structure.

    The effects of ``seed`` (:func:`evidence_structure`) are in the fit, their coefficients
    started from the regression (the offset); when that fit fails, the base model is tried.
    The fit is None when it fails.  Each fit is on the run's criterion and position error's
    model.
    """
    records, torque_constant, progress = inputs.records, inputs.torque_constant, inputs.progress
    quasi, evidence = fit.quasi, inputs.evidence
    criterion, position_error = inputs.criterion, inputs.on.position_error
    names = [name for name in parameter_names(torque_constant is not None)
             if not (quasi and name == 'La')]
    start = regression_start(evidence, fit.estimate.parameters, names)
    progress.set_stage('second start (initial states pinned)', record_names(records))
    if len(seed) and evidence is not None:
        values = {**start, **{cls.term_name('torque_Nm'): evidence['offset']
                              for cls, _ in seed.items if cls.name == 'load_torque'}}
        try:
            pinned = refit_all_data(seed, records, torque_constant, values, start,
                                    initial_state='measured', quasi_static=quasi,
                                    progress=progress, criterion=criterion,
                                    position_error=position_error)[2]
            check_physical(pinned)
            check['seeded'] = seed.names()
            return pinned, seed
        except (DcMotorIdError, np.linalg.LinAlgError, TimeBudgetExceeded) as error:
            check['seeded'] = f'failed: {error}'  # the base model is tried instead
    try:
        pinned = RefinedEstimator(initial=start, initial_state='measured', quasi_static=quasi,
                                  progress=progress, criterion=criterion,
                                  position_error=position_error).fit(
            records, torque_constant=torque_constant)
        check_physical(pinned)
    except (DcMotorIdError, np.linalg.LinAlgError, TimeBudgetExceeded) as error:
        check['second_start'] = f'failed: {error}'
        return None, Structure()
    return pinned, Structure()


def _second_start(inputs: Inputs, fit: Fit, pinned: Estimate, check: dict[str, Any],
                  seed: Structure) -> _SecondStart:
    """Search the effects from the pinned fit (its structure ``seed``), then free the states."""
    records, torque_constant, progress = inputs.records, inputs.torque_constant, inputs.progress
    quasi, criterion, position_error = fit.quasi, inputs.criterion, inputs.on.position_error
    found, info, structure = None, None, seed
    values, states = pinned.parameters, pinned.initial_states
    if inputs.discover:
        found, info = run_discovery(inputs, quasi, pinned, structure=structure,
                                    initial_state='measured')
        if found is not None:
            structure = found.final.structure
            values, states = found.estimate.parameters, found.estimate.initial_states
    second_records = structure.transformed(records)
    second = _SecondStart(found, info, structure,
                          found.estimate if found is not None else pinned, second_records,
                          Models(second_records, torque_constant, quasi, criterion,
                                 tuple(found.terms) if found is not None else ()).compared)
    try:
        freed = refit_all_data(structure, records, torque_constant, values,
                               refit_start(values, records, torque_constant), progress=progress,
                               initial_states=states, initial_state='estimate',
                               quasi_static=quasi, criterion=criterion,
                               position_error=position_error)[2]
        check_physical(freed)
    except (DcMotorIdError, np.linalg.LinAlgError, TimeBudgetExceeded) as error:
        check['freed'] = f'failed: {error}'  # the pinned fit is still a candidate
        freed = None
    second.freed = freed
    return second


def _choose(check, first, first_records, model, second):
    """
    Score the first start and the second's candidates (BIC); account for and return the best.

    The BIC counts the samples the residuals are worth (the fewest over the candidates,
    :func:`~dcmotor_id.identification.checks.start.effective_samples`), so that a free initial
    speed absorbing a slow misfit does not win on thousands of correlated samples.
    """
    noise = dict(first.info.get('noise_std', {}))
    candidates = {'first start': (first, first_records, model, True),
                  'second start, initial states pinned': (second.pinned_final, second.records,
                                                          second.model, False)}
    if second.freed is not None:
        candidates['second start'] = (second.freed, second.records, second.model, True)
    scores, effective = bic_scores(candidates, noise)
    chosen = min(scores, key=lambda key: scores[key])
    shown = second.freed if second.freed is not None else second.pinned_final
    check.update({'second_start': {'effects': second.structure.names(),
                                   'J': float(shown.parameters['J']),
                                   'b': float(shown.parameters['b'])},
                  'bic': scores, 'effective_samples': float(effective), 'chosen': chosen})
    return chosen


def start_warning(check: dict[str, Any] | None) -> str | None:
    """Return the warning of a start check: the result from a second start, or a doubt kept."""
    if check is None:
        return None
    if check['chosen'] != 'first start':
        return _second_start_warning(check)
    if not check['doubts']:
        return None
    outcome = check.get('second_start')
    return ('the fit disagrees with the model-free evidence ('
            + '; '.join(check['doubts']) + ') and a second start '
            + (f'could not help ({outcome})' if isinstance(outcome, str) else
               'explains the data no better')
            + ': the values may come from a wrong basin; compare with '
            '--initial-state measured')


def _second_start_warning(check: dict[str, Any]) -> str:
    """Return the warning of a result taken from the second start."""
    how = ("the fit with every initial state pinned to the records' first samples"
           if check['chosen'].endswith('pinned') else
           'from a second start (the regression on the data, initial states pinned to the '
           'first samples while the effects were searched, then freed)')
    seeded = check.get('seeded')
    held = (f' (holding from the start the torque offset the regression sees, as '
            f'{", ".join(seeded)})' if isinstance(seeded, list) and seeded else '')
    return ('the fit from the default start landed where the model-free evidence disagrees ('
            + '; '.join(check['doubts']) + f'); the result is {how}{held}, which explains all '
            'of the data better (BIC)')
