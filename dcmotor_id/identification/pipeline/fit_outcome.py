"""
What a fit gives, as every stage measures it: its simulation errors, refused when non-physical.

:func:`simulation_errors` of an estimate over the records, :data:`NO_FIT_NRMSE_PCT` (the
error beyond which a model does not fit at all), :func:`check_physical` refusing non-physical
values (:func:`physical_errors`: both at once, for a fit every stage then carries;
:func:`physical_simulation`: with the simulation they are measured on).
"""

from __future__ import annotations

from typing import Sequence, TYPE_CHECKING


from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import inadmissible, UNITS
from dcmotor_id.identification.error_model.residuals import (ChannelErrors, model_errors,
                                                             simulated, SimulatedModel,
                                                             Simulation)
from dcmotor_id.identification.estimators.refined import OutputErrorModel

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate

#: Simulation error (percent of std) above which the model is said not to fit at all.
NO_FIT_NRMSE_PCT = 60.0


def simulation_errors(estimate: Estimate, records: Sequence[Record],
                      torque_constant: float | None = None, terms: Sequence = (),
                      quasi_static: bool = False) -> ChannelErrors:
    """
    Return the simulation error of an estimate over the records (from its initial states).

    The result is ``{current_nrmse_pct, speed_nrmse_pct}``
    (:func:`dcmotor_id.identification.error_model.residuals.model_errors`); the current error is
    ``None`` in
    mechanical-only mode (current is the input there).
    """
    model = OutputErrorModel(records, torque_constant, terms, quasi_static)
    return model_errors(model, dict(estimate.parameters), estimate.initial_states)


def physical_errors(estimate: Estimate, model: SimulatedModel) -> ChannelErrors:
    """
    Refuse a non-physical estimate (:func:`check_physical`); return its simulation errors.

    ``model``: the model on the records the estimate was fitted on.
    """
    check_physical(estimate)
    return model_errors(model, dict(estimate.parameters), estimate.initial_states)


def physical_simulation(estimate: Estimate, model: SimulatedModel) -> Simulation:
    """
    Refuse a non-physical estimate (:func:`check_physical`); return its simulation.

    ``model``: the model on the records the estimate was fitted on.  The simulation's
    ``errors`` are :func:`physical_errors`'; the later stages measure the same fit from it.
    """
    check_physical(estimate)
    return simulated(model, dict(estimate.parameters), estimate.initial_states)


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
