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

With several records a third figure enters the largest: the spread *between* the records.
Records of one motor rarely share one set of parameters exactly (each HSM150 record's friction
differs, it settles differently); blocks within a record cannot see that, so disjoint subsets
of the HSM150 records disagreed at z = 4.7 (b, the three 4-record runs) with the figures
above.  The record-level figure is a delete-one-record jackknife, linearised: ``d_r = (H -
H_r)^-1 s_r`` is the Gauss-Newton step of the fit without record ``r`` (``s_r`` its score sum,
``H_r`` its normal matrix), and the covariance ``(R - 1) / R sum_r (d_r - mean d)(d_r - mean
d)^T`` (CR3 of the cluster-robust literature).  The cluster sandwich CR1 ``R / (R - 1) sum_r
s_r s_r^T`` understates with few records of unequal weight: on the HSM150 runs it was
1.5-5.5x below the jackknife that refits each leave-one-out subset, where the linearised one
was 1.1-1.4x it on runs 2 and 3 and 2.5-3.3x on run 1 (a fit 46 % off in J); the runs' max z
fell to 0.58 (J) and 0.56 (b) (bench/real_results_coverage.md).  When one of three or more
records cannot be left out without (nearly) losing a parameter (one record per direction with
a torque offset) or carries more than 99 % of one, the cluster sandwich stands in.  On a
simulated class of 4-record halves whose friction differs record to record (10 %), the RMS z
between halves went from 3.4 to 1.5 (b) and from 3.0 to 0.8 (Mc) (a t with 3 degrees of
freedom has 1.7); with the friction shared, from 1.3-1.6 to 0.9-1.1; on the laboratory
scenarios with two records (parameters shared) the stated figure is the within-record one but
for Mc of a record pair whose load the base model lacks (2.1x) and for the servo pair that the
base model (discovery off) fits 40x off in J, whose records then disagree: 13x (J) and 9x (b)
the within-record figure (bench/records_results.md).

Two records are the jackknife's too, centred at the fit (CV3 of MacKinnon, Nielsen and Webb
2023): ``1/2 sum_r d_r d_r^T``, ``d_r`` the step to the other record's fit, unbiased for the
spread between records whatever their weights, where the cluster sandwich of two records is
unbiased only when they weigh the same (with weights 0.9 / 0.1 it has 8 % of the variance; it
can be fully downward biased when one record dominates, Hansen 2025).  A parameter that one
record alone does not determine (Coulomb friction beside a torque offset with one record per
direction) is held while the step is taken, and keeps the cluster sandwich (named in the
note: the pair does not measure its spread).  On the HSM150 opposite pairs the largest z
between pairs went from 3.2 to 2.5 (J) and from 6.9 to 2.3 (b); Mc stays at 6.7.

However it is estimated, the figure of R records rests on R - 1 degrees of freedom: from two
records a variance is a chi-square with one degree of freedom, half the time below 45 % of the
truth, and the z between two disjoint pairs is a Student t with about two degrees of freedom.
``stderr`` stays a standard error; ``between_records`` adds ``t_95`` and ``interval_95``, the
95 % interval with the t quantile of ``dof`` degrees of freedom where the record-level figure
sets ``stderr`` (12.7 for two records, 4.3 for three; Cameron and Miller 2015, Imbens and
Kolesar 2016; for two groups the t interval keeps its level even when their variances
differ, Ibragimov and Mueller 2010) and the normal 1.96 where the within-record figure does.
On a simulated class of pairs whose friction differs by 10 % it covered the population value
of b and Mc in 97 % and 94 % of the fits (the normal interval before: 90 % and 85 %)
(bench/records_few_results.md).  Three records whose information one record dominates keep
the cluster sandwich and are not covered there (see that table).  One record: nothing
changes.

The estimator delivers what is needed in ``Estimate.info`` (keys of :data:`INFO_KEYS`):
``normal_matrix`` (``J^T J`` in its internal coordinates ``z``), ``block_scores`` (score sums
over fine blocks, ``n_blocks x p``), ``block_record`` (the record of every block), ``chain``
(``d theta / d z`` per parameter) and ``residual_rms_weighted`` (``s``), and for the
jackknife over records ``record_normal_matrices`` (``J_r^T J_r`` per record; without it the
cluster sandwich); :func:`block_scores` computes the blocks from a residual and its Jacobian.
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
#: Name of the method in the result of a fit of several records (with the record-level one).
METHOD_RECORDS = ('max(Gauss-Newton, sandwich with batch-means score covariance over 8, 10 and '
                  '32 blocks per record, {})')
#: The record-level estimators by their key in ``between_records``.
RECORD_ESTIMATORS = {'jackknife': 'delete-one-record jackknife',
                     'cluster': 'record-level (cluster) sandwich'}
#: What ``between_records`` says when the cluster sandwich stands in for the jackknife.
CLUSTER_NOTE = ('a record that cannot be left out without (nearly) losing a parameter (e.g. '
                'one record per direction with a torque offset), or one that carries 99 % of '
                'one: the record-level figure is the cluster sandwich, which understates the '
                'spread when the records are few')
#: What ``between_records`` says of the parameters the jackknife of two records leaves to the
#: cluster sandwich.
PAIR_CLUSTER_NOTE = ('{}: one record alone does not determine them (e.g. Coulomb friction '
                     'beside a torque offset with one record per direction), so the pair does '
                     'not measure their spread between records: their record-level figure is '
                     'the cluster sandwich, blind to it')
#: Two-sided 95 % quantiles of Student's t with 1 to 30 degrees of freedom.
T_975 = (12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281,
         2.2010, 2.1788, 2.1604, 2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860,
         2.0796, 2.0739, 2.0687, 2.0639, 2.0595, 2.0555, 2.0518, 2.0484, 2.0452, 2.0423)
#: Two-sided 95 % quantile of the normal distribution.
Z_975 = 1.959964
#: Ridge on the correlation form of a leave-one-out normal matrix (a lost direction shows as
#: a huge variance instead of a failed inverse).
RIDGE = 1e-12
#: Variance inflation (correlation form) beyond which the record left of a pair does not
#: determine a parameter (correlation with the others beyond 1 - 5e-7; Coulomb friction beside
#: a torque offset in one direction: 5e11 on an HSM150 pair, J and b 2-100).
LOST_INFLATION = 1e6
#: Fewest samples in a fine block.
MIN_BLOCK_SAMPLES = 4
#: Parameters whose record-level figure is checked for the warning.
CORE_NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
#: Most records for the jackknife over records (more: the cluster sandwich, as good then).
JACKKNIFE_MAX_RECORDS = 30
#: What ``between_records`` says of a fit of two records.
PAIR_NOTE = ('two records give the spread between records one degree of freedom: the '
             'record-level figure is a rough guide and can be several times too small; '
             'interval_95 allows for it (Student t with 1 degree of freedom: +- 12.7 standard '
             'errors where the record-level figure sets the standard error)')
#: Growth of a reported parameter's variance without one record beyond which the jackknife
#: over records is not used (the record carries more than 99 % of that parameter's information).
LEVERAGE_LIMIT = 100.0
#: Smallest eigenvalue of a normal matrix's correlation form below which it is singular.
SINGULAR = 1e-9
#: Record-level over within-record standard error from which the records are said to disagree.
WARN_RATIO = 3.0


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
        ``block_scores`` (``n_blocks x p``), ``block_record`` (record index per block) and,
        for 2 to :data:`JACKKNIFE_MAX_RECORDS` records, ``record_normal_matrices``
        (``J_r^T J_r`` of every record, ``n_records x p x p``).

    """
    scores, owner, normals = [], [], []
    position = 0
    for index, length in enumerate(record_lengths):
        g = np.zeros((length, jac.shape[1]))
        normal = np.zeros((jac.shape[1], jac.shape[1]))
        for _ in range(n_outputs):
            rows = slice(position, position + length)
            g += jac[rows] * residual[rows, None]
            normal += jac[rows].T @ jac[rows]
            position += length
        edges = block_edges(length, fine_blocks)
        scores.append(np.add.reduceat(g, edges[:-1], axis=0))
        owner.extend([index] * (len(edges) - 1))
        normals.append(normal)
    p = jac.shape[1]
    out = {'block_scores': np.vstack(scores) if scores else np.zeros((0, p)),
           'block_record': np.array(owner, dtype=int)}
    if 1 < len(normals) <= JACKKNIFE_MAX_RECORDS:
        out['record_normal_matrices'] = np.array(normals)
    return out


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


def record_scores(scores: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """Sum the fine-block scores of every record (``n_records x p``, in record order)."""
    return np.vstack([scores[owner == record].sum(axis=0) for record in np.unique(owner)])


def _record_covariance(scores: np.ndarray, owner: np.ndarray) -> np.ndarray | None:
    """
    Record-level (cluster) ``S``: ``R / (R - 1) sum_r s_r s_r^T``; None for one record.

    ``s_r`` is the score of record ``r`` at the fit, which sums to zero over the records, so
    ``R - 1`` of them are free: the factor makes ``S`` unbiased (CR1).
    """
    if len(np.unique(owner)) < 2:
        return None
    sums = record_scores(scores, owner)
    records = sums.shape[0]
    return records / (records - 1.0) * (sums.T @ sums)


def _leave_one_out_step(h: np.ndarray, h_inv: np.ndarray, normal: np.ndarray,
                        score: np.ndarray, n_shared: int) -> np.ndarray | None:
    """
    Return the Gauss-Newton step of the fit without one record, ``(H - H_r)^-1 s_r``.

    None when ``H - H_r`` is singular, or when without the record the variance of one of the
    first ``n_shared`` parameters (those reported) would grow more than
    :data:`LEVERAGE_LIMIT` times.
    The record's own columns (its initial states) vanish from ``H - H_r`` and stay zero; the
    rest must be well determined without the record (a shared parameter seen by that record
    alone, e.g. a torque offset beside Coulomb friction with one record per direction, is not).
    """
    rest = h - normal
    diagonal = np.diag(rest)
    active = diagonal > SINGULAR * np.maximum(np.diag(h), 1e-300)
    block = rest[np.ix_(active, active)]
    scale = np.sqrt(np.diag(block))
    if np.linalg.eigvalsh(block / np.outer(scale, scale))[0] < SINGULAR:
        return None
    # Nearly lost: the step is then the subset's instability, not the fit's (leverage).
    shared = active[:n_shared]
    without = np.diag(np.linalg.inv(block))[:int(shared.sum())]
    if np.any(without > LEVERAGE_LIMIT * np.diag(h_inv)[:n_shared][shared]):
        return None
    step = np.zeros_like(score)
    step[active] = np.linalg.solve(block, score[active])
    return step


def _record_jackknife(h: np.ndarray, h_inv: np.ndarray, scores: np.ndarray, owner: np.ndarray,
                      normals: np.ndarray, n_shared: int) -> np.ndarray | None:
    """
    Delete-one-record jackknife covariance in ``z`` (linearised: one Gauss-Newton step each).

    ``(R - 1) / R sum_r (d_r - mean d)(d_r - mean d)^T`` with ``d_r`` the step of the fit
    without record ``r`` (CR3 of the cluster-robust literature); None when a record cannot be
    left out (:func:`_leave_one_out_step`) or there are only two (:func:`_pair_jackknife`).
    """
    sums = record_scores(scores, owner)
    if sums.shape[0] < 3:
        return None
    steps = []
    for score, normal in zip(sums, normals):
        step = _leave_one_out_step(h, h_inv, normal, score, n_shared)
        if step is None:
            return None
        steps.append(step)
    d = np.array(steps)
    d -= d.mean(axis=0)
    return (len(d) - 1.0) / len(d) * (d.T @ d)


def _inflation(rest: np.ndarray, active: np.ndarray, n_shared: int) -> np.ndarray:
    """
    Return the variance inflation of every shared parameter in a leave-one-out normal matrix.

    The diagonal of the inverse of its correlation form: how far the parameter is tangled
    with the others within what is left, whatever that weighs; ``inf`` for a parameter whose
    column is gone.  A tiny ridge (:data:`RIDGE`) keeps a singular direction finite and huge.
    """
    block = rest[np.ix_(active, active)]
    scale = np.sqrt(np.diag(block))
    form = block / np.outer(scale, scale) + RIDGE * np.eye(len(block))
    inflation = np.full(n_shared, np.inf)
    shared = active[:n_shared]
    inflation[shared] = np.diag(np.linalg.inv(form))[:int(shared.sum())]
    return inflation


def _pair_step(h: np.ndarray, normal: np.ndarray, score: np.ndarray,
               n_shared: int) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the Gauss-Newton step of the fit of two records without one, and what it loses.

    The shared parameters that the other record alone does not determine (variance inflation
    beyond :data:`LOST_INFLATION`: one record per direction cannot tell Coulomb friction from
    a torque offset) are held one at a time, the worst first, until the rest is determined:
    the partner left free absorbs the sum (the direction's total friction), so the step of the
    others is the one-record fit's.  No limit on the leverage here (unlike
    :func:`_leave_one_out_step`): with two records the step to the other record's fit is the
    only evidence of their spread, however unequal their weights.  Returns the step and the
    mask of lost shared parameters.
    """
    rest = h - normal
    active = np.diag(rest) > SINGULAR * np.maximum(np.diag(h), 1e-300)
    lost = _inflation(rest, active, n_shared) > LOST_INFLATION
    for _ in range(n_shared):
        inflation = _inflation(rest, active, n_shared)
        tangled = active[:n_shared] & (inflation > LOST_INFLATION)
        if not tangled.any():
            break
        active[int(np.argmax(np.where(tangled, inflation, -np.inf)))] = False
    step = np.zeros_like(score)
    if active[:n_shared].any():
        step[active] = np.linalg.solve(rest[np.ix_(active, active)], score[active])
    return step, lost


def _pair_jackknife(h: np.ndarray, scores: np.ndarray, owner: np.ndarray, normals: np.ndarray,
                    n_shared: int) -> tuple[np.ndarray, np.ndarray]:
    """
    Delete-one-record jackknife of two records, centred at the fit (CV3); and what it lacks.

    ``1/2 sum_r d_r d_r^T``, ``d_r = theta_(-r) - theta`` (the step of the fit on the other
    record alone).  Centred at the fit, not at the mean of the two steps: the latter is
    ``(d_1 - d_2)^2 / 4``, the cluster sandwich of two equal records, blind to their unequal
    weight, where this one is unbiased for the spread between records whatever the weights
    (MacKinnon, Nielsen and Webb 2023, CV3).  Returns the covariance in ``z`` and the mask of
    shared parameters that one record alone does not determine (their figure is not this).
    """
    steps, lost = [], np.zeros(n_shared, dtype=bool)
    for score, normal in zip(record_scores(scores, owner), normals):
        step, gone = _pair_step(h, normal, score, n_shared)
        steps.append(step)
        lost |= gone
    d = np.array(steps)
    return 0.5 * (d.T @ d), lost


def _between_records(h: np.ndarray, h_inv: np.ndarray, info: dict[str, Any], scores: np.ndarray,
                     owner: np.ndarray) -> tuple[np.ndarray, np.ndarray, str] | None:
    """
    Record-level covariance in ``z``, the cluster sandwich's, and the estimator's name.

    The jackknife over records when every record can be left out and the fit carries the
    records' normal matrices, else the cluster sandwich (which understates with few records).
    With two records the jackknife (:func:`_pair_jackknife`) stands for the parameters one
    record determines and the cluster sandwich for the rest: the second array is the mask of
    the shared parameters whose figure is the cluster sandwich's.  None for one record.
    """
    count = len(np.unique(owner))
    if count < 2:
        return None
    n_shared = len(info['names'])
    cluster = _record_covariance(scores, owner)
    assert cluster is not None  # several records
    cluster = h_inv @ cluster @ h_inv
    everything = np.ones(n_shared, dtype=bool)
    normals = info.get('record_normal_matrices')
    if normals is None or len(normals) != count:
        return cluster, everything, 'cluster'
    normals = np.asarray(normals, dtype=float)
    if count == 2:
        pair, lost = _pair_jackknife(h, scores, owner, normals, n_shared)
        if lost.all():
            return cluster, everything, 'cluster'
        variance = np.where(lost, np.diag(cluster)[:n_shared], np.diag(pair)[:n_shared])
        merged = pair.copy()
        merged[np.arange(n_shared), np.arange(n_shared)] = variance
        return merged, lost, 'jackknife'
    jackknife = _record_jackknife(h, h_inv, scores, owner, normals, n_shared)
    if jackknife is None:
        return cluster, everything, 'cluster'
    return jackknife, ~everything, 'jackknife'


def robust_covariance(info: dict[str, Any]) -> dict[str, Any] | None:
    """
    Return the data-based covariance of the parameters, or None when the info lacks it.

    Returns
    -------
    dict or None
        ``covariance`` (of ``info['names']``: the per-parameter largest of the Gauss-Newton,
        batch-means and (with several records) record-level variances, with the correlations
        of the largest batch-means sandwich), ``stderr_model``, ``stderr_within`` (the
        largest without the record-level figure), ``stderr_records`` (the record-level
        figure, None for one record) and ``stderr`` (arrays in the order of ``names``),
        ``records`` (how many), ``method``.

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
    within = np.max(np.vstack(variances), axis=0)
    # The correlations of the sandwich with the largest total relative variance (not of the
    # record-level one: its rank is the number of records less one).
    relative = [np.sum(v / np.maximum(np.diag(model), 1e-300)) for v in variances[1:]]
    correlation = correlation_of((sandwiches[int(np.argmax(relative))] * scale)[:n, :n])
    between = _between_records(h, h_inv, info, scores, owner)
    records, estimator, by_cluster = None, None, []
    largest = within
    if between is not None:
        records = np.sqrt(np.maximum(np.diag((between[0] * scale)[:n, :n]), 0.0))
        estimator = between[2]
        if estimator == 'jackknife':
            by_cluster = [name for name, lost in zip(names, between[1]) if lost]
        largest = np.maximum(within, records ** 2)
    stderr = np.sqrt(np.maximum(largest, 0.0))
    covariance = correlation * np.outer(stderr, stderr)
    return {'covariance': covariance, 'stderr': stderr,
            'stderr_model': np.sqrt(np.maximum(np.diag(model), 0.0)),
            'stderr_within': np.sqrt(np.maximum(within, 0.0)), 'stderr_records': records,
            'records': int(len(np.unique(owner))), 'record_estimator': estimator,
            'record_cluster': by_cluster,
            'method': (METHOD if estimator is None
                       else METHOD_RECORDS.format(RECORD_ESTIMATORS[estimator])),
            'correlation': correlation}


def correlation_of(covariance: np.ndarray) -> np.ndarray:
    """
    Return the correlation matrix of a covariance, every entry within [-1, 1].

    A sandwich is positive semi-definite in exact arithmetic only: with a parameter pressed
    to its bound (a Coulomb friction of 1e-35 N m, its variance some 1e-100) rounding leaves
    negative eigenvalues, and the quotient by the standard deviations reads correlations of
    2 or more.  The nearest positive semi-definite matrix (negative eigenvalues set to zero,
    Higham 1988) is what the data can say; numpy has no such projection.
    """
    symmetric = 0.5 * (covariance + covariance.T)
    values, vectors = np.linalg.eigh(symmetric)
    projected = (vectors * np.maximum(values, 0.0)) @ vectors.T
    sd = np.sqrt(np.maximum(np.diag(projected), 1e-300))
    correlation = np.clip(projected / np.outer(sd, sd), -1.0, 1.0)
    np.fill_diagonal(correlation, 1.0)
    return correlation


def t_quantile_95(dof: float) -> float:
    """
    Return the two-sided 95 % quantile of Student's t with ``dof`` degrees of freedom.

    Tabulated for whole numbers to 30 (:data:`T_975`), the Cornish-Fisher expansion beyond
    (within 1e-5 there), the normal 1.96 for an infinite ``dof``.  Not scipy: the identify
    path does not import it.
    """
    if not np.isfinite(dof):
        return Z_975
    if dof <= len(T_975):
        if dof < 1 or not float(dof).is_integer():
            raise ValueError(f'degrees of freedom must be a whole number >= 1, got {dof}')
        return T_975[int(dof) - 1]
    z = Z_975
    return float(z + (z ** 3 + z) / (4 * dof)
                 + (5 * z ** 5 + 16 * z ** 3 + 3 * z) / (96 * dof ** 2)
                 + (3 * z ** 7 + 19 * z ** 5 + 17 * z ** 3 - 15 * z) / (384 * dof ** 3))


def _intervals(names: Sequence[str], account: dict[str, Any], stderr: Sequence[float],
               parameters: Any) -> dict[str, Any]:
    """
    Return ``t_95`` and ``interval_95`` of :func:`between_records`.

    A parameter whose ``stderr`` the spread between the records sets (``dominant``) rests on
    ``dof`` degrees of freedom: its 95 % interval is ``+- t_(0.975, dof)`` standard errors
    (Cameron and Miller 2015, Imbens and Kolesar 2016: t with G - 1 degrees of freedom for G
    clusters; with two groups Ibragimov and Mueller 2010 show that this t interval keeps its
    level at 95 % even when the groups' variances differ).  The others' figure is the
    within-record one, which rests on many blocks: the normal 1.96.
    """
    dominant = set(account['dominant'])
    factor = {name: t_quantile_95(account['dof'] if name in dominant else np.inf)
              for name in names}
    out: dict[str, Any] = {'t_95': factor}
    if parameters is not None:
        out['interval_95'] = {
            name: [float(parameters[name] - factor[name] * error),
                   float(parameters[name] + factor[name] * error)]
            for name, error in zip(names, stderr) if name in parameters}
    return out


def between_records(names: Sequence[str], robust: dict[str, Any],
                    parameters: Any = None) -> dict[str, Any] | None:
    """
    Return the JSON account of the record-level figure (``between_records``), None for one.

    ``records`` and ``dof`` (records less one: how many independent record-level scores the
    figure rests on), ``estimator`` (``jackknife`` or ``cluster``), ``note`` (why the cluster
    sandwich, which parameters it stands for beside the jackknife of two records, and that two
    records say little of their spread; absent otherwise),
    ``stderr_within`` (Gauss-Newton and batch means, blind to a difference
    between records) and ``stderr_records`` (the record-level figure) by parameter,
    ``dominant``: the parameters whose record-level figure is the larger, i.e. whose
    ``stderr`` the spread between the records sets, and ``t_95`` / ``interval_95``
    (:func:`_intervals`; the interval with the parameters' values only).
    """
    if robust.get('stderr_records') is None:
        return None
    within = {name: float(v) for name, v in zip(names, robust['stderr_within'])}
    records = {name: float(v) for name, v in zip(names, robust['stderr_records'])}
    account = {'records': int(robust['records']), 'dof': int(robust['records']) - 1,
               'estimator': robust['record_estimator'],
               'stderr_within': within, 'stderr_records': records,
               'dominant': [name for name in names if records[name] > within[name]]}
    notes = [CLUSTER_NOTE] if robust['record_estimator'] == 'cluster' else []
    if robust.get('record_cluster'):
        notes.append(PAIR_CLUSTER_NOTE.format(', '.join(robust['record_cluster'])))
    if account['dof'] == 1:
        notes.append(PAIR_NOTE)
    if notes:
        account['note'] = '; '.join(notes)
    account.update(_intervals(names, account, robust['stderr'], parameters))
    return account


def between_record_warnings(account: dict[str, Any] | None,
                            names: Sequence[str] = CORE_NAMES) -> list[str]:
    """
    Say when the records disagree far beyond their noise (record-level figure >= 3x).

    The spread between the records then sets the standard errors, and it rests on
    ``records - 1`` degrees of freedom only: a standard error estimated from ``d`` of them is
    itself uncertain by about ``1 / sqrt(2 d)``.
    """
    if not account:
        return []
    within, records = account['stderr_within'], account['stderr_records']
    far = {name: records[name] / within[name] for name in names
           if name in within and within[name] > 0 and np.isfinite(records[name])
           and records[name] >= WARN_RATIO * within[name]}
    if not far:
        return []
    dof = account['dof']
    listing = ', '.join(f'{name} {ratio:.1f}x' for name, ratio in far.items())
    return [f'the records disagree far beyond their noise (record-level standard error / '
            f'within-record one: {listing}): the standard errors include the spread between '
            f'the {account["records"]} records, estimated from {dof} degree(s) of freedom, so '
            f'they are themselves uncertain by about {100 / np.sqrt(2 * dof):.0f} %; the '
            'records do not share one set of parameters (fit them one by one to see which '
            'differs)']


def with_robust_stderr(estimate: Any) -> Any:
    """
    Return the estimate with data-based standard errors (unchanged when it has no info).

    ``stderr`` becomes the largest of the Gauss-Newton, the batch-means and (with several
    records) the record-level figure per parameter (Ka and Ta by the delta method on that
    covariance); ``info`` gains ``stderr_model`` (the Gauss-Newton figures),
    ``uncertainty_method``, ``robust_covariance``, ``robust_correlation`` and
    ``between_records`` (:func:`between_records`).
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
            'robust_correlation': robust['correlation'],
            'between_records': between_records(names, robust, estimate.parameters)}
    return replace(estimate, stderr=stderr, info=info)
