"""
ARMA(1, q) error models of a held-out residual's AR(1) innovations (rule ``innovation-arma``).

The AR(1) error model of a position residual (:func:`~dcmotor_id.identification.discovery.
judging.residual_ar`) leaves the residual's increments.  When the noise the model integrates
is on its *input* (a logged current driving the mechanical model: errors in variables), the
increments are a slowly wandering speed error plus the differenced sensor noise of the position
(an encoder's rounding): a long positive correlation under a lag-1 correlation near -0.5.  The
t test's correlation time stops at the first negative lag and counts every increment as
independent, so a tiny effect fitted to the wander passes.  An ARMA(1, q) model of the
increments (``u[k] = phi u[k-1] + e[k] + theta_1 e[k-1] + ... + theta_q e[k-q]``), fitted by
conditional least squares (:func:`fit_arma`), removes both: its innovations are the one-step
prediction errors of the wander and the rounding, nearly white, and a white residual gives
``phi``, ``theta`` near 0 (its innovations are the residual).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

#: Largest magnitude of the AR coefficient and of the MA polynomial's partial autocorrelations
#: (stationary, invertible: the filters stay stable).
MAX_COEFFICIENT = 0.999
#: Order of the moving-average part: the rounding's increments and the wander's (an MA(2)
#: after the wander's AR root is taken out).
MA_ORDER = 2
#: Leading innovations of each piece left out of the fit (the filter's start).
BURN_IN = 5


def polynomial(partials: Sequence[float]) -> np.ndarray:
    """
    Return ``[1, c_1, ..., c_q]`` with roots outside the unit circle from partial correlations.

    Levinson-Durbin from ``partials`` in ``(-1, 1)``: ``1 - a_1 z - ... - a_q z^q`` is the
    stationary AR polynomial of those partial autocorrelations; ``c = -a``.
    """
    coefficients: list[float] = []
    for value in partials:
        coefficients = [a - value * b for a, b in zip(coefficients, coefficients[::-1])]
        coefficients.append(float(value))
    return np.concatenate([[1.0], -np.asarray(coefficients, dtype=float)])


def arma_filter(increments: np.ndarray, phi: float, theta: np.ndarray) -> np.ndarray:
    """Innovations of an ARMA(1, q) series: ``(1 - phi L) / (1 + theta_1 L + ...)`` applied."""
    from scipy.signal import lfilter

    return lfilter(np.array([1.0, -phi]), theta, np.asarray(increments, dtype=float))


def _unpack(x: np.ndarray) -> tuple[float, np.ndarray]:
    return (MAX_COEFFICIENT * float(np.tanh(x[0])),
            polynomial(MAX_COEFFICIENT * np.tanh(x[1:])))


def fit_arma(pieces: Sequence[np.ndarray], ma_order: int = MA_ORDER
             ) -> tuple[float, np.ndarray]:
    """
    ARMA(1, ``ma_order``) model of ``pieces`` (one series per record) by conditional least squares.

    Minimises the sum of the squared innovations (:func:`arma_filter`, zero initial state,
    the first :data:`BURN_IN` of each piece left out) over the AR coefficient and the MA
    polynomial's partial autocorrelations (a hyperbolic tangent keeps both inside
    :data:`MAX_COEFFICIENT`).  Returns ``(phi, [1, theta_1, ..., theta_q])``; ``(0, [1, 0..])``
    when the pieces are too short or not finite.
    """
    from scipy.optimize import minimize

    pieces = [np.asarray(piece, dtype=float) for piece in pieces
              if piece.shape[0] > BURN_IN + ma_order + 2 and np.all(np.isfinite(piece))]
    if not pieces:
        return 0.0, np.concatenate([[1.0], np.zeros(ma_order)])
    scale = float(np.sqrt(np.mean(np.concatenate(pieces) ** 2))) or 1.0
    pieces = [piece / scale for piece in pieces]

    def cost(x: np.ndarray) -> float:
        phi, theta = _unpack(x)
        return float(sum(np.sum(arma_filter(piece, phi, theta)[BURN_IN:] ** 2)
                         for piece in pieces))

    # Two starts: white increments, and a wander (an AR root near 1) under the rounding.
    best = min((minimize(cost, np.r_[phi, np.zeros(ma_order)], method='Nelder-Mead',
                         options={'xatol': 1e-4, 'fatol': 1e-9,
                                  'maxiter': 400 * (1 + ma_order)})
                for phi in (0.0, 2.5)), key=lambda result: float(result.fun))
    x = best.x if best.fun <= cost(np.zeros(1 + ma_order)) else np.zeros(1 + ma_order)
    return _unpack(np.asarray(x, dtype=float))
