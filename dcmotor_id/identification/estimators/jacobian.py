"""
The one finite-difference Jacobian of the package (estimators, the delta method, bounds).

Written here rather than taken from scipy: scipy's public ``scipy.optimize.approx_fprime``
has forward differences only and adjusts the step, while the fits need central differences
(with a one-sided step at a bound, e.g. a friction that may be zero) and the delta method
reproducible forward differences; ``approx_derivative`` is private.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numpy.typing import ArrayLike


def jacobian(function: Callable[[np.ndarray], ArrayLike], x: ArrayLike, steps: ArrayLike, *,
             central: bool = True, f0: ArrayLike | None = None,
             lower: ArrayLike | None = None) -> np.ndarray:
    """
    Finite-difference Jacobian ``d function / d x``, one column per element of ``x``.

    Parameters
    ----------
    function : callable
        Maps a 1-D float array to a 1-D array (the same length for every input).
    x : array_like
        The point (1-D).
    steps : array_like
        Step of every element of ``x`` (> 0).
    central : bool
        Central differences ``(f(x + h) - f(x - h)) / 2h`` (divided by the step actually
        taken); else forward differences
        ``(f(x + h) - f0) / h``.
    f0 : array_like, optional
        ``function(x)``, for forward differences (computed when not given).
    lower : array_like, optional
        Central differences only: elements whose backward step would go below their bound
        take the one-sided difference ``(f(x + h) - f(x)) / h`` instead.

    Returns
    -------
    numpy.ndarray
        Shape ``(len(function(x)), len(x))``.

    """
    x = np.asarray(x, dtype=float)
    steps = np.broadcast_to(np.asarray(steps, dtype=float), x.shape)
    if not central and f0 is None:
        f0 = function(x.copy())
    columns = []
    for column in range(x.shape[0]):
        step = steps[column]
        up = x.copy()
        up[column] += step
        if not central:
            columns.append((np.asarray(function(up)) - f0) / step)
            continue
        down = x.copy()
        if lower is None or x[column] - step >= np.asarray(lower)[column]:
            down[column] -= step
        # The step actually taken (round-off of x + h and x - h included).
        width = up[column] - down[column]
        columns.append((np.asarray(function(up)) - np.asarray(function(down))) / width)
    return np.column_stack(columns) if columns else np.zeros((0, 0))


def record_sparse_jacobian(residual: Callable[..., list], z: np.ndarray, steps: np.ndarray,
                           parts: list, n_shared: int) -> np.ndarray:
    """
    Forward-difference Jacobian of a residual stacked record by record, initial states sparse.

    The first ``n_shared`` elements of ``z`` move every record's part; the rest are the
    records' own initial states, an equal number per record in record order, and each moves
    its record's part alone.  Their columns are the same forward differences as
    :func:`jacobian`'s (the other records' parts would be differences of identical
    simulations, exactly zero), for one record's simulation instead of all of them.

    Parameters
    ----------
    residual : callable
        ``residual(z, only=None)``: the list of the records' parts; with ``only`` (a set of
        record indices) the parts of the other records are None and not computed.
    z : numpy.ndarray
        The point (1-D).
    steps : numpy.ndarray
        Step of every element of ``z`` (> 0).
    parts : list of numpy.ndarray
        ``residual(z)``.
    n_shared : int
        Elements of ``z`` shared by all records.

    Returns
    -------
    numpy.ndarray
        Shape ``(sum of the parts' lengths, len(z))``.

    """
    z = np.asarray(z, dtype=float)
    lengths = [part.shape[0] for part in parts]
    edges = np.concatenate([[0], np.cumsum(lengths)])
    f0 = np.concatenate(parts)
    per_record = (z.shape[0] - n_shared) // max(len(parts), 1)
    jac = np.zeros((f0.shape[0], z.shape[0]))
    for column in range(z.shape[0]):
        up = z.copy()
        up[column] += steps[column]
        if column < n_shared:
            jac[:, column] = (np.concatenate(residual(up)) - f0) / steps[column]
            continue
        index = (column - n_shared) // per_record
        rows = slice(edges[index], edges[index + 1])
        moved = residual(up, {index})[index]
        jac[rows, column] = (moved - parts[index]) / steps[column]
    return jac
