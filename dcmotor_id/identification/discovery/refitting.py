"""Fitting a structure again: open-loop outputs, the start of a refit, the all-data refit."""

from __future__ import annotations

from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.model import parameter_names
from dcmotor_id.identification.discovery.structure import _with_initial, Structure
from dcmotor_id.identification.effects import torque_spread
from dcmotor_id.identification.estimators.refined import RefinedEstimator

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate


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
    from dcmotor_id.identification.validate import Model, simulate

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
    terms = _with_initial(structure.terms(prepared, values, torque_constant), values)
    estimator = RefinedEstimator(initial=start, **options)
    return prepared, terms, estimator.fit(prepared, torque_constant=torque_constant,
                                          terms=terms)
