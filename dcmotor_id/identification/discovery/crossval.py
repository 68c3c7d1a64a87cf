"""
Rules ``blocked-cv`` and ``blocked-cv-white``: blocked cross-validation over the whole records.

The held-out tests (:func:`~dcmotor_id.identification.discovery.judging.innovation_t`) see
the end of each record only: an effect whose excitation lies in the 70 % the loop trains on
does not stand out there (``bench/discovery_results.md``, round 11: 8 of the 80 current-speed
effects, training likelihood ratio 20-133, held-out t 1.4-2.6).  Here every record is cut
into :data:`FOLDS` contiguous blocks; each block is held out in turn, and the current
structure and the candidate's are both refitted on the rest (:func:`fold_outputs`): the
samples before the block and after it, each piece a record of its own with its own initial
state, a gap of the current residual's integrated correlation time
(:func:`~dcmotor_id.identification.checks.start.correlation_time`) cut on either side of the
block (:func:`training_pieces`) so that no training sample shares the held-out block's
noise.  Each refit starts from its structure's fit of the loop (a few evaluations).  The
held-out block is simulated from the record's start, as the loop's held-out end is: it
continues the simulation from the piece before it (the first block starts from the loop
fit's initial state, the only value not fitted on the other folds).

Every sample is held out exactly once, so the blocks' held-out residuals join into one
cross-validated residual per record and channel for each structure, and the two are compared
by the loop's held-out test (:func:`cross_validated_t`): the drop of their squared
innovations (each structure's AR(1) error model of its own cross-validated residual) on the
samples the noise is worth, Student's t at the held-out size
(:data:`~dcmotor_id.identification.discovery.judging.HELDOUT_ALPHA`), the channels'
variances added (Welch-Satterthwaite).  A t test on the :data:`FOLDS` per-fold gains (``K -
1`` degrees of freedom) would ask the gain to be spread over the folds, which an effect
excited in one stretch is not; pooling the held-out samples asks only that the samples
where it shows predict better than without it.

Under these rules the round's candidates that lower the training BIC are ranked by their
cross-validated cost (:func:`choose_cross_validated`; the held-out end no longer decides,
and the training cost would favour the candidate with the most coefficients: a Stribeck
friction taking up a quadratic drag); the winner must pass this test and,
where the measured current drives the model, the input noise's null
(:func:`~dcmotor_id.identification.discovery.input_null.input_noise_doubt`).  ``blocked-cv``
judges every round (no whiteness stop, as ``judged-always``); ``blocked-cv-white`` stops on a
white residual over the held-out part and the whole records (as ``whole-record-white``).
Their size and power: ``bench/bench_discovery.py`` and ``bench/bench_discovery_real.py``
(``bench/discovery_results.md``, round 12).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import parameter_names
from dcmotor_id.identification.discovery.refitting import make_estimator, open_loop_outputs
from dcmotor_id.identification.discovery.structure import with_initial
from dcmotor_id.identification.error_model.residuals import simulate_records
from dcmotor_id.identification.estimators.refined import OutputErrorModel

if TYPE_CHECKING:
    from dcmotor_id.identification.discovery.state import LoopState
    from dcmotor_id.identification.discovery.structure import Candidate, Fit

#: Contiguous blocks per record, each held out in turn.
FOLDS = 5
#: Evaluations of a fold's refit (it starts at its structure's fit on the training parts and
#: every piece at that fit's simulated state; the bound of the loop's base fit).
FOLD_MAX_NFEV = 100
#: Fewest samples of a training piece: shorter ones are left out (their initial state alone
#: would take them up).
LEAST_PIECE = 20


def fold_edges(size: int, folds: int = FOLDS) -> list[tuple[int, int]]:
    """Return the ``folds`` contiguous blocks ``(start, stop)`` of a record of ``size`` samples."""
    edges = np.linspace(0, size, folds + 1).astype(int)
    return [(int(first), int(last)) for first, last in zip(edges[:-1], edges[1:])
            if last > first]


def training_pieces(size: int, block: tuple[int, int], gap: int) -> list[tuple[int, int]]:
    """
    Return the training pieces of a record around a held-out block, ``gap`` samples off it.

    The samples before ``block`` and after it, each cut ``gap`` samples short of it; a piece
    of fewer than :data:`LEAST_PIECE` samples is left out.
    """
    pieces = [(0, block[0] - gap), (block[1] + gap, size)]
    return [(first, last) for first, last in pieces if last - first >= LEAST_PIECE]


def fold_gap(loop: LoopState, current: Fit) -> int:
    """
    Gap between a held-out block and the training pieces: the residual's correlation time.

    The integrated correlation time of the current structure's residual over the whole
    records, the largest over the output channels, rounded up; at most a quarter of the
    shortest block.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    longest = 1.0
    for channel in loop.outputs:
        for rec, sim in zip(current.records, current.simulated):
            residual = np.asarray(sim[channel] - getattr(rec, channel), dtype=float)
            longest = max(longest, correlation_time(residual[np.isfinite(residual)]))
    shortest = min(len(rec) for rec in current.records) // FOLDS
    return int(min(np.ceil(longest), max(shortest // 4, 1)))


def _piece_terms(terms: Sequence, pieces: Sequence[Sequence[tuple[int, int]]]) -> tuple:
    """Return the terms cut to the pieces (each record's regressor, piece by piece)."""
    return tuple(replace(term, regressors=tuple(
        reg[first:last] for reg, spans in zip(term.regressors, pieces)
        for first, last in spans)) for term in terms)


def _piece_states(loop: LoopState, fit: Fit,
                  pieces: Sequence[Sequence[tuple[int, int]]]) -> list[list[float]]:
    """
    Warm start of every piece's initial state: the loop fit's simulated state at its start.

    The current (full model) and the speed; the position, where the state has one, from the
    simulation when it has the position, else measured.
    """
    states = []
    for index, spans in enumerate(pieces):
        sim, rec = fit.simulated[index], fit.records[index]
        size = len(fit.estimate.initial_states[index])
        for first, _ in spans:
            state = [float(sim[channel][first]) for channel in
                     (('speed',) if loop.mechanical_only else ('current', 'speed'))]
            if size > len(state):
                source = sim['position'] if 'position' in sim else rec.position
                state.append(float(source[first]))
            states.append(state)
    return states


def _fold_simulation(loop: LoopState, fit: Fit, fold: int, gap: int) -> list[dict] | None:
    """
    Refit a structure with every record's block ``fold`` held out; simulate the whole records.

    None when the refit fails.  The refit starts from the loop's fit of the structure: its
    base values, its terms' coefficients; the position error's AR(1) coefficient of each
    record is each of its pieces'.
    """
    records = fit.records
    blocks = [fold_edges(len(rec))[min(fold, len(fold_edges(len(rec))) - 1)] for rec in records]
    pieces = [training_pieces(len(rec), block, gap) for rec, block in zip(records, blocks)]
    train = [rec.slice(first, last) for rec, spans in zip(records, pieces)
             for first, last in spans]
    if not train:
        return None
    values = fit.values
    terms = with_initial(fit.terms, values)
    start = {name: float(values[name]) for name in parameter_names(loop.mechanical_only)
             if name in values}
    position_ar = None if loop.position_ar is None else [
        loop.position_ar[index] for index, spans in enumerate(pieces) for _ in spans]
    estimator = make_estimator(loop, max_nfev=FOLD_MAX_NFEV, initial=start,
                               initial_states=_piece_states(loop, fit, pieces),
                               position_ar=position_ar, retry=False)
    try:
        with np.errstate(all='ignore'):
            estimate = estimator.fit(train, torque_constant=loop.torque_constant,
                                     terms=_piece_terms(terms, pieces))
    except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None
    states, position = [], 0
    for index, spans in enumerate(pieces):
        # A record whose first piece starts at its first sample starts from that piece's
        # fitted state; the first block held out starts from the loop fit's.
        starts_here = bool(spans) and spans[0][0] == 0
        states.append(estimate.initial_states[position] if starts_here
                      else fit.estimate.initial_states[index])
        position += len(spans)
    estimate = replace(estimate, initial_states=states)
    if loop.criterion != 'speed' and len(fit.structure) and not loop.quasi_static:
        return open_loop_outputs(fit.structure, estimate, records, loop.torque_constant)
    model = OutputErrorModel(records, loop.torque_constant, terms, loop.quasi_static,
                             loop.criterion)
    return simulate_records(model, estimate.parameters, states)


def fold_outputs(loop: LoopState, fit: Fit, gap: int) -> list[dict[str, np.ndarray]] | None:
    """
    Return a structure's cross-validated residual per record and output channel, or None.

    Block ``k`` of every record holds the residual of the refit with block ``k`` held out
    (:func:`_fold_simulation`); None when a fold's refit fails.  Kept in ``fit.info`` (the
    current structure's serves every candidate of a round).
    """
    key = f'cross_validated_{gap}'
    if key in fit.info:
        return fit.info[key]
    residuals = [{channel: np.full(len(rec), np.nan) for channel in loop.outputs}
                 for rec in fit.records]
    for fold in range(FOLDS):
        simulated = _fold_simulation(loop, fit, fold, gap)
        if simulated is None:
            return None
        for rec, sim, out in zip(fit.records, simulated, residuals):
            edges = fold_edges(len(rec))
            if fold >= len(edges):
                continue
            first, last = edges[fold]
            for channel in loop.outputs:
                out[channel][first:last] = (sim[channel][first:last]
                                            - getattr(rec, channel)[first:last])
    fit.info[key] = residuals
    return residuals


def _innovations(residual: np.ndarray) -> tuple[np.ndarray, float]:
    """
    Return the AR(1) innovations of a cross-validated residual and their variance.

    Innovation ``k`` is of sample ``k + 1``.  The residual's blocks come from different
    refits: the innovation of each block's first sample (its step from the block before) is
    NaN, and no lag-1 product crosses a block's edge (a drifting position residual jumps
    there, which would swamp its increments).
    """
    from dcmotor_id.identification.error_model.criterion import MAX_POSITION_AR

    residual = np.asarray(residual, dtype=float)
    edges = [first for first, _ in fold_edges(residual.shape[0])[1:]]
    finite = np.where(np.isfinite(residual), residual, 0.0)
    finite_pairs = finite[1:] * finite[:-1]
    finite_pairs[[edge - 1 for edge in edges]] = 0.0
    previous = finite[:-1] ** 2
    previous[[edge - 1 for edge in edges]] = 0.0
    lagged = float(np.sum(previous))
    rho = float(np.clip(np.sum(finite_pairs) / lagged, 0.0, MAX_POSITION_AR)) \
        if lagged > 0 else 0.0
    innovations = residual[1:] - rho * residual[:-1]
    innovations[[edge - 1 for edge in edges]] = np.nan
    finite_innovations = innovations[np.isfinite(innovations)]
    variance = float(np.mean(finite_innovations ** 2)) if finite_innovations.shape[0] else 0.0
    return innovations, max(variance, 1e-300)


def _paired(loop: LoopState, fits: tuple[Fit, Fit], residuals: tuple[list, list],
            channel: str) -> tuple[np.ndarray, np.ndarray, float]:
    """
    Both structures' cross-validated innovations of one channel on the same raw samples.

    A data effect (a sensor delay) shifts and trims its structure's records
    (:func:`~dcmotor_id.identification.discovery.judging.measured_offset`): the innovations
    are paired by the raw measured sample.  Returns the current's, the candidate's and the
    current's innovation variance (their scale).
    """
    from dcmotor_id.identification.discovery.judging import measured_offset

    pairs, variances = [], []
    for index in range(len(fits[0].records)):
        series = []
        for fit, residual in zip(fits, residuals):
            innovations, variance = _innovations(residual[index][channel])
            # Innovation k is of sample k + 1 of the fit's record.
            series.append((innovations, measured_offset(fit, channel) + 1))
            variances.append(variance)
        first = max(offset for _, offset in series)
        last = min(values.shape[0] + offset for values, offset in series)
        if last > first:
            pairs.append([values[first - offset:last - offset] for values, offset in series])
    scale = float(np.mean(variances[::2])) if variances else 1.0
    if not pairs:
        return np.zeros(0), np.zeros(0), scale
    before = np.concatenate([pair[0] for pair in pairs])
    after = np.concatenate([pair[1] for pair in pairs])
    finite = np.isfinite(before) & np.isfinite(after)
    return before[finite], after[finite], scale


def cross_validated_t(loop: LoopState, current: Fit, fitted: Fit) -> tuple[float, float]:
    """
    Student t of the cross-validated drop of the innovations, and the samples it is worth.

    Both structures' cross-validated residuals (:func:`fold_outputs`, the gap of
    :func:`fold_gap`) are whitened by each one's AR(1) model; per output channel the drop of
    the squared innovations (the current's variance its scale) and its chance part
    ``2 a (a - b)`` give the t on the samples over the larger integrated correlation time,
    the channels' variances added (Welch-Satterthwaite), as
    :func:`~dcmotor_id.identification.discovery.judging.innovation_t` does on the held-out
    end.  ``(0, 0)`` when a fold's refit fails.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    gap = fold_gap(loop, current)
    residuals = (fold_outputs(loop, current, gap), fold_outputs(loop, fitted, gap))
    if residuals[0] is None or residuals[1] is None:
        return 0.0, 0.0
    total, variances, dofs = 0.0, [], []
    for channel in loop.outputs:
        before, after, scale = _paired(loop, (current, fitted), (residuals[0], residuals[1]),
                                       channel)
        if before.shape[0] < 3:
            return 0.0, 0.0
        drop = (before ** 2 - after ** 2) / scale
        chance = 2.0 * after * (after - before) / scale
        effective = max(drop.shape[0] / max(correlation_time(after), correlation_time(chance)),
                        2.0)
        total += float(np.mean(drop))
        variances.append(float(np.var(chance, ddof=1)) / effective)
        dofs.append(effective - 1.0)
    variance = float(sum(variances))
    worth = 1.0 + variance ** 2 / max(sum(v ** 2 / d for v, d in zip(variances, dofs)),
                                      1e-300)
    t = total / np.sqrt(variance) if variance > 0 else (np.inf if total > 0 else 0.0)
    return float(t), float(worth)


def cross_validated_cost(loop: LoopState, fit: Fit, gap: int) -> float:
    """
    Weighted mean squared cross-validated residual of a structure, summed over the outputs.

    The loop's cost (:func:`~dcmotor_id.identification.discovery.refitting.cost`) on the
    residual of :func:`fold_outputs`; ``inf`` when a fold's refit fails.
    """
    residuals = fold_outputs(loop, fit, gap)
    if residuals is None:
        return float('inf')
    total = 0.0
    for channel in loop.outputs:
        joined = np.concatenate([residual[channel] for residual in residuals])
        with np.errstate(all='ignore'):
            value = float(np.mean(joined ** 2)) / loop.fitted_weights[channel] ** 2
        total += value if np.isfinite(value) else np.inf
    return total


def choose_cross_validated(loop: LoopState, current: Fit, admissible: Sequence[Candidate],
                           order: dict[str, int]) -> tuple[Candidate | None, list[Candidate]]:
    """
    Return the candidate of lowest cross-validated cost when it is below the current's.

    Among the admissible candidates that lower the training BIC; the candidates within
    :data:`~dcmotor_id.identification.discovery.judging.TIE_SHARE` of the best one's drop tie
    with it and the earliest in the vocabulary wins (the others are its equivalents).
    """
    from dcmotor_id.identification.discovery.judging import TIE_SHARE

    lowering = [candidate for candidate in admissible if float(candidate.bic_delta or 0.0) < 0.0]
    if not lowering:
        return None, []  # no refit of the folds
    gap = fold_gap(loop, current)
    before = cross_validated_cost(loop, current, gap)
    if not np.isfinite(before):
        return None, []
    scored = [(cross_validated_cost(loop, candidate.fitted, gap), candidate)
              for candidate in lowering]
    drop = before - min(value for value, _ in scored)
    if not drop > 0:
        return None, []
    ties = [candidate for value, candidate in scored if before - value >= TIE_SHARE * drop]
    winner = min(ties, key=lambda candidate: order[candidate.name])
    return winner, [candidate for candidate in ties if candidate is not winner]


def unearned_cross_validated(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why a winning candidate has not earned its place by blocked cross-validation, or None.

    Its cross-validated t (:func:`cross_validated_t`) must reach
    :func:`~dcmotor_id.identification.discovery.judging.heldout_t_threshold` on its effective
    samples; where the current drives the model, its coefficients must stand out of the input
    noise's null.  The evidence is kept in the candidate's fit (``info['cross_validation']``,
    the round's report).
    """
    from dcmotor_id.identification.discovery.input_null import input_noise_doubt
    from dcmotor_id.identification.discovery.judging import HELDOUT_ALPHA, heldout_t_threshold

    t, effective = cross_validated_t(loop, current, candidate.fitted)
    required = heldout_t_threshold(effective)
    candidate.fitted.info['cross_validation'] = {
        'folds': FOLDS, 't': t, 't_needed': required, 'effective_innovations': effective}
    if not effective:
        return 'a refit of blocked cross-validation failed: not judged'
    if t < required:
        return (f'its cross-validated gain is not significant (t = {t:.2g} on {effective:.0f} '
                f'effective innovations over {FOLDS} blocks held out in turn, t >= '
                f'{required:.3g} needed)')
    return input_noise_doubt(loop, candidate, HELDOUT_ALPHA)
