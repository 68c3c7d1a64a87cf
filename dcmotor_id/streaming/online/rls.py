"""
The old online estimator: recursive least squares on the exactly discretised neurons.

Kept for comparison (``online_method: rls``, bench/bench_online.py) and because it costs about
a microsecond a sample; :mod:`dcmotor_id.streaming.online.window` is the default, noise-consistent
one.

Between speed reversals the motor is linear with the voltage held over each sample, so the
exact zero-order-hold discretisation is, with ``s_k = sgn(w_k)``::

    i(k+1) - i(k) = (Phi - I)[0] [i(k), w(k)] + Gu[0] u(k) + Gs[0] s_k      (neuron 1)
    w(k+1) - w(k) = (Phi - I)[1] [i(k), w(k)] + Gu[1] u(k) + Gs[1] s_k      (neuron 2)

with ``Phi = exp(A dt)``, ``Gu = M [1/La, 0]``, ``Gs = M [0, -Mc/J]`` and
``M = A^-1 (Phi - I)``. Unlike the paper's Euler neurons this has no discretisation bias at
any sample period. Both neurons share one regressor ``[i, w, u, s]``, so one recursive least
squares (RLS) with exponential forgetting updates them together, sample by sample (a numba
kernel: about a microsecond a sample). Pairs where the speed changes sign or is exactly zero
inside the step (reversal, stiction) are skipped, since the model above does not hold there.

The physical parameters follow from ``A = logm(Phi)/dt`` and ``B = M^-1 G``::

    La = 1/Bu[0], Ra = -A[0,0] La, CPhi = -A[0,1] La, J = CPhi/A[1,0], b = -A[1,1] J,
    Mc = -Bs[1] J

Their standard errors come from the RLS covariance (``P`` times each neuron's innovation
variance) by the delta method. The estimate is flagged *converged* when every physical
parameter is positive (``b`` and ``Mc`` non-negative) and has a relative standard error
below ``converged_rel_stderr``.

The regressors are measured, so sensor noise biases this equation-error estimate the way it
biases the paper's neurons; the offline output-error fit
(:mod:`dcmotor_id.identification.identify`) is the
accurate one. The online estimate tracks slow changes and tells whether the data excite the
motor.
"""

from __future__ import annotations

import cmath
import math
from typing import Any, Mapping

from numba import njit
import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.core.model import derived_values
from dcmotor_id.identification.estimators.jacobian import jacobian
from dcmotor_id.streaming.online.estimate import is_converged, NAMES, OnlineEstimate

__all__ = ['log2x2', 'physical_from_discrete', 'RlsEstimator']
_N_REGRESSORS = 4


@njit(cache=True)
def _rls_block(phi, target, use, theta, cov, forgetting, trace_cap, err_sq):
    """Update ``theta`` (4x2), ``cov`` (4x4) and ``err_sq`` (2) in place; return updates."""
    n_used = 0
    px = np.empty(4)
    for k in range(phi.shape[0]):
        if not use[k]:
            continue
        x = phi[k]
        denom = forgetting
        for r in range(4):
            acc = 0.0
            for c in range(4):
                acc += cov[r, c] * x[c]
            px[r] = acc
            denom += x[r] * acc
        for out in range(2):
            predicted = 0.0
            for r in range(4):
                predicted += theta[r, out] * x[r]
            error = target[k, out] - predicted
            err_sq[out] = forgetting * err_sq[out] + (1.0 - forgetting) * error * error
            for r in range(4):
                theta[r, out] += px[r] / denom * error
        trace = 0.0
        for r in range(4):
            for c in range(4):
                cov[r, c] -= px[r] * px[c] / denom
            trace += cov[r, r]
        if trace < trace_cap:
            for r in range(4):
                for c in range(4):
                    cov[r, c] /= forgetting
        for r in range(4):
            for c in range(r + 1, 4):
                mean = 0.5 * (cov[r, c] + cov[c, r])
                cov[r, c] = mean
                cov[c, r] = mean
        n_used += 1
    return n_used


def log2x2(matrix: np.ndarray) -> np.ndarray | None:
    """
    Return the real principal logarithm of a real 2x2 matrix, or None if it has none.

    Closed form (Sylvester's formula on the eigenvalues), exact to round-off and about a
    hundred times cheaper than a general matrix logarithm; a repeated eigenvalue uses the
    Jordan form ``log(l) I + (M - l I)/l``.
    """
    (a, b), (c, d) = matrix
    half_trace = 0.5 * (a + d)
    discriminant = (0.5 * (a - d)) ** 2 + b * c
    root = cmath.sqrt(discriminant)
    first, second = half_trace + root, half_trace - root
    if discriminant >= 0 and (first <= 0 or second <= 0):
        return None  # a non-positive real eigenvalue: no real logarithm
    identity = np.eye(2)
    if abs(root) <= 1e-12 * abs(half_trace):
        return math.log(half_trace) * identity + (matrix - half_trace * identity) / half_trace
    log_first, log_second = cmath.log(first), cmath.log(second)
    result = (log_first * (matrix - second * identity)
              - log_second * (matrix - first * identity)) / (first - second)
    return np.real(result)


def physical_from_discrete(theta: ArrayLike, sample_period_s: float) -> dict[str, float]:
    """
    Physical parameters from the neuron weights ``theta`` (4x2, columns di and dw).

    Returns a dict with Ra, La, CPhi, J, b, Mc, Ka, Ta (NaN when the weights do not map to a
    motor, e.g. before any excitation).
    """
    theta = np.asarray(theta, dtype=float)
    phi = np.eye(2) + theta[:2, :].T
    gain_u = theta[2, :]
    gain_s = theta[3, :]
    nan = {name: float('nan') for name in NAMES}
    if not np.all(np.isfinite(phi)):
        return nan
    with np.errstate(all='ignore'):
        a_matrix = log2x2(phi)
        if a_matrix is None:
            return nan
        a_matrix = a_matrix / sample_period_s
        try:
            integral = np.linalg.solve(a_matrix, phi - np.eye(2))
            b_u = np.linalg.solve(integral, gain_u)
            b_s = np.linalg.solve(integral, gain_s)
        except np.linalg.LinAlgError:
            return nan
        la = 1.0 / b_u[0]
        ra = -a_matrix[0, 0] * la
        cphi = -a_matrix[0, 1] * la
        inertia = cphi / a_matrix[1, 0]
        values = {'Ra': ra, 'La': la, 'CPhi': cphi, 'J': inertia,
                  'b': -a_matrix[1, 1] * inertia, 'Mc': -b_s[1] * inertia}
        values.update(derived_values(values))
    return {name: float(value) for name, value in values.items()}


class RlsEstimator:
    """
    Recursive least squares on the exactly discretised neurons (an ``OnlineEstimator``).

    Parameters
    ----------
    sample_period_s : float
        Sample period of the data fed in [s].
    memory_s : float
        Time constant of the exponential forgetting [s]: older samples weigh
        ``exp(-age / memory_s)``.
    converged_rel_stderr : float
        Relative standard error every parameter must be below for ``converged``.
    initial_covariance : float
        Initial ``P`` (identity times this) on the normalised regressors.

    """

    method = 'rls'

    def __init__(self, sample_period_s: float, memory_s: float = 10.0,
                 converged_rel_stderr: float = 0.05, initial_covariance: float = 1e4) -> None:
        if not sample_period_s > 0:
            raise ValueError('sample_period_s must be positive')
        if not memory_s > 0:
            raise ValueError('memory_s must be positive')
        self.sample_period_s = float(sample_period_s)
        self.memory_s = float(memory_s)
        self.converged_rel_stderr = float(converged_rel_stderr)
        self.forgetting = float(np.exp(-self.sample_period_s / self.memory_s))
        self.baseline_window_s = 2.0 * self.memory_s
        self._initial_covariance = float(initial_covariance)
        self.reset()

    @classmethod
    def from_options(cls, sample_period_s: float, options: Mapping[str, Any]) -> 'RlsEstimator':
        """
        Build from the node's options: ``memory_s``, ``converged_rel_stderr``.

        With ``window_s``, the baseline window is the shorter of it and two memories.
        """
        estimator = cls(sample_period_s, options.get('memory_s', 10.0),
                        options.get('converged_rel_stderr', 0.05))
        if 'window_s' in options:
            estimator.baseline_window_s = min(float(options['window_s']),
                                              estimator.baseline_window_s)
        return estimator

    def flush(self) -> None:
        """Nothing is buffered: every sample is used as it comes."""

    def close(self) -> None:
        """Nothing to release."""

    def reset(self) -> None:
        """Forget everything."""
        self._theta = np.zeros((_N_REGRESSORS, 2))
        self._cov = np.eye(_N_REGRESSORS) * self._initial_covariance
        self._err_sq = np.zeros(2)
        self._scale: np.ndarray | None = None
        self._last: tuple[float, float, float] | None = None
        self.n_updates = 0
        self.n_samples = 0

    @property
    def time_s(self) -> float:
        """Return the data time fed so far [s] (gaps not counted)."""
        return self.n_samples * self.sample_period_s

    def break_continuity(self) -> None:
        """Declare a gap: the next sample is not the successor of the last one."""
        self._last = None

    def update(self, voltage: ArrayLike, current: ArrayLike, speed: ArrayLike) -> int:
        """Feed consecutive samples (arrays of equal length, continuing the previous call)."""
        voltage = np.asarray(voltage, dtype=float).ravel()
        current = np.asarray(current, dtype=float).ravel()
        speed = np.asarray(speed, dtype=float).ravel()
        if not voltage.size == current.size == speed.size:
            raise ValueError('voltage, current and speed must have the same length')
        if voltage.size == 0:
            return 0
        self.n_samples += voltage.size
        if self._last is not None:
            voltage = np.concatenate([[self._last[0]], voltage])
            current = np.concatenate([[self._last[1]], current])
            speed = np.concatenate([[self._last[2]], speed])
        self._last = (voltage[-1], current[-1], speed[-1])
        if voltage.size < 2:
            return 0
        if self._scale is None:
            self._scale = np.array([max(np.max(np.abs(current)), 1e-9),
                                    max(np.max(np.abs(speed)), 1e-9),
                                    max(np.max(np.abs(voltage)), 1e-9), 1.0])
        sign = np.sign(speed)
        phi = np.column_stack([current[:-1], speed[:-1], voltage[:-1], sign[:-1]]) / self._scale
        target = np.column_stack([np.diff(current), np.diff(speed)])
        use = (sign[:-1] != 0) & (sign[:-1] == sign[1:]) & np.all(np.isfinite(phi), axis=1) \
            & np.all(np.isfinite(target), axis=1)
        used = _rls_block(np.ascontiguousarray(phi), np.ascontiguousarray(target), use,
                          self._theta, self._cov, self.forgetting,
                          1e3 * _N_REGRESSORS * self._initial_covariance, self._err_sq)
        self.n_updates += int(used)
        return int(used)

    def _weights(self, scaled_theta):
        return scaled_theta / self._scale[:, None]

    def estimate(self) -> OnlineEstimate:
        """Return the current :class:`OnlineEstimate` (parameters, stderr, convergence)."""
        rms = {'current': float(np.sqrt(self._err_sq[0])),
               'speed': float(np.sqrt(self._err_sq[1]))}
        nan = {name: float('nan') for name in NAMES}
        if self._scale is None or self.n_updates < 2 * _N_REGRESSORS:
            return OnlineEstimate(nan, dict(nan), False, rms, self.n_updates, method='rls',
                                  time_s=self.n_samples * self.sample_period_s)
        theta = self._theta.copy()
        values = physical_from_discrete(self._weights(theta), self.sample_period_s)
        stderr = dict(nan)
        if all(np.isfinite(list(values.values()))):
            # delta method over the 8 weights; each neuron's covariance is P * its noise var
            flat = theta.ravel(order='F')
            base = np.array([values[name] for name in NAMES])

            def physical(weights: np.ndarray) -> np.ndarray:
                moved = physical_from_discrete(
                    self._weights(weights.reshape(theta.shape, order='F')),
                    self.sample_period_s)
                return np.array([moved[name] for name in NAMES])
            jac = jacobian(physical, flat, 1e-6 * np.maximum(np.abs(flat), 1e-9),
                           central=False, f0=base)
            # cov(theta) of one neuron ~ P * its innovation variance (slightly conservative
            # with forgetting: the exact factor tends to 1/2 as the memory grows)
            covariance = np.zeros((flat.size, flat.size))
            for out in range(2):
                block = slice(out * _N_REGRESSORS, (out + 1) * _N_REGRESSORS)
                covariance[block, block] = self._cov * self._err_sq[out]
            with np.errstate(invalid='ignore'):
                spread = np.sqrt(np.maximum(np.diag(jac @ covariance @ jac.T), 0.0))
            stderr = {name: float(value) for name, value in zip(NAMES, spread)}
        converged = is_converged(values, stderr, self.converged_rel_stderr)
        return OnlineEstimate(values, stderr, converged, rms, self.n_updates, method='rls',
                              time_s=self.n_samples * self.sample_period_s,
                              window_s=self.memory_s)
