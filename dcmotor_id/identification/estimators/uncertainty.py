"""
Standard errors that hold when the residual is coloured or the model is not exact.

The Gauss-Newton covariance ``s^2 (J^T J)^-1`` of an output-error fit assumes white residuals
and an exact model.  Real residuals are coloured (a wandering load, a sensor's dynamics, an
effect the model lacks), and then it is many times too small.  The sandwich covariance
``H^-1 S H^-1`` (``H = J^T J`` of the weighted residual, ``S`` the covariance of the score
``J^T r``) does not assume either; ``S`` is estimated by *batch means*: the scores
``g_t = sum_channels J_t^T r_t`` of every sample are summed over contiguous blocks of each
record and ``S = sum_b s_b s_b^T``.  Blocks longer than the residual's correlation keep it
whole; too few blocks make ``S`` noisy, so the figure is the largest over several block counts
(8, 10 and 32 per record) and the Gauss-Newton one.  On the laboratory scenarios this gave
0.6-1.8x the Monte Carlo spread, where Newey-West with an automatic bandwidth gave 0.2x on a
servo record and the Gauss-Newton figure 1/25x (bench/lab_results.md).

The estimator delivers what is needed in ``Estimate.info`` (keys of :data:`INFO_KEYS`):
``normal_matrix`` (``J^T J`` in its internal coordinates ``z``), ``block_scores`` (score sums
over fine blocks, ``n_blocks x p``), ``block_record`` (the record of every block), ``chain``
(``d theta / d z`` per parameter) and ``residual_rms_weighted`` (``s``); :func:`block_scores`
computes the blocks from a residual and its Jacobian.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from dcmotor_id.core.model import derived_stderr

#: Keys of ``Estimate.info`` the data-based covariance reads.
INFO_KEYS = ('normal_matrix', 'block_scores', 'block_record', 'chain', 'residual_rms_weighted',
             'names')
#: Fine blocks per record (a multiple of every count of :data:`BLOCK_COUNTS`).
FINE_BLOCKS = 160
#: Blocks per record over which the batch-means covariance is taken (the largest figure).
BLOCK_COUNTS = (8, 10, 32)
#: Name of the method in the result.
METHOD = ('max(Gauss-Newton, sandwich with batch-means score covariance over 8, 10 and 32 '
          'blocks per record)')
#: Fewest samples in a fine block.
MIN_BLOCK_SAMPLES = 4


def block_edges(length: int, fine_blocks: int = FINE_BLOCKS) -> np.ndarray:
    """Return the sample edges of a record's fine blocks (``count + 1`` increasing indices)."""
    count = max(min(fine_blocks, int(length) // MIN_BLOCK_SAMPLES), 1)
    return np.linspace(0, int(length), count + 1).round().astype(np.int64)


def block_scores(residual: np.ndarray, jac: np.ndarray, record_lengths: Sequence[int],
                 n_outputs: int, fine_blocks: int = FINE_BLOCKS) -> dict[str, np.ndarray]:
    """
    Sum the per-sample scores of a weighted residual over contiguous blocks of every record.

    Parameters
    ----------
    residual : numpy.ndarray
        Weighted residual, laid out record by record, channel by channel within a record.
    jac : numpy.ndarray
        Its Jacobian (rows as ``residual``).
    record_lengths : sequence of int
        Samples of every record.
    n_outputs : int
        Channels per record.
    fine_blocks : int
        Blocks per record (fewer for short records: at least 4 samples a block).

    Returns
    -------
    dict
        ``block_scores`` (``n_blocks x p``) and ``block_record`` (record index per block).

    """
    scores, owner = [], []
    position = 0
    for index, length in enumerate(record_lengths):
        g = np.zeros((length, jac.shape[1]))
        for _ in range(n_outputs):
            rows = slice(position, position + length)
            g += jac[rows] * residual[rows, None]
            position += length
        edges = block_edges(length, fine_blocks)
        scores.append(np.add.reduceat(g, edges[:-1], axis=0))
        owner.extend([index] * (len(edges) - 1))
    return {'block_scores': np.vstack(scores) if scores else np.zeros((0, jac.shape[1])),
            'block_record': np.array(owner, dtype=int)}


def _score_covariance(scores: np.ndarray, owner: np.ndarray, blocks: int) -> np.ndarray:
    """Batch-means ``S``: fine blocks merged into ``blocks`` contiguous groups per record."""
    p = scores.shape[1]
    total = np.zeros((p, p))
    for record in np.unique(owner):
        mine = scores[owner == record]
        edges = np.linspace(0, mine.shape[0], min(blocks, mine.shape[0]) + 1).round()
        sums = np.add.reduceat(mine, edges[:-1].astype(int), axis=0)
        total += sums.T @ sums
    return total


def robust_covariance(info: dict[str, Any]) -> dict[str, Any] | None:
    """
    Return the data-based covariance of the parameters, or None when the info lacks it.

    Returns
    -------
    dict or None
        ``covariance`` (of ``info['names']``: the per-parameter largest of the Gauss-Newton
        and batch-means variances, with the correlations of the largest sandwich),
        ``stderr_model`` and ``stderr`` (arrays in the order of ``names``), ``method``.

    """
    if any(key not in info for key in INFO_KEYS):
        return None
    names = list(info['names'])
    h = np.asarray(info['normal_matrix'], dtype=float)
    scores = np.asarray(info['block_scores'], dtype=float)
    owner = np.asarray(info['block_record'], dtype=int)
    chain = np.asarray(info['chain'], dtype=float)
    s2 = float(info['residual_rms_weighted']) ** 2
    h_inv = np.linalg.pinv(h)
    model_z = s2 * h_inv
    sandwiches = [h_inv @ _score_covariance(scores, owner, k) @ h_inv for k in BLOCK_COUNTS]
    scale = np.outer(chain, chain)
    n = len(names)
    model = (model_z * scale)[:n, :n]
    variances = [np.diag(model)] + [np.diag((c * scale)[:n, :n]) for c in sandwiches]
    stacked = np.vstack(variances)
    largest = np.max(stacked, axis=0)
    # The correlations of the sandwich with the largest total relative variance.
    relative = [np.sum(v / np.maximum(np.diag(model), 1e-300)) for v in variances[1:]]
    widest = (sandwiches[int(np.argmax(relative))] * scale)[:n, :n]
    sd = np.sqrt(np.maximum(np.diag(widest), 1e-300))
    correlation = widest / np.outer(sd, sd)
    stderr = np.sqrt(np.maximum(largest, 0.0))
    covariance = correlation * np.outer(stderr, stderr)
    return {'covariance': covariance, 'stderr': stderr,
            'stderr_model': np.sqrt(np.maximum(np.diag(model), 0.0)), 'method': METHOD,
            'correlation': correlation}


def with_robust_stderr(estimate: Any) -> Any:
    """
    Return the estimate with data-based standard errors (unchanged when it has no info).

    ``stderr`` becomes the larger of the Gauss-Newton and the batch-means figure per
    parameter (Ka and Ta by the delta method on that covariance); ``info`` gains
    ``stderr_model`` (the Gauss-Newton figures), ``uncertainty_method``,
    ``robust_covariance`` and ``robust_correlation``.
    """
    robust = robust_covariance(estimate.info)
    if robust is None:
        return replace(estimate, info={**estimate.info, 'stderr_model': dict(estimate.stderr),
                                       'uncertainty_method': 'Gauss-Newton'})
    names = list(estimate.info['names'])
    stderr = dict(estimate.stderr)
    stderr.update({name: float(value) for name, value in zip(names, robust['stderr'])})
    if 'Ra' in names and 'La' in names and 'Ka' in estimate.parameters:
        stderr.update(derived_stderr(estimate.parameters, robust['covariance'], names))
    info = {**estimate.info, 'stderr_model': dict(estimate.stderr),
            'uncertainty_method': robust['method'],
            'robust_covariance': robust['covariance'],
            'robust_correlation': robust['correlation']}
    return replace(estimate, stderr=stderr, info=info)
