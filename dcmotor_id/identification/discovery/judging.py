"""
Judging candidates on the held-out parts: gain, its noise and t, the round's choice.

A refitted candidate is scored (:func:`score`); the best admissible one that gains enough is
chosen (:func:`choose`) if it has earned its place (:func:`unearned`), else the next best is
considered (:func:`decide`).  The loop never ends worse than its base model
(:func:`never_worse`).

Earned (rule ``heldout-t``): the held-out drop is significant on the samples it is worth
(:func:`heldout_t`, the residual's correlation time) and spread over the held-out part
(:func:`gain_t`).  Rule ``innovation-t``: the same on the innovations of an
AR(1) error model of each structure's held-out residual (:func:`innovation_t`): a drifting
residual (a position the model integrates) is judged on its increments, which are worth
many samples where the drift is worth a handful.  Rule ``innovation-t-null`` (the default):
innovation-t, and a mechanical-only candidate's t beyond a parametric bootstrap of the
current structure with the input current's noise
(:mod:`~dcmotor_id.identification.discovery.bootstrap`).  Rule ``innovation-dm``: a Diebold-Mariano
test of the held-out one-step predictions, each structure under its own error model (an AR(p)
by BIC, or the Kalman filter of a noisy input current integrated into the position), with a
long-run variance that follows the differential's correlation (:func:`innovation_dm`,
:mod:`~dcmotor_id.identification.discovery.comparison`).  Every rule is measured beside the
others by ``bench/bench_discovery.py`` (a column per rule).  The former rules (an effect's own
part of the outputs against the per-sample noise, a cogging ripple above the Coulomb
friction needing twice the evidence: ``noise-level``) were deleted when innovation-t-null
became the default; their last measurements are in ``bench/discovery_results.md``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, cast, Sequence

import numpy as np

from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Fit


#: Contiguous blocks of the held-out part whose error drops give the noise of the gain.
HELDOUT_BLOCKS = 8
#: Standard errors of the held-out drop a candidate's gain must exceed.
GAIN_NOISE_FACTOR = 2.0
#: Candidates explaining at least this share of the best one's improvement tie with it.
TIE_SHARE = 0.98
#: Blocks per record's held-out part of the gain's t statistic (:func:`gain_t`).
GAIN_BLOCKS = 8
#: Least t of the held-out gain for an effect to be added.
GAIN_T = 2.0
#: Nominal one-sided size of the held-out t test (:func:`heldout_t_threshold`): t >= 3 on
#: many samples; the false-effect rate and the power are measured by
#: ``bench/bench_discovery.py`` (a column per rule) and ``bench/bench_discovery_real.py``.
HELDOUT_ALPHA = 0.00135


def heldout_gain_noise(current: Fit, candidate: Fit, outputs: Sequence[str],
                       weights: dict[str, float]) -> float:
    """
    Noise of a candidate's relative held-out gain: two standard errors of the error drop.

    The weighted squared held-out errors of both fits (the held-out cost's terms) are
    subtracted sample by sample and summed over :data:`HELDOUT_BLOCKS` contiguous blocks;
    the blocks' spread gives the standard error of the total drop (blocks far longer than the
    residual's correlation are nearly independent; shorter ones make it conservative).
    Returns ``GAIN_NOISE_FACTOR`` times it relative to the current held-out cost (``inf``
    when it cannot be computed).
    """
    drop = None
    for channel in outputs:
        before = current.channel_residual(channel, 'heldout')
        after = candidate.channel_residual(channel, 'heldout')
        # A data effect (a sensor delay) shifts the records by a few samples: the common end.
        common = min(before.shape[0], after.shape[0])
        before, after = before[before.shape[0] - common:], after[after.shape[0] - common:]
        if common < 2 * HELDOUT_BLOCKS:
            return float('inf')
        term = (before ** 2 - after ** 2) / (max(weights.get(channel, 1.0), 1e-300) ** 2
                                             * before.shape[0])
        drop = term if drop is None else drop + term
    if drop is None or not np.all(np.isfinite(drop)) or current.heldout_cost <= 0.0:
        return float('inf')
    sums = np.array([part.sum() for part in np.array_split(drop, HELDOUT_BLOCKS)])
    stderr = float(np.sqrt(HELDOUT_BLOCKS) * np.std(sums, ddof=1))
    return GAIN_NOISE_FACTOR * stderr / current.heldout_cost


def never_worse(base: Fit, final: Fit, reason: str) -> tuple[Fit, str]:
    """Return the final structure, or the base one when it is not better on the held-out part."""
    if final is base or final.heldout_cost < base.heldout_cost:
        return final, reason
    return base, (reason + '; the effects found did not lower the held-out error of the base '
                  'model, which is kept')


def bic(loop: LoopState, fitted: Fit) -> float:
    """Bayesian information criterion of a fit's training cost (initial states counted)."""
    n = max(fitted.n_train, 1)
    n_parameters = len(fitted.estimate.parameters) + len(fitted.records) * len(loop.outputs)
    return float(n * np.log(max(fitted.train_cost, 1e-300)) + n_parameters * np.log(n))


def score(loop: LoopState, current: Fit, candidate: Candidate) -> Candidate:
    """Return the candidate with its held-out gain and BIC change (None if not refitted)."""
    if candidate.fit is None:
        return candidate
    return replace(candidate, gain=1.0 - candidate.fit.heldout_cost / current.heldout_cost,
                   bic_delta=bic(loop, candidate.fit) - bic(loop, current),
                   insample_gain=1.0 - candidate.fit.train_cost / current.train_cost,
                   gain_noise=heldout_gain_noise(current, candidate.fit, loop.outputs,
                                                 dict(loop.weights or {})))


def choose(loop: LoopState, current: Fit, admissible: list[Candidate],
           order: dict[str, int]) -> tuple[Candidate | None, list[Candidate]]:
    """Return the best admissible candidate when it gains enough (and its ties), else None."""
    drop = current.heldout_cost - admissible[0].fitted.heldout_cost if admissible else 0.0
    if not drop > 0:
        return None, []
    ties = [candidate for candidate in admissible
            if current.heldout_cost - candidate.fitted.heldout_cost >= TIE_SHARE * drop]
    winner = min(ties, key=lambda candidate: order[candidate.name])
    # Refitted candidates are scored: gain, bic_delta and gain_noise are set.
    gain, bic_delta = cast(float, winner.gain), cast(float, winner.bic_delta)
    noise = winner.gain_noise
    if gain >= loop.min_gain and bic_delta < 0 and (noise is None or gain > noise):
        return winner, [candidate for candidate in ties if candidate is not winner]
    return None, []


def decide(loop: LoopState, current: Fit, refitted: list[Candidate],
           order: dict[str, int]) -> tuple[Candidate | None, list[Candidate], list[Candidate]]:
    """
    Choose the effect of a round among the refitted candidates (best held-out cost first).

    The best admissible candidate that gains enough (:func:`choose`) must also have earned
    its place (:func:`unearned`); a winner that has not is rejected (its ``problem`` says
    why) and the next best is considered in its place.  Returns the chosen candidate (or
    None), its equivalent ties and the refitted candidates with the rejections marked.
    """
    chosen = None
    equivalent: list[Candidate] = []
    while chosen is None:
        admissible = [candidate for candidate in refitted if not candidate.problem]
        chosen, equivalent = choose(loop, current, admissible, order)
        if chosen is None:
            break
        doubt = unearned(loop, current, chosen)
        if doubt:
            # Rejected, and the next best is considered in its place.
            refitted = [replace(candidate, problem=doubt) if candidate is chosen
                        else candidate for candidate in refitted]
            chosen = None
    return chosen, equivalent, refitted


def round_report(loop: LoopState, current: Fit, analysis: dict, results: list[Candidate],
                 chosen: Candidate | None, equivalent: list[Candidate]) -> dict[str, Any]:
    """Return the JSON report of a search round: errors, every candidate's evidence, choice."""
    report: dict[str, Any] = {
        'error_before': current.errors(loop.error_channels),
        'candidates': [candidate_report(candidate, analysis)
                       for candidate in results],
        'added': None,
    }
    if chosen is not None:
        report['added'] = chosen.describe()
        report['error_after'] = chosen.fitted.errors(loop.error_channels)
        report['gain_pct'] = cast(float, chosen.gain) * 100.0  # a chosen candidate is scored
        report['equivalent'] = [candidate.describe() for candidate in equivalent]
    return report


def gain_t(loop: LoopState, current: Fit, fitted: Fit) -> float:
    """
    Student t of the held-out gain over contiguous blocks (its size against its noise).

    Every record's held-out part is cut into :data:`GAIN_BLOCKS` blocks; the gain of a
    block is the drop of its weighted squared residual.  A gain that a few blocks carry
    while the others lose (a model fitting noise, or trading one stretch for another) has
    a small t.
    """
    weights = loop.weights or {}

    def squared(fit: Fit, index: int) -> np.ndarray:
        start = fit.stops[index]
        total = np.zeros(fit.simulated[index][loop.outputs[0]].shape[0] - start)
        for channel in loop.outputs:
            total += ((fit.simulated[index][channel][start:]
                       - getattr(fit.records[index], channel)[start:])
                      / weights.get(channel, 1.0)) ** 2
        return total

    drops = []
    for index in range(len(current.stops)):
        old, new = squared(current, index), squared(fitted, index)
        size = min(old.shape[0], new.shape[0])
        for block in np.array_split(np.arange(size), GAIN_BLOCKS):
            if block.shape[0]:
                drops.append(float(np.mean(old[block]) - np.mean(new[block])))
    drops_array = np.array(drops)
    if drops_array.shape[0] < 2 or not np.all(np.isfinite(drops_array)):
        return 0.0
    spread = float(np.std(drops_array, ddof=1)) / np.sqrt(drops_array.shape[0])
    mean = float(np.mean(drops_array))
    return mean / spread if spread > 0 else (np.inf if mean > 0 else 0.0)


def heldout_t(loop: LoopState, current: Fit, fitted: Fit) -> tuple[float, float]:
    """
    Student t of the held-out drop on the samples the noise is worth, and that number.

    With ``b`` the current fit's held-out residual, ``a`` the candidate's and ``s = a - b``
    the change the candidate makes to the simulated outputs, the per-sample drop is
    ``b^2 - a^2 = -(2 a s + s^2)`` (weighted, summed over the output channels).  Its
    chance part is ``-2 a s``, noise times the change; its standard error counts the samples
    over the integrated correlation time of the candidate's residual ``a``
    (:func:`~dcmotor_id.identification.checks.start.correlation_time`), per channel, not
    every correlated sample; the channels' variances add, and the samples their sum is worth
    follow Welch and Satterthwaite.  A change that follows the noise it removes
    (an effect) gives ``t ~ rms(s) / (2 sigma) sqrt(n_eff)``: an amplitude below the
    per-sample noise is resolved by many samples; a change independent of the held-out noise
    (fitted noise) makes the drop negative.  Returns ``(t, effective samples)``.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    weights = loop.weights or {}
    total, variances, dofs = 0.0, [], []
    for channel in loop.outputs:
        before = current.channel_residual(channel, 'heldout')
        after = fitted.channel_residual(channel, 'heldout')
        common = min(before.shape[0], after.shape[0])  # a delay shifts the records
        before, after = before[before.shape[0] - common:], after[after.shape[0] - common:]
        scale = max(weights.get(channel, 1.0), 1e-300) ** 2
        drop = (before ** 2 - after ** 2) / scale
        chance = 2.0 * after * (after - before) / scale
        if common < 3 or not (np.all(np.isfinite(drop)) and np.all(np.isfinite(chance))):
            return 0.0, 0.0
        effective = max(common / correlation_time(after), 2.0)
        total += float(np.mean(drop))
        variances.append(float(np.var(chance, ddof=1)) / effective)
        dofs.append(effective - 1.0)
    if not variances:
        return 0.0, 0.0
    variance = float(sum(variances))
    # Welch-Satterthwaite: the samples the channels' sum is worth.
    worth = 1.0 + variance ** 2 / max(sum(v ** 2 / d for v, d in zip(variances, dofs)),
                                      1e-300)
    t = total / np.sqrt(variance) if variance > 0 else (np.inf if total > 0 else 0.0)
    return float(t), float(worth)


def innovation_t(loop: LoopState, current: Fit, fitted: Fit) -> tuple[float, float]:
    """
    Student t of the held-out drop in the innovations of the residual's error model.

    A misfit the model integrates (the position of a model lacking a force) drifts: its
    held-out samples are worth a handful of independent ones, and :func:`heldout_t` on them
    cannot resolve a candidate that removes most of the drift.  The error model of each
    output channel is an AR(1) sequence, one per structure (:func:`residual_ar`, fitted on
    its held-out residual: white noise gives 0, a drift nearly 1, where the innovations are
    the residual's increments; each structure with its own, so that a bias the candidate
    removes is not taken for a drift of both); each fit's held-out residual is whitened by
    its own (the first held-out innovation from the last training sample), both scaled by
    the current structure's innovation variance.  The drop of their squares compares the
    two structures' held-out one-step predictions under their error models; its t counts
    the samples over the integrated correlation time of the whitened residual (and of the
    drop's chance part), as :func:`heldout_t` does, and the channels' variances add
    (Welch-Satterthwaite).  Returns ``(t, effective samples)``.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    total, variances, dofs = 0.0, [], []
    for channel in loop.outputs:
        rho, scale = residual_ar(current, channel)
        rhos = (rho, residual_ar(fitted, channel)[0])
        pairs = [_innovations(current, fitted, index, channel, rhos)
                 for index in range(len(current.stops))]
        before = np.concatenate([pair[0] for pair in pairs])
        after = np.concatenate([pair[1] for pair in pairs])
        drop = (before ** 2 - after ** 2) / scale
        chance = 2.0 * after * (after - before) / scale
        if drop.shape[0] < 3 or not (np.all(np.isfinite(drop)) and np.all(np.isfinite(chance))):
            return 0.0, 0.0
        effective = max(drop.shape[0] / max(correlation_time(after), correlation_time(chance)),
                        2.0)
        total += float(np.mean(drop))
        variances.append(float(np.var(chance, ddof=1)) / effective)
        dofs.append(effective - 1.0)
    variance = float(sum(variances))
    if not variances or not variance > 0:
        return (np.inf if total > 0 else 0.0), float(sum(dofs) + len(dofs))
    worth = 1.0 + variance ** 2 / max(sum(v ** 2 / d for v, d in zip(variances, dofs)),
                                      1e-300)
    return float(total / np.sqrt(variance)), float(worth)


def residual_ar(fit: Fit, channel: str) -> tuple[float, float]:
    """
    AR(1) error model of a fit's held-out residual on one channel: ``(rho, innovation var)``.

    ``rho`` is the lag-1 autocorrelation over the records' held-out parts, in ``[0, 1)``
    (:data:`~dcmotor_id.identification.error_model.criterion.MAX_POSITION_AR`); the variance
    is that of the whitened residual (at least a tiny positive number).  The held-out part,
    not the training one: a fit absorbs much of a drift where it is fitted (its parameters
    and initial states), and the drift it extrapolates (an input's noise integrated twice
    into the position) shows where it was not.
    """
    from dcmotor_id.identification.error_model.criterion import MAX_POSITION_AR, whiten

    lagged = products = 0.0
    pieces = []
    for rec, sim, stop in zip(fit.records, fit.simulated, fit.stops):
        error = np.asarray(sim[channel][stop:] - getattr(rec, channel)[stop:], dtype=float)
        error = error[np.isfinite(error)]
        if error.shape[0] >= 2:
            lagged += float(error[:-1] @ error[:-1])
            products += float(error[1:] @ error[:-1])
            pieces.append(error)
    rho = float(np.clip(products / lagged, 0.0, MAX_POSITION_AR)) if lagged > 0 else 0.0
    whitened = [whiten(piece, rho)[1:] for piece in pieces]
    variance = float(np.mean(np.concatenate(whitened) ** 2)) if whitened else 0.0
    return rho, max(variance, 1e-300)


def _innovations(current: Fit, fitted: Fit, index: int, channel: str,
                 rhos: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Held-out innovations of one record: the current fit's, the candidate's (each its rho)."""
    out = []
    for fit, rho in zip((current, fitted), rhos):
        error = fit.simulated[index][channel] - getattr(fit.records[index], channel)
        innovations = error[1:] - rho * error[:-1]
        out.append(innovations[max(fit.stops[index] - 1, 0):])
    # A data effect (a sensor delay) shifts the records by a few samples: the common end.
    common = min(out[0].shape[0], out[1].shape[0])
    return out[0][out[0].shape[0] - common:], out[1][out[1].shape[0] - common:]


def innovation_dm(loop: LoopState, current: Fit, fitted: Fit) -> tuple[float, int]:
    """
    Diebold-Mariano t of the held-out one-step predictions, and its degrees of freedom.

    Each structure's held-out residual on each output channel gets its own error model
    (:func:`held_out_innovations`: an autoregression, order by BIC, where white noise needs
    no lag and a drift one; for a mechanical-only position also the Kalman filter of the
    input current's noise integrated twice, the one of lower BIC); the squared one-step
    prediction errors of the two structures, each channel's scaled by the current
    structure's innovation variance, are subtracted sample by sample and summed over the
    channels (:func:`prediction_differential`).
    The mean of that differential is tested by
    :func:`~dcmotor_id.identification.discovery.comparison.diebold_mariano`, whose variance
    and degrees of freedom follow the differential's own correlation, so the size holds where
    the error models miss it (the test of the rule ``innovation-dm``).  Returns ``(t, degrees
    of freedom)``.
    """
    from dcmotor_id.identification.discovery.comparison import diebold_mariano

    differential = prediction_differential(loop, current, fitted)
    if differential is None:
        return 0.0, 0
    return diebold_mariano(differential)


def prediction_differential(loop: LoopState, current: Fit, fitted: Fit) -> np.ndarray | None:
    """Held-out loss differential of the one-step predictions (:func:`innovation_dm`), or None."""
    per_record: list[list[np.ndarray]] = [[] for _ in current.stops]
    for channel in loop.outputs:
        innovations = [held_out_innovations(loop, fit, channel) for fit in (current, fitted)]
        scale = float(np.mean(np.concatenate(innovations[0]) ** 2))
        if not scale > 0:
            return None
        for index, (before, after) in enumerate(zip(*innovations)):
            # A data effect (a sensor delay) shifts the records by a few samples: the common end.
            common = min(before.shape[0], after.shape[0])
            per_record[index].append((before[before.shape[0] - common:] ** 2
                                      - after[after.shape[0] - common:] ** 2) / scale)
    pieces = []
    for channels in per_record:
        common = min(part.shape[0] for part in channels)
        pieces.append(np.sum([part[part.shape[0] - common:] for part in channels], axis=0))
    differential = np.concatenate(pieces) if pieces else np.zeros(0)
    return differential if np.all(np.isfinite(differential)) else None


def held_out_innovations(loop: LoopState, fit: Fit, channel: str) -> list[np.ndarray]:
    """
    Return a fit's held-out one-step prediction errors on one channel, per record.

    The residual's autoregressive model, order by BIC
    (:func:`~dcmotor_id.identification.discovery.comparison.fit_ar`); for the position of a
    mechanical-only fit, whose logged input current may carry noise, also the Kalman filter
    of that noise integrated twice by the shaft
    (:func:`~dcmotor_id.identification.discovery.comparison.input_noise_innovations`: the
    current's and the position's noise levels, the fit's J and b; no free parameter), and of
    the two error models the one of lower BIC on the held-out innovations (a misfit the
    filter's noise levels do not describe, such as a missing force under an exact input, is
    left to the autoregression).
    """
    from dcmotor_id.identification.discovery.comparison import (ar_innovations, fit_ar,
                                                                MAX_AR_ORDER)

    errors = [np.asarray(sim[channel] - getattr(rec, channel), dtype=float)
              for rec, sim in zip(fit.records, fit.simulated)]
    starts = [max(stop, MAX_AR_ORDER) for stop in fit.stops]
    model = fit_ar(list(zip(errors, fit.stops)))
    regressed = [ar_innovations(error, start, model) for error, start in zip(errors, starts)]
    if channel != 'position' or loop.torque_constant is None:
        return regressed
    filtered = _input_noise_filtered(loop, fit, errors, starts)
    if filtered is None:
        return regressed
    n = max(sum(part.shape[0] for part in regressed), 1)

    def score(parts: list[np.ndarray], count: int) -> float:
        variance = float(np.mean(np.concatenate(parts) ** 2)) if parts else 0.0
        return n * np.log(max(variance, 1e-300)) + count * np.log(n)
    return filtered if score(filtered, 0) <= score(regressed, model.shape[0]) else regressed


def _input_noise_filtered(loop: LoopState, fit: Fit, errors: list[np.ndarray],
                          starts: list[int]) -> list[np.ndarray] | None:
    """Held-out innovations of the input-noise Kalman filter per record, or None."""
    from dcmotor_id.identification.discovery.comparison import input_noise_innovations
    from dcmotor_id.identification.error_model.criterion import noise_level

    out = []
    for error, rec, start in zip(errors, fit.records, starts):
        filtered = input_noise_innovations(
            error, float(np.median(np.diff(rec.time_s))), float(fit.values.get('J', 0.0)),
            float(fit.values.get('b', 0.0)),
            cast(float, loop.torque_constant) * noise_level(rec.current),
            noise_level(rec.position))
        if filtered is None:
            return None
        out.append(filtered[start:])
    return out


def unearned_dm(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why a winning candidate's held-out predictions are not significantly better, or None.

    The Diebold-Mariano t of :func:`innovation_dm` must reach Student's t quantile of its
    degrees of freedom at the one-sided size :data:`HELDOUT_ALPHA`, and the held-out gain the
    loop's least gain.  The test compares structures, not fits: when the current structure,
    refitted from the candidate's values (:func:`restarted`), reaches a lower training cost
    than the current fit (a better optimum of the same structure; the held-out part is not
    looked at), the candidate must beat that refit too.  No other rule: the test's size holds
    whatever the residual's correlation (``bench/dm_size_results.md``,
    ``test/identification/test_discovery_comparison.py``).
    """
    doubt = _dm_doubt(loop, current, candidate, 'its held-out gain')
    if doubt is not None:
        return doubt
    again = restarted(loop, current, candidate.fitted)
    if again is not None and again.train_cost < current.train_cost:
        doubt = _dm_doubt(loop, again, candidate,
                          'against the current structure refitted from its values (a better '
                          'optimum, training cost '
                          f'{again.train_cost / current.train_cost:.3g} of the first fit), its '
                          'held-out gain')
    return doubt or _beyond_null(loop, current, candidate)


def _beyond_null(loop: LoopState, current: Fit, candidate: Candidate,
                 statistic: Callable[[LoopState, Fit, Fit], tuple[float, Any]] | None = None,
                 name: str = 'Diebold-Mariano t') -> str | None:
    """
    Why the candidate's t is within its bootstrap null (a mechanical-only loop), or None.

    The t of refits of replicas of the current structure with the input current's noise
    (:func:`~dcmotor_id.identification.discovery.bootstrap.null_t`) give the null's mean and
    spread; the candidate's t must lie beyond their one-sided :data:`HELDOUT_ALPHA`
    prediction bound (``mean + t_(R-1) s sqrt(1 + 1/R)`` over ``R`` replicas).
    """
    from scipy.stats import t as student

    from dcmotor_id.identification.discovery.bootstrap import MIN_REPLICAS, null_t

    test = statistic or innovation_dm
    replicas = np.array(null_t(loop, current, candidate.fitted, statistic=test))
    if replicas.shape[0] < MIN_REPLICAS:
        return None
    count = replicas.shape[0]
    bound = float(np.mean(replicas) + student.ppf(1.0 - HELDOUT_ALPHA, count - 1)
                  * np.std(replicas, ddof=1) * np.sqrt(1.0 + 1.0 / count))
    t = float(test(loop, current, candidate.fitted)[0])
    if t > bound:
        return None
    return (f'its {name} ({t:.3g}) is within what refits of {count} replicas of '
            "the current structure with the input current's noise give (t "
            f'{np.mean(replicas):.3g} +- {np.std(replicas, ddof=1):.3g}, bound {bound:.3g}): '
            'the gain may be the noise the shaft integrates')


def _dm_doubt(loop: LoopState, current: Fit, candidate: Candidate, what: str) -> str | None:
    """Why the Diebold-Mariano test of :func:`unearned_dm` does not pass, or None."""
    from scipy.stats import t as student

    t, dof = innovation_dm(loop, current, candidate.fitted)
    achieved = 1.0 - candidate.fitted.heldout_cost / current.heldout_cost
    required = float(student.ppf(1.0 - HELDOUT_ALPHA, max(dof, 1)))
    if t >= required and achieved >= loop.min_gain:
        return None
    return (f'{what} ({100 * achieved:.3g} %) is not significant in the one-step '
            f'predictions (Diebold-Mariano t = {t:.2g} on {dof} degrees of freedom, '
            f't >= {required:.3g} needed)')


def restarted(loop: LoopState, current: Fit, fitted: Fit) -> Fit | None:
    """Return the current structure refitted from a candidate's values (None if it fails)."""
    from dcmotor_id.identification.discovery.refitting import _try_from, base_start

    initial = {**current.values, **{name: value for name, value in fitted.values.items()
                                    if name in current.values}}
    return _try_from(loop, current.structure, base_start(loop, fitted), initial,
                     fitted.estimate.initial_states)


def unearned(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why a winning candidate has not earned its place on held-out data, or None.

    By the loop's rule (``loop.acceptance``, one of
    :data:`~dcmotor_id.identification.discovery.state.ACCEPTANCE_RULES`): ``heldout-t``:
    :func:`unearned_heldout_t`; ``innovation-t``: the same on the innovations of the
    residuals' AR(1) error models (:func:`innovation_t`); ``innovation-t-null`` (default):
    innovation-t, and for a mechanical-only loop its t beyond the parametric bootstrap of
    the current structure with the input current's noise (:func:`_beyond_null`: with a noisy
    input the output-error fit of the position is biased and a candidate absorbing the
    integrated noise predicts better, so the t test alone has not its size there);
    ``innovation-dm``: :func:`unearned_dm`.
    """
    if loop.acceptance == 'innovation-dm':
        return unearned_dm(loop, current, candidate)
    if loop.acceptance == 'innovation-t-null':
        return (unearned_heldout_t(loop, current, candidate, innovation_t)
                or _beyond_null(loop, current, candidate, innovation_t, 'innovation t'))
    if loop.acceptance == 'innovation-t':
        return unearned_heldout_t(loop, current, candidate, innovation_t)
    return unearned_heldout_t(loop, current, candidate)


def unearned_heldout_t(loop: LoopState, current: Fit, candidate: Candidate,
                       test: Callable[[LoopState, Fit, Fit], tuple[float, float]] | None = None
                       ) -> str | None:
    """
    Why a winning candidate's held-out gain is not significant, or None.

    Its held-out drop must have a t of at least :func:`heldout_t_threshold` on the samples it
    is worth (``test``: :func:`heldout_t` by default, :func:`innovation_t` for the rule
    ``innovation-t``), the gain must be spread over the held-out part
    (:func:`gain_t` over blocks at least :data:`GAIN_T`: not one stretch traded for another)
    and at least the loop's least gain.  No size rule: a per-sample amplitude below the
    per-sample noise is what many samples resolve.
    """
    t, effective = (test or heldout_t)(loop, current, candidate.fitted)
    achieved = float(candidate.gain or 0.0)
    required = heldout_t_threshold(effective)
    if t >= required and achieved >= loop.min_gain:
        blocks = gain_t(loop, current, candidate.fitted)
        if blocks >= GAIN_T:
            return None
        return (f'its held-out gain ({100 * achieved:.3g} %) is carried by a few stretches '
                f'(t = {blocks:.2g} over {GAIN_BLOCKS} blocks per record, {GAIN_T:g} needed)')
    what = 'effective samples' if test in (None, heldout_t) else 'effective innovations'
    return (f'its held-out gain ({100 * achieved:.3g} %, t = {t:.2g} on {effective:.0f} '
            f'{what}) is not significant (t >= {required:.3g} needed)')


def heldout_t_threshold(effective: float) -> float:
    """
    Least t of :func:`heldout_t` on ``effective`` samples: one-sided :data:`HELDOUT_ALPHA`.

    Student's t with ``effective - 1`` degrees of freedom (3.0 for many
    samples; far more for a handful, where a drop carried by a few correlated stretches is
    likely by chance).
    """
    from scipy.stats import t as student

    return float(student.ppf(1.0 - HELDOUT_ALPHA, max(effective - 1.0, 1.0)))


def candidate_report(candidate: Candidate, analysis: dict) -> dict[str, Any]:
    """Return one candidate's JSON evidence in a round (screen, refit, gains, rejection)."""
    correlation = max((channel['regressors'].get(candidate.name, {}).get('max_abs', 0.0)
                       for channel in analysis.values()), default=0.0)
    return {
        'name': candidate.name,
        'inner': dict(candidate.inner),
        'refitted': candidate.fit is not None,
        'rejected': candidate.problem,
        'heldout_gain_pct': None if candidate.gain is None else candidate.gain * 100.0,
        'heldout_gain_noise_pct': _pct_or_none(candidate.gain_noise),
        'insample_gain_pct': _pct_or_none(candidate.insample_gain),
        'bic_delta': candidate.bic_delta,
        'screen_explained_pct': candidate.screen_explained * 100.0,
        'regressor_correlation': correlation,
    }


def _pct_or_none(value: float | None) -> float | None:
    return None if value is None else float(value) * 100.0
