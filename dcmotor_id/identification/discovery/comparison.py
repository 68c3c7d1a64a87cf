"""
Comparing two structures' held-out predictions: AR(p) error models and a Diebold-Mariano test.

The rule ``innovation-dm`` of the discovery loop (:func:`~dcmotor_id.identification.discovery.
judging.innovation_dm`) asks whether a candidate structure predicts the held-out outputs one
step ahead better than the current one, each under its own error model:

- the error model of a structure's residual on one channel is an autoregression whose order is
  chosen by the Bayesian information criterion (Schwarz 1978), fitted by least squares on the
  held-out part (:func:`fit_ar`); an input's noise integrated twice into a position (errors in
  variables) needs two or more lags, which an AR(1) model misses;
- the one-step prediction errors (innovations, :func:`ar_innovations`) of the two structures
  give a loss differential; its mean is tested by Diebold and Mariano (1995) with a long-run
  variance that the differential's own correlation cannot fool (:func:`diebold_mariano`): the
  equal-weighted cosine estimator (Mueller 2007; Lazarus, Lewis, Stock and Watson 2018), whose
  statistic is Student's t with as many degrees of freedom as cosine terms (fixed-smoothing
  inference, as Coroneo and Iacone 2020 recommend for comparing predictions), with the number
  of terms chosen from the data (:func:`cosine_terms`).

Neither scipy nor numpy has these tests (statsmodels, which has a Newey-West variance and the
AR order selection but not the fixed-smoothing test, is not a dependency); they are written
here on numpy's least squares and scipy's discrete cosine transform.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

#: Most lags of a residual's autoregressive error model (:func:`fit_ar`).
MAX_AR_ORDER = 10
#: Largest shortfall of the cosine terms' mean spectral density below the density at frequency
#: zero (:func:`cosine_terms`): it bounds the long-run variance's bias, so the test's size.
SPECTRAL_SHORTFALL = 0.02


def fit_ar(pieces: Sequence[tuple[np.ndarray, int]],
           max_order: int = MAX_AR_ORDER) -> np.ndarray:
    """
    Autoregressive error model of a residual: its coefficients, order chosen by BIC.

    ``pieces``: ``(residual of a whole record, first held-out sample)`` per record.  The
    model ``e[t] = sum_k a[k] e[t - 1 - k] + innovation`` is fitted by least squares on the
    held-out samples (lags may reach into the training part; no lag crosses a record), for
    every order up to ``max_order`` on the same samples; the order of least
    ``n log(variance) + order log(n)`` is kept.  The coefficients are not constrained to a
    stationary model: a residual the model integrates (a drift) is predicted by its
    increments.  Returns the coefficients (empty: the residual is its own innovation).
    """
    rows, targets = [], []
    for error, stop in pieces:
        error = np.asarray(error, dtype=float)
        start = max(int(stop), max_order)
        if error.shape[0] <= start:
            continue
        index = np.arange(start, error.shape[0])
        rows.append(np.stack([error[index - 1 - lag] for lag in range(max_order)], axis=1))
        targets.append(error[index])
    if not rows:
        return np.zeros(0)
    design, target = np.concatenate(rows), np.concatenate(targets)
    if not (np.all(np.isfinite(design)) and np.all(np.isfinite(target))):
        return np.zeros(0)
    n = target.shape[0]
    best, best_score = np.zeros(0), n * np.log(max(float(np.mean(target ** 2)), 1e-300))
    for order in range(1, min(max_order, n - 1) + 1):
        coefficients = np.linalg.lstsq(design[:, :order], target, rcond=None)[0]
        variance = float(np.mean((target - design[:, :order] @ coefficients) ** 2))
        score = n * np.log(max(variance, 1e-300)) + order * np.log(n)
        if score < best_score:
            best, best_score = coefficients, score
    return best


def ar_innovations(error: np.ndarray, start: int, coefficients: np.ndarray) -> np.ndarray:
    """Return the one-step prediction errors of ``error`` from sample ``start`` on."""
    error = np.asarray(error, dtype=float)
    start = max(int(start), coefficients.shape[0])
    out = error[start:].copy()
    for lag, coefficient in enumerate(coefficients):
        out -= coefficient * error[start - 1 - lag:error.shape[0] - 1 - lag]
    return out


def cosine_terms(differential: np.ndarray, shortfall: float = SPECTRAL_SHORTFALL) -> int:
    """
    Return the number of cosine terms of the long-run variance, from the data (at least 1).

    The ``j``-th term estimates the spectral density at frequency ``pi j / T``, not at zero:
    a persistent differential's density falls off within a few terms, and their mean then
    under-estimates the long-run variance (the test rejects too often).  Under an AR(1)
    approximation of the differential (the plug-in of Andrews 1991), the largest number of
    terms whose mean density stays within ``shortfall`` of the density at zero is kept
    (the size-oriented choice of Sun, Phillips and Jin 2008, here with the equal-weighted
    cosine estimator).  White noise gives half the samples; an AR(1) with coefficient 0.9
    about 12 of 1500; a random walk 1.
    """
    x = np.asarray(differential, dtype=float)
    n = x.shape[0]
    if n < 4:
        return 1
    x = x - np.mean(x)
    lagged = float(x[:-1] @ x[:-1])
    rho = float(np.clip(float(x[1:] @ x[:-1]) / lagged, -0.999, 0.999999)) if lagged > 0 else 0.0
    terms = np.arange(1, n // 2 + 1)
    density = (1.0 - rho) ** 2 / (1.0 - 2.0 * rho * np.cos(np.pi * terms / n) + rho ** 2)
    short = np.flatnonzero(np.cumsum(density) / terms < 1.0 - shortfall)
    return max(int(short[0]) if short.shape[0] else n // 2, 1)


def diebold_mariano(differential: np.ndarray) -> tuple[float, int]:
    """
    Diebold-Mariano t of a loss differential's mean, and its degrees of freedom.

    ``differential``: the first prediction's loss minus the second's, sample by sample
    (positive: the second predicts better).  The long-run variance is the mean square of
    the first ``B`` cosine transforms of the differential (equal-weighted cosine estimator,
    ``B`` from :func:`cosine_terms`); for a Gaussian differential with a flat spectrum over
    those frequencies the statistic is exactly Student's t with ``B`` degrees of freedom.
    Returns ``(t, B)``; ``(0, 0)`` when it cannot be computed.
    """
    from scipy.fft import dct

    d = np.asarray(differential, dtype=float)
    n = d.shape[0]
    if n < 4 or not np.all(np.isfinite(d)):
        return 0.0, 0
    count = cosine_terms(d)
    # dct type II: 2 sum_t d[t] cos(pi j (t + 1/2) / n); the cosine basis is orthonormal
    # with the factor sqrt(2 / n) / 2 and orthogonal to the mean.
    transforms = dct(d, type=2)[1:count + 1] * np.sqrt(2.0 / n) / 2.0
    variance = float(np.mean(transforms ** 2))
    mean = float(np.mean(d))
    if not variance > 0:
        return (np.inf if mean > 0 else 0.0), count
    return mean * np.sqrt(n) / np.sqrt(variance), count


def input_noise_innovations(error: np.ndarray, sample_period_s: float, inertia: float,
                            damping: float, torque_noise_std: float,
                            sensor_noise_std: float) -> np.ndarray | None:
    """
    One-step prediction errors of a position residual whose input carries noise (a Kalman filter).

    A shaft ``J w' = tau - b w`` driven by a logged torque whose noise (``torque_noise_std``,
    white, held over each sample) the simulation integrates twice: the residual ``e`` (the
    simulated minus the measured angle) is then the state-space process ``x[k + 1] = A x[k] +
    B n[k]``, ``e[k] = x[k][0] + v[k]`` with the sensor's noise ``v`` (``sensor_noise_std``),
    the errors-in-variables model of the residual.  The steady-state Kalman filter (the
    discrete Riccati equation, scipy) gives its innovations, white when the structure is the
    data's; they are computed as a linear filter of the residual from rest (the transient has
    settled long before the held-out part).  Returns the innovations over the whole record,
    or None when the model cannot be formed (no input noise, a non-physical inertia).
    """
    from scipy.linalg import expm, solve_discrete_are
    from scipy.signal import lfilter, ss2tf

    if not (inertia > 0 and torque_noise_std > 0 and sample_period_s > 0
            and np.isfinite(damping)):
        return None
    continuous = np.zeros((3, 3))
    continuous[0, 1], continuous[1, 1], continuous[1, 2] = 1.0, -max(damping, 0.0) / inertia, \
        1.0 / inertia
    discrete = expm(continuous * sample_period_s)  # zero-order hold of the torque
    a, b = discrete[:2, :2], discrete[:2, 2:]
    c = np.array([[1.0, 0.0]])
    process = b @ b.T * torque_noise_std ** 2
    sensor = np.array([[max(sensor_noise_std, 1e-12 * torque_noise_std) ** 2]])
    try:
        covariance = solve_discrete_are(a.T, c.T, process, sensor)
    except (ValueError, np.linalg.LinAlgError):
        return None
    gain = a @ covariance @ c.T / (c @ covariance @ c.T + sensor).item()
    # Innovation filter: x^[k+1] = (A - G C) x^[k] + G e[k], eps[k] = e[k] - C x^[k].
    numerator, denominator = ss2tf(a - gain @ c, gain, -c, np.ones((1, 1)))
    innovations = lfilter(numerator[0], denominator, np.asarray(error, dtype=float))
    return innovations if np.all(np.isfinite(innovations)) else None
