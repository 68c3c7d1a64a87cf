"""
The paper's structural neural identifier (the documented baseline).

Two linear neurons on the Euler-discretised motor equations (the paper's eqs. 6, 9, 17, 18 with
the corrections of shared/paper/ERRATA.md; weights named by the input they multiply)::

    N1: i(k+1) = w1 u(k) + w2 w(k) + w3 i(k)
    N2: w(k+1) = v1 i(k) + v2 w(k) + v3 sgn(w(k))

each trained with Levenberg-Marquardt on the mean squared one-step error (eq. 25); for a
linear neuron that minimiser is the least-squares solution, computed directly.  The
physical parameters follow from the weights (eqs. 13-15, 22-24)::

    CPhi = -w2/w1, Ta = dT/(1-w3), Ka = w1/(1-w3), Ra = 1/Ka, La = Ta Ra
    J = CPhi dT/v1, b = (1-v2) J/dT, Mc = -v3 J/dT

The Euler discretisation biases La and J in proportion to the sample period, and the one-step
error with measured regressors is biased by sensor noise; both are documented limits.
Standard errors are those of the linear regressions propagated to the parameters (they describe
the scatter, not these biases).
"""

from __future__ import annotations

from typing import Any, Callable, ClassVar, Sequence

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import derived_stderr, derived_values, MECHANICAL_NAMES, PARAMETER_NAMES
from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm
from dcmotor_id.identification.estimators.jacobian import jacobian


def _check_weights(divisors: dict[str, float]) -> None:
    """
    Refuse neuron weights the physical parameters are divided by when they are (about) zero.

    A window in which the voltage (or the current) does not move gives such a weight: the
    parameters would be ``inf`` (a numpy "divide by zero" warning, then nonsense); the
    refusal names the weight and what is missing.
    """
    for name, value in divisors.items():
        if not (np.isfinite(value) and abs(value) > 1e-12):
            raise FitError(f'the paper method cannot separate the parameters: its weight '
                           f'{name} is {value:.3g} (the signal it multiplies does not move '
                           'enough in these data); give a record with more excitation')


def _train_neuron(inputs, target):
    """
    Train a linear neuron on its mean squared error; return weights and covariance.

    The paper trains with Levenberg-Marquardt; on a linear neuron the error is quadratic in
    the weights and LM converges to its least-squares minimiser, computed here directly (on
    the inputs scaled to unit spread, as before), which gives the weights LM gave to 1e-12
    without importing :mod:`scipy.optimize` on the identify path (issue 11).
    """
    scale = np.maximum(np.std(inputs, axis=0), 1e-300)
    scaled = inputs / scale
    solution = np.linalg.lstsq(scaled, target, rcond=None)[0]
    if not np.all(np.isfinite(solution)):
        raise FitError('the paper method failed: a neuron weight is not finite')
    weights = solution / scale
    dof = max(target.shape[0] - inputs.shape[1], 1)
    sigma2 = np.sum((inputs @ weights - target) ** 2) / dof
    try:
        covariance = sigma2 * np.linalg.inv(inputs.T @ inputs)
    except np.linalg.LinAlgError:
        covariance = np.full((inputs.shape[1],) * 2, np.nan)
    return weights, covariance


def _propagate(function: Callable[[np.ndarray], Sequence[float]], weights: np.ndarray,
               covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values of ``function(weights)`` and their covariance by the delta method."""
    values = np.asarray(function(weights), dtype=float)
    grad = jacobian(function, weights, 1e-7 * np.maximum(np.abs(weights), 1e-12),
                    central=False, f0=values)
    return values, grad @ covariance @ grad.T


class PaperEstimator:
    """
    Faithful replication of the paper's two-neuron identifier.

    Parameters
    ----------
    n1_records, n2_records : list of int, optional
        Which of the records train N1 and N2 (the paper used a sine set for N1 and a
        sawtooth set for N2); default all records for both.

    """

    name: ClassVar[str] = 'paper'
    #: No effect terms (so no effect discovery): the neurons are the paper's model only.
    supports_terms: ClassVar[bool] = False

    def __init__(self, n1_records: Sequence[int] | None = None,
                 n2_records: Sequence[int] | None = None) -> None:
        self.n1_records = n1_records
        self.n2_records = n2_records

    def fit(self, records: Sequence[Any], torque_constant: float | None = None,
            terms: Sequence[ExogenousTerm] = ()) -> Estimate:
        """Train the neurons on the records and return the parameters."""
        if terms:
            raise FitError('the paper method has no effect terms; use the refined method')
        dt = records[0].sample_period_s
        n2_set = self.n2_records if self.n2_records is not None else range(len(records))
        n2_in, n2_out = [], []
        for index in n2_set:
            rec = records[index]
            n2_in.append(np.column_stack([rec.current[:-1], rec.speed[:-1],
                                          np.sign(rec.speed[:-1])]))
            n2_out.append(rec.speed[1:])
        v, cov_v = _train_neuron(np.vstack(n2_in), np.concatenate(n2_out))
        info = {'sample_period_s': dt, 'n2_weights': v.tolist()}
        if torque_constant is not None:
            cphi = float(torque_constant)
            _check_weights({'v1 (current in N2)': v[0]})

            def mech(weights):
                j = cphi * dt / weights[0]
                return [j, (1.0 - weights[1]) * j / dt, -weights[2] * j / dt]
            values, cov = _propagate(mech, v, cov_v)
            spread = np.sqrt(np.maximum(np.diag(cov), 0.0))
            return Estimate(self.name, dict(zip(MECHANICAL_NAMES, map(float, values))),
                            dict(zip(MECHANICAL_NAMES, map(float, spread))),
                            [(float(rec.speed[0]),) for rec in records], info)
        n1_set = self.n1_records if self.n1_records is not None else range(len(records))
        n1_in, n1_out = [], []
        for index in n1_set:
            rec = records[index]
            n1_in.append(np.column_stack([rec.voltage[:-1], rec.speed[:-1], rec.current[:-1]]))
            n1_out.append(rec.current[1:])
        w, cov_w = _train_neuron(np.vstack(n1_in), np.concatenate(n1_out))
        _check_weights({'w1 (voltage)': w[0], '1 - w3 (current memory)': 1.0 - w[2],
                        'v1 (current in N2)': v[0]})
        info['n1_weights'] = w.tolist()
        weights = np.concatenate([w, v])
        covariance = np.zeros((6, 6))
        covariance[:3, :3] = cov_w
        covariance[3:, 3:] = cov_v

        def physical(all_weights):
            w1, w2, w3, v1, v2, v3 = all_weights
            cphi = -w2 / w1
            ta = dt / (1.0 - w3)
            ka = w1 / (1.0 - w3)
            ra = 1.0 / ka
            j = cphi * dt / v1
            return [ra, ta * ra, cphi, j, (1.0 - v2) * j / dt, -v3 * j / dt]
        with np.errstate(divide='ignore', invalid='ignore'):  # non-finite: refused by callers
            values, cov = _propagate(physical, weights, covariance)
        names = PARAMETER_NAMES
        parameters = dict(zip(names, map(float, values)))
        stderr = dict(zip(names, map(float, np.sqrt(np.maximum(np.diag(cov), 0.0)))))
        parameters.update(derived_values(parameters))
        stderr.update(derived_stderr(parameters, cov, names))
        states = [(float(rec.current[0]), float(rec.speed[0])) for rec in records]
        return Estimate(self.name, parameters, stderr, states, info)
