"""
What the stages of :func:`~dcmotor_id.identification.identify.identify` share about a fit.

:func:`simulation_errors` of an estimate over the records, :func:`check_physical` refusing
non-physical values, :func:`supports_discovery` and :func:`run_discovery` (the discovery loop
within the time budget, its failures turned into a reason), and :func:`record_names` for the
progress line.
"""

from __future__ import annotations

from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError, FitError
from dcmotor_id.core.model import inadmissible, UNITS
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.discovery import DiscoveryLoop, DiscoveryResult
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.residuals import ChannelErrors, model_errors

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import Structure
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate


def simulation_errors(estimate: Estimate, records: Sequence[Record],
                      torque_constant: float | None = None, terms: Sequence = (),
                      quasi_static: bool = False) -> ChannelErrors:
    """
    Return the simulation error of an estimate over the records (from its initial states).

    The result is ``{current_nrmse_pct, speed_nrmse_pct}``
    (:func:`dcmotor_id.identification.residuals.model_errors`); the current error is ``None`` in
    mechanical-only mode (current is the input there).
    """
    model = OutputErrorModel(records, torque_constant, terms, quasi_static)
    return model_errors(model, dict(estimate.parameters), estimate.initial_states)


def check_physical(estimate: Estimate) -> None:
    """Refuse non-physical results instead of reporting made-up numbers."""
    bad = inadmissible(estimate.parameters)
    if bad:
        listing = ', '.join(f'{name} = {value:.4g} {UNITS[name]}' for name, value in bad.items())
        hint = (' Check the signs and units of the columns (current and speed must be positive '
                'for a positive voltage).')
        if estimate.method == 'paper':
            hint += ' The paper method is also not robust to sensor noise: use --method refined.'
        raise FitError(f'the {estimate.method} method gave non-physical values: {listing}.'
                       + hint)


def supports_discovery(estimator: Any) -> bool:
    """
    Whether the discovery loop can follow this estimator (it fits effect terms).

    The :class:`~dcmotor_id.identification.estimators.base.Estimator` protocol's ``supports_terms``
    says whether the estimator fits effect terms (the refined one does, the paper's does not).
    """
    return bool(getattr(estimator, 'supports_terms', False))


def run_discovery(records: Sequence[Record], torque_constant: float | None, estimator: Any,
                  vocabulary: Sequence[type[Effect]], progress: Progress, initial_state: str,
                  quasi_static: bool = False, estimate: Estimate | None = None,
                  criterion: str = 'speed', structure: Structure | None = None,
                  position_error: str = 'adaptive'
                  ) -> tuple[DiscoveryResult | None, dict[str, Any]]:
    """
    Run the loop; return ``(DiscoveryResult or None, JSON summary or skip reason)``.

    ``structure``: effects the loop's base holds from the start (``DiscoveryLoop.run``);
    ``position_error``: the model of the position error of its fits.
    """
    if not supports_discovery(estimator):
        return None, {'skipped': f'effect discovery needs the refined method (the '
                                 f'{getattr(estimator, "name", "given")} method has no effect '
                                 'terms)'}
    try:
        found = DiscoveryLoop(records, torque_constant, vocabulary=vocabulary,
                              progress=progress, initial_state=initial_state,
                              quasi_static=quasi_static, criterion=criterion,
                              position_error=position_error).run(estimate, structure)
        check_physical(found.estimate)
    except TimeBudgetExceeded:
        return None, {'skipped': f'the time budget ({progress.max_time_s:g} s) ran out '
                                 'before effect discovery had a result: the base model is '
                                 'reported'}
    except (DcMotorIdError, np.linalg.LinAlgError) as error:
        return None, {'skipped': f'effect discovery could not run on these data: {error}'}
    return found, found.summary()


def record_names(records: Sequence[Record]) -> str | None:
    """Name the records for the progress line: the one source, or how many records."""
    names = [rec.source for rec in records if rec.source]
    if not names:
        return None
    return names[0] if len(names) == 1 else f'{len(records)} records'
