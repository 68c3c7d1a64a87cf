"""
The Cramer-Rao bound of the output-error model (what no unbiased estimator can beat).

With white Gaussian noise of known standard deviation ``sigma[r, c]`` on output channel ``c``
(current, speed) of record ``r``, the Fisher information of the parameters ``theta`` is::

    F = sum_r sum_c S[r, c]^T S[r, c] / sigma[r, c]^2,    S[r, c] = d y[r, c] / d theta

where ``y[r, c]`` is the noise-free simulated output of the model at the true parameters.  The
bound on the covariance of any unbiased estimate is ``F^-1``; its diagonal square roots are the
smallest standard errors achievable.  ``theta`` holds the physical parameters of the mode
(Ra, La, CPhi, J, b, Mc; or J, b, Mc), the coefficients of any exogenous terms, and, by
default, the initial state of every record (the refined estimator estimates it too, so the
bound that applies to it treats the initial states as nuisance parameters).

The information is accumulated by the analytic-sensitivity kernel of the fit
(:mod:`dcmotor_id.identification.estimators.normal_equations`: the sensitivities propagated beside
the exact
hybrid ZOH solution, exact through speed reversals and stick phases, never stored), the same
accumulation that gives the refined estimator its standard errors.  Model variants that kernel
does not cover (effects held over sub-steps) fall back to central differences of
:class:`OutputErrorModel` simulations with a relative step of ``1e-6`` (the outputs are smooth
in the parameters between events and continuous through them: about six digits).  In
mechanical-only mode the measured current is the model's input and is taken as noise-free.
"""

from __future__ import annotations

from typing import Any, Iterator, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.core.model import derived_stderr, MotorParameters, NON_NEGATIVE_NAMES
from dcmotor_id.identification.estimators.base import ExogenousTerm
from dcmotor_id.identification.estimators.jacobian import jacobian
from dcmotor_id.identification.estimators.normal_equations import NormalEquations
from dcmotor_id.identification.estimators.refined import (has_analytic_sensitivities,
                                                          OutputErrorModel)


def _noise_table(noise_std, n_records, outputs):
    """Return ``sigma[record][channel]`` from a scalar-per-channel or per-record mapping."""
    table = []
    for index in range(n_records):
        row = {}
        for channel in outputs:
            if channel not in noise_std:
                raise ValueError(f'noise_std needs the channel {channel!r}')
            value = noise_std[channel]
            value = float(value[index]) if np.ndim(value) else float(value)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f'noise_std[{channel!r}] must be positive, got {value}')
            row[channel] = value
        table.append(row)
    return table


def output_sensitivities(model: OutputErrorModel, values: Mapping[str, float],
                         initial_states: Sequence[ArrayLike],
                         include_initial_states: bool = True, relative_step: float = 1e-6
                         ) -> tuple[list[str], list[dict[str, np.ndarray]]]:
    """
    Differentiate every simulated output with respect to the parameters.

    Parameters
    ----------
    model : OutputErrorModel
        The model and its records (only the inputs of the records are used).
    values : dict
        Parameter values by name (the base parameters and every term coefficient).
    initial_states : sequence of array_like
        Initial state of every record (``(i0, w0)``, or ``(w0,)`` mechanical-only).
    include_initial_states : bool
        Also differentiate with respect to the initial states.
    relative_step : float
        Central-difference step relative to each parameter's magnitude.

    Returns
    -------
    names : list of str
        Names of the columns (initial states as ``x0[record].channel``).
    sensitivities : list of dict
        Per record, channel -> array ``(n_samples, n_parameters)``.

    """
    names = list(model.base_names) + [term.name for term in model.terms]
    states = [np.array(state, dtype=float) for state in initial_states]
    if len(states) != len(model.records):
        raise ValueError('one initial state per record is needed')
    n_params = len(names)
    n_out = len(model.outputs)
    labels = list(names)
    if include_initial_states:
        labels += [f'x0[{index}].{channel}' for index in range(len(states))
                   for channel in model.outputs]
    result = [{channel: np.zeros((len(rec), len(labels))) for channel in model.outputs}
              for rec in model.records]
    by_parameters = _parameter_jacobians(model, values, names, states, relative_step)
    for index, matrix in enumerate(by_parameters):
        _store(model, result, index, slice(0, n_params), matrix)
    if include_initial_states:
        for index, state in enumerate(states):
            column = n_params + index * n_out
            _store(model, result, index, slice(column, column + n_out),
                   _state_jacobian(model, values, index, state, relative_step))
    return labels, result


def _simulated(model: OutputErrorModel, index: int, values: Mapping[str, float],
               state: np.ndarray) -> np.ndarray:
    """Simulate record ``index`` from ``state``; return its outputs, channels concatenated."""
    out = model.simulate(values, index, state)
    return np.concatenate([out[channel] for channel in model.outputs])


def _store(model: OutputErrorModel, result: list[dict[str, np.ndarray]], index: int,
           columns: slice, matrix: np.ndarray) -> None:
    """Write the channels' rows of ``matrix`` (concatenated) into record ``index``'s columns."""
    length = len(model.records[index])
    for position, channel in enumerate(model.outputs):
        result[index][channel][:, columns] = matrix[position * length:(position + 1) * length]


def _parameter_jacobians(model: OutputErrorModel, values: Mapping[str, float],
                         names: list[str], states: list[np.ndarray],
                         relative_step: float) -> Iterator[np.ndarray]:
    """
    Yield every record's central-difference Jacobian of its outputs by the parameters.

    The step is relative to each parameter's magnitude (at least a term's typical scale).
    """
    typical = {term.name: term.scale for term in model.terms}
    point = np.array([float(values[name]) for name in names])
    steps = relative_step * np.maximum(
        np.maximum(np.abs(point), [typical.get(name, 0.0) for name in names]), 1e-12)
    # b and Mc may be zero: a one-sided difference keeps the friction non-negative.
    lower = np.array([0.0 if name in NON_NEGATIVE_NAMES else -np.inf for name in names])
    for index, state in enumerate(states):
        def by_parameters(theta: np.ndarray, index: int = index,
                          state: np.ndarray = state) -> np.ndarray:
            return _simulated(model, index, {**values, **dict(zip(names, theta))}, state)
        yield jacobian(by_parameters, point, steps, lower=lower)


def _state_jacobian(model: OutputErrorModel, values: Mapping[str, float], index: int,
                    state: np.ndarray, relative_step: float) -> np.ndarray:
    """
    Return record ``index``'s central-difference Jacobian of its outputs by its initial state.

    The step is relative to the state's magnitude or the channel's spread, the larger.
    """
    magnitudes = [max(abs(state[position]),
                      float(np.std(getattr(model.records[index], channel))), 1e-12)
                  for position, channel in enumerate(model.outputs)]

    def by_state(start: np.ndarray) -> np.ndarray:
        return _simulated(model, index, values, start)
    return jacobian(by_state, state, relative_step * np.array(magnitudes))


def fisher_information(model: OutputErrorModel, values: Mapping[str, float],
                       initial_states: Sequence[ArrayLike], noise_std: Mapping[str, Any],
                       include_initial_states: bool = True) -> tuple[list[str], np.ndarray]:
    """
    Fisher information of the output-error model with known white noise per channel.

    Parameters
    ----------
    model : OutputErrorModel
        The model and its records.
    values : dict
        True parameter values by name.
    initial_states : sequence of array_like
        True initial state of every record.
    noise_std : dict
        Channel (``current``, ``speed``) -> noise standard deviation, a scalar for every
        record or a sequence with one value per record [A, rad/s].
    include_initial_states : bool
        Treat the initial states as unknown (nuisance) parameters.

    Returns
    -------
    names : list of str
        Parameter names of the rows and columns.
    information : numpy.ndarray
        The Fisher information matrix.

    """
    sigma = _noise_table(noise_std, len(model.records), model.outputs)
    if has_analytic_sensitivities(model):
        return _accumulated_information(model, values, initial_states, sigma,
                                        include_initial_states)
    names, sensitivities = output_sensitivities(model, values, initial_states,
                                                include_initial_states)
    information = np.zeros((len(names), len(names)))
    for index, per_channel in enumerate(sensitivities):
        for channel, matrix in per_channel.items():
            information += matrix.T @ matrix / sigma[index][channel] ** 2
    return names, information


def _accumulated_information(model, values, initial_states, sigma, include_initial_states):
    """Fisher information from the analytic kernel's ``J^T J`` (weighted by ``1/sigma``)."""
    equations = NormalEquations(model)
    states = [np.asarray(state, dtype=float) for state in initial_states]
    if len(states) != len(model.records):
        raise ValueError('one initial state per record is needed')
    n_shared = equations.n_shared
    size = n_shared + equations.n_state * len(states)
    information = np.zeros((size, size))
    for index, state in enumerate(states):
        weights = [1.0 / sigma[index][channel] for channel in model.outputs]
        columns = equations.columns(index)
        information[np.ix_(columns, columns)] += equations.record(values, index, state,
                                                                  weights).hessian
    names = list(equations.names)
    if not include_initial_states:
        return names, information[:n_shared, :n_shared]
    names += [f'x0[{index}].{channel}' for index in range(len(states))
              for channel in getattr(model, 'states', model.outputs)]
    return names, information


def cramer_rao_bound(records: Sequence[Any], truth: MotorParameters | Mapping[str, float],
                     noise_std: Mapping[str, Any], torque_constant: float | None = None,
                     terms: Sequence[ExogenousTerm] = (),
                     initial_states: Sequence[ArrayLike] | None = None,
                     include_initial_states: bool = True,
                     criterion: str = 'speed') -> dict[str, float]:
    """
    Smallest standard error of every parameter that an unbiased estimator can reach.

    Parameters
    ----------
    records : list of Record
        The experiments (their voltage, or current in mechanical-only mode, drives the model).
    truth : MotorParameters or dict
        True parameters (and term coefficients, by name).
    noise_std : dict
        Channel -> white-noise standard deviation, scalar or one per record.
    torque_constant : float, optional
        Mechanical-only mode (J, b, Mc) with this torque constant [N m/A].
    terms : sequence of ExogenousTerm
        Exogenous terms of the model.
    initial_states : sequence of array_like, optional
        True initial states; default zero (a motor at rest).
    include_initial_states : bool
        Treat the initial states as unknown, as the refined estimator does.
    criterion : str
        The channels observed (:mod:`dcmotor_id.identification.error_model.criterion`): with
        ``position``
        the noise of ``position`` [rad] is needed, and the initial position is a nuisance
        parameter.

    Returns
    -------
    dict
        Parameter name -> standard-deviation bound, in SI units (Ka and Ta by the delta method
        in the full mode).

    """
    model = OutputErrorModel(records, torque_constant, terms, criterion=criterion)
    values = truth.as_dict(derived=False) if isinstance(truth, MotorParameters) else dict(truth)
    for term in model.terms:
        values.setdefault(term.name, term.initial)
    if initial_states is None:
        initial_states = [np.zeros(len(model.states)) for _ in model.records]
    names, information = fisher_information(model, values, initial_states, noise_std,
                                            include_initial_states)
    diagonal = np.sqrt(np.diag(information))
    if np.any(diagonal == 0) or not np.all(np.isfinite(diagonal)):
        raise ValueError('the Fisher information is singular: a parameter does not affect '
                         'the outputs of these records')
    scaled = information / np.outer(diagonal, diagonal)
    covariance = np.linalg.inv(scaled) / np.outer(diagonal, diagonal)
    bound = {name: float(np.sqrt(max(covariance[position, position], 0.0)))
             for position, name in enumerate(names)}
    if not model.mechanical_only:
        base = list(model.base_names)
        bound.update(derived_stderr(values, covariance[:len(base), :len(base)], base))
    return bound
