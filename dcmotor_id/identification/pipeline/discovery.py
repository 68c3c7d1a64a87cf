"""
Stage 5, discovery: the effect discovery loop from the base, within the time budget.

Not tried when the base is hopeless (:data:`HOPELESS_NRMSE_PCT`), given a short look when it
does not fit (:data:`HOPELESS_DISCOVERY_S`), skipped when the second start ran its own loop.
:func:`run_discovery` runs the loop (:mod:`~dcmotor_id.identification.discovery`), its
failures turned into a reason; :func:`time_warnings` says when the budget ran out there.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.discovery import DiscoveryLoop, DiscoveryResult
from dcmotor_id.identification.pipeline.fit_outcome import check_physical, NO_FIT_NRMSE_PCT
from dcmotor_id.identification.pipeline.state import Fit, Inputs

if TYPE_CHECKING:
    from dcmotor_id.identification.discovery import Structure
    from dcmotor_id.identification.estimators.base import Estimate

#: Simulation error of the base model above which effect discovery is not tried (percent).
HOPELESS_NRMSE_PCT = 100.0
#: Time given to effect discovery when the base model is off by more than NO_FIT_NRMSE_PCT
#: [s of CPU time, as the budget: :func:`dcmotor_id.core.progress.budget_clock`].
HOPELESS_DISCOVERY_S = 3.0


def discovery(inputs: Inputs, fit: Fit) -> Fit:
    """Return the fit with the effects discovered from its base, unless hopeless or done."""
    base_worst = max([value for value in fit.errors.values() if value is not None] or [np.inf])
    if inputs.criterion != 'speed':
        # The base model's position may be far off for lack of the very effect (a load) the
        # loop is there to find: the loop gets its full time, the final model is checked.
        base_worst = min(base_worst, NO_FIT_NRMSE_PCT)
    if fit.start_check is not None and fit.start_check['chosen'] != 'first start':
        return fit  # the second start ran its own discovery
    if not inputs.discover:
        return fit
    if not base_worst <= HOPELESS_NRMSE_PCT:
        # Worse than the signals' mean: a sign or unit error, which no effect explains (and
        # every candidate fit would diverge slowly); refused later without the loop.
        return replace(fit, discovery_info={'skipped': f'the base model does not fit '
                                                       f'({base_worst:.3g} % simulation error)'})
    progress = inputs.progress
    deadline = progress.deadline
    if base_worst > NO_FIT_NRMSE_PCT:
        # A base model this far off is rarely rescued by one effect: a short look only, so
        # that a record that cannot be fitted is refused in seconds.
        progress.deadline = min(deadline if deadline is not None else np.inf,
                                progress.now() + HOPELESS_DISCOVERY_S)
    try:
        found, info = run_discovery(inputs, fit.quasi, fit.estimate)
    finally:
        progress.deadline = deadline
    return replace(fit, found=found, discovery_info=info,
                   warnings=fit.warnings + time_warnings(found, info, progress))


def time_warnings(found: DiscoveryResult | None, discovery_info: dict[str, Any] | None,
                  progress: Progress) -> tuple[str, ...]:
    """Say when the time budget ran out during discovery, or before it had a result."""
    if found is not None and found.out_of_time:
        return (f'the time budget ({progress.max_time_s:g} s) ran out during effect discovery: '
                'the result is the best structure so far'
                + (' fitted on the training parts only (first '
                   f'{100 * (1 - found.holdout_fraction):.0f} % of the motion)'
                   if found.estimate is found.final.estimate else '')
                + '; give more time with --max-time',)
    if found is None and discovery_info and 'time budget' in discovery_info.get('skipped', ''):
        return (discovery_info['skipped'],)
    return ()


def supports_discovery(estimator: Any) -> bool:
    """
    Whether the discovery loop can follow this estimator (it fits effect terms).

    The :class:`~dcmotor_id.identification.estimators.base.Estimator` protocol's ``supports_terms``
    says whether the estimator fits effect terms (the refined one does, the paper's does not).
    """
    return bool(getattr(estimator, 'supports_terms', False))


def run_discovery(inputs: Inputs, quasi_static: bool, estimate: Estimate,
                  structure: Structure | None = None, initial_state: str | None = None
                  ) -> tuple[DiscoveryResult | None, dict[str, Any]]:
    """
    Run the loop; return ``(DiscoveryResult or None, JSON summary or skip reason)``.

    The loop starts from ``estimate`` on the run's records, vocabulary, criterion and position
    error's model.  ``structure``: effects the loop's base holds from the start
    (``DiscoveryLoop.run``); ``initial_state``: its fits' (default: the run's).
    """
    estimator, progress = inputs.estimator, inputs.progress
    if not supports_discovery(estimator):
        return None, {'skipped': f'effect discovery needs the refined method (the '
                                 f'{getattr(estimator, "name", "given")} method has no effect '
                                 'terms)'}
    try:
        found = DiscoveryLoop(inputs.records, inputs.torque_constant,
                              vocabulary=inputs.vocabulary, progress=progress,
                              initial_state=initial_state or inputs.initial_state,
                              quasi_static=quasi_static, criterion=inputs.criterion,
                              position_error=inputs.on.position_error).run(estimate, structure)
        check_physical(found.estimate)
    except TimeBudgetExceeded:
        return None, {'skipped': f'the time budget ({progress.max_time_s:g} s) ran out '
                                 'before effect discovery had a result: the base model is '
                                 'reported'}
    except (DcMotorIdError, np.linalg.LinAlgError) as error:
        return None, {'skipped': f'effect discovery could not run on these data: {error}'}
    return found, found.summary()
