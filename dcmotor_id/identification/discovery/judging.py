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
many samples where the drift is worth a handful.  Rule ``innovation-t-alone``: that t test
alone, without the spread over blocks (:func:`heldout_gain_noise` in
:func:`choose`, :func:`gain_t`), which repeats the test with 7 degrees of freedom and turns
down evidence gathered at a few instants (a sensor delay at a sawtooth's jumps).  Rule
``innovation-arma``: that test alone on the innovations of an ARMA(1, 2) model of each
structure's AR(1) innovations (:func:`innovation_arma_t`, :mod:`.arma`: the input noise a
mechanical model integrates leaves a wandering speed error under the rounding's increments),
measured beside the default (``bench/discovery_results.md``, round 7).  Rule
``input-noise-null`` (the default in rounds 8 and 9): the test of ``innovation-t-alone``,
then, where the measured current drives the model, the effect's coefficients against their
fits to draws of the current's noise (:mod:`.input_null`: a fit that bends to the input
noise's drift leaves a candidate a real held-out gain, ``bench/discovery_results.md``, round
8).  Rule ``input-noise-null-any-gain`` (the default in round 10): those tests
without the loop's least gain of 5 % (:func:`least_gain`): the t test on the effective
innovations is the criterion, its size measured; the fixed least gain turned down an effect
whose t passed (``bench/discovery_results.md``, round 10).  Rule ``judged-always``: those
tests, and the loop does not stop on a white held-out residual before judging
(:func:`~dcmotor_id.identification.discovery.analysis.stops_before_judging`; round 11); rule
``whole-record-white`` (the default since round 11): those tests, and the loop stops on a white
held-out residual only when the whole records' residual is white too.  Rules ``blocked-cv``
and ``blocked-cv-white`` (round 12, measured): the candidates ranked and the winner judged
by blocked cross-validation over the whole records (:mod:`.crossval`), with the stop of
``judged-always`` or of ``whole-record-white``.  Rule
``all-data-lr`` (measured,
not the default: it adds effects to real records): the training parts' likelihood ratio on
effective samples, the held-out part a guard (:mod:`.likelihood`).  The former rules
(``noise-level``: an effect's own part of the outputs against the per-sample noise,
:func:`own_part`, and a cogging ripple above the Coulomb friction needing twice the evidence)
are kept to be measured against (``bench/bench_discovery.py``, a column per rule).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, cast, Sequence

import numpy as np

from dcmotor_id.identification.discovery.state import CROSS_VALIDATED, LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Fit
from dcmotor_id.identification.error_model.residuals import simulate_records
from dcmotor_id.identification.estimators.refined import OutputErrorModel


#: Contiguous blocks of the held-out part whose error drops give the noise of the gain.
HELDOUT_BLOCKS = 8
#: Standard errors of the held-out drop a candidate's gain must exceed.
GAIN_NOISE_FACTOR = 2.0
#: Candidates explaining at least this share of the best one's improvement tie with it.
TIE_SHARE = 0.98
#: Blocks per record's held-out part of the gain's t statistic (:func:`gain_t`).
GAIN_BLOCKS = 8
#: Share of a refit's residual RMS an effect's own part of the outputs must exceed.
OWN_PART_SHARE = 0.5
#: Noise levels of an effect's own part beyond which its held-out gain needs no t test.
OWN_PART_STRONG = 3.0
#: Least t of the held-out gain for an effect to be added.
GAIN_T = 2.0
#: Nominal one-sided size of the held-out t test (:func:`heldout_t_threshold`): t >= 3 on
#: many samples; the false-effect rate and the power are measured by
#: ``bench/bench_discovery.py`` (a column per rule) and ``bench/bench_discovery_real.py``.
HELDOUT_ALPHA = 0.00135
#: Rules that do not ask the gain to be spread over the held-out part.
SPREAD_FREE = ('innovation-t-alone', 'innovation-arma', 'input-noise-null',
               'input-noise-null-any-gain', 'all-data-lr', 'judged-always',
               'whole-record-white', 'blocked-cv', 'blocked-cv-white')
#: Rules without the loop's least gain: their test is the criterion (round 10).
GAIN_FREE = ('input-noise-null-any-gain', 'all-data-lr', 'judged-always',
             'whole-record-white', 'blocked-cv', 'blocked-cv-white')


def least_gain(loop: LoopState) -> float:
    """Return the least held-out gain of the loop's rule: ``min_gain``, 0 for :data:`GAIN_FREE`."""
    return 0.0 if loop.acceptance in GAIN_FREE else loop.min_gain


def measured_offset(fit: Fit, channel: str) -> int:
    """
    Return the raw sample of ``channel`` that a fit's record holds at its index 0.

    A data effect (a sensor delay of ``samples``) shifts the delayed channel by ``samples``
    (its sample ``k`` is the raw ``k + samples``) and trims the record: a late sensor's
    last samples, an early sensor's first ones (then every channel starts ``-samples``
    later).  0 for a fit without one.
    """
    offset = 0
    for cls, inner in fit.structure.items:
        if cls.TRANSFORM:
            samples = int(inner.get('samples', 0))
            offset += max(-samples, 0) + (samples if inner.get('channel') == channel else 0)
    return offset


def common_instants(current: Fit, fitted: Fit, index: int,
                    channel: str) -> tuple[slice, slice]:
    """
    Return the held-out samples of one record and channel that both fits compare.

    A data effect (a sensor delay) shifts and trims a record (:func:`measured_offset`).  The
    two fits' held-out residuals are paired by the raw measured sample they compare with:
    on a channel the delay does not shift, the same instant; on the delayed one, the same
    measurement.  Paired by the records' ends, a late sensor's other channels were compared
    ``samples`` samples apart: the drop's chance part then held two independent noises and
    crushed the t of every delay; paired by the instant, so would the delayed channel.
    """
    spans = []
    for fit in (current, fitted):
        size = len(fit.simulated[index][channel])
        offset = measured_offset(fit, channel)
        spans.append((fit.stops[index] + offset, size + offset, offset))
    first, last = max(span[0] for span in spans), min(span[1] for span in spans)
    if last <= first:
        return slice(0, 0), slice(0, 0)
    return (slice(first - spans[0][2], last - spans[0][2]),
            slice(first - spans[1][2], last - spans[1][2]))


def paired_heldout(current: Fit, fitted: Fit, channel: str) -> tuple[np.ndarray, np.ndarray]:
    """Held-out residuals of one channel under both fits on the same measured samples, joined."""
    pairs = []
    for index in range(len(current.stops)):
        spans = common_instants(current, fitted, index, channel)
        pairs.append([fit.simulated[index][channel][span]
                      - getattr(fit.records[index], channel)[span]
                      for fit, span in zip((current, fitted), spans)])
    if not pairs:
        return np.zeros(0), np.zeros(0)
    return (np.concatenate([pair[0] for pair in pairs]),
            np.concatenate([pair[1] for pair in pairs]))


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
        # A data effect (a sensor delay) trims the records: the same instants.
        before, after = paired_heldout(current, candidate, channel)
        if before.shape[0] < 2 * HELDOUT_BLOCKS:
            return float('inf')
        with np.errstate(over='ignore', invalid='ignore'):  # a diverged candidate: inf below
            term = (before ** 2 - after ** 2) / (max(weights.get(channel, 1.0), 1e-300) ** 2
                                                 * before.shape[0])
        if drop is not None:  # a delayed channel pairs a few samples fewer: the common start
            common = min(drop.shape[0], term.shape[0])
            drop, term = drop[:common], term[:common]
        drop = term if drop is None else drop + term
    if drop is None or not np.all(np.isfinite(drop)) or current.heldout_cost <= 0.0:
        return float('inf')
    sums = np.array([part.sum() for part in np.array_split(drop, HELDOUT_BLOCKS)])
    stderr = float(np.sqrt(HELDOUT_BLOCKS) * np.std(sums, ddof=1))
    return GAIN_NOISE_FACTOR * stderr / current.heldout_cost


def never_worse(base: Fit, final: Fit, reason: str,
                reference: Fit | None = None) -> tuple[Fit, str]:
    """
    Return the final structure, or the base one when it is not better on the held-out part.

    Better than ``reference`` (default ``base``): the base structure as the candidates were
    refitted, when the base is not a fit of the loop's criterion.
    """
    if final is base or final.heldout_cost < (reference or base).heldout_cost:
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
    """
    Return the best admissible candidate when it gains enough (and its ties), else None.

    Rule ``all-data-lr``: the strongest evidence on the training parts
    (:func:`~dcmotor_id.identification.discovery.likelihood.choose_by_ratio`); rules
    ``blocked-cv`` and ``blocked-cv-white``: the lowest cross-validated cost
    (:func:`~dcmotor_id.identification.discovery.crossval.choose_cross_validated`).
    """
    if loop.acceptance == 'all-data-lr':
        from dcmotor_id.identification.discovery.likelihood import choose_by_ratio

        return choose_by_ratio(loop, current, admissible, order)
    if loop.acceptance in CROSS_VALIDATED:
        from dcmotor_id.identification.discovery.crossval import choose_cross_validated

        return choose_cross_validated(loop, current, admissible, order)
    drop = current.heldout_cost - admissible[0].fitted.heldout_cost if admissible else 0.0
    if not drop > 0:
        return None, []
    ties = [candidate for candidate in admissible
            if current.heldout_cost - candidate.fitted.heldout_cost >= TIE_SHARE * drop]
    winner = min(ties, key=lambda candidate: order[candidate.name])
    # Refitted candidates are scored: gain, bic_delta and gain_noise are set.
    gain, bic_delta = cast(float, winner.gain), cast(float, winner.bic_delta)
    noise = None if loop.acceptance in SPREAD_FREE else winner.gain_noise
    if gain >= least_gain(loop) and bic_delta < 0 and (noise is None or gain > noise):
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
        if 'cross_validation' in chosen.fitted.info:
            report['cross_validation'] = chosen.fitted.info['cross_validation']
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
        before, after = paired_heldout(current, fitted, channel)  # a delay trims records
        common = before.shape[0]
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


def innovation_t(loop: LoopState, current: Fit, fitted: Fit,
                 arma: bool = False) -> tuple[float, float]:
    """
    Student t of the held-out drop in the innovations of the residual's error model.

    A misfit the model integrates (the position of a model lacking a force) drifts: its
    held-out samples are worth a handful of independent ones, and :func:`heldout_t` on them
    cannot resolve a candidate that removes most of the drift.  The error model of each
    output channel is an AR(1) sequence, one per structure (:func:`residual_ar`, fitted on
    its held-out residual: white noise gives 0, a drift nearly 1, where the innovations are
    the residual's increments; each structure with its own, so that a bias the candidate
    removes is not taken for a drift of both); with ``arma`` (rule ``innovation-arma``) the
    AR(1) innovations are whitened further by an ARMA(1, 2) model of each structure's own
    (:func:`residual_arma`: the wander of an input's integrated noise under the rounding's
    increments).  Each fit's held-out residual is whitened by its own model (the first
    held-out innovation from the training samples before it), both scaled by the current
    structure's innovation variance.  The drop of their squares compares the
    two structures' held-out one-step predictions under their error models; its t counts
    the samples over the integrated correlation time of the whitened residual (and of the
    drop's chance part), as :func:`heldout_t` does, and the channels' variances add
    (Welch-Satterthwaite).  Returns ``(t, effective samples)``.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    total, variances, dofs = 0.0, [], []
    for channel in loop.outputs:
        models = (residual_arma(current, channel, arma), residual_arma(fitted, channel, arma))
        pairs = [_innovations(current, fitted, index, channel, models)
                 for index in range(len(current.stops))]
        before = np.concatenate([pair[0] for pair in pairs])
        after = np.concatenate([pair[1] for pair in pairs])
        scale = models[0][3]
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


def innovation_arma_t(loop: LoopState, current: Fit, fitted: Fit) -> tuple[float, float]:
    """:func:`innovation_t` on the innovations of the ARMA(1, 2) error models (``arma``)."""
    return innovation_t(loop, current, fitted, arma=True)


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
    rho, _, _, variance = residual_arma(fit, channel, False)
    return rho, variance


def residual_arma(fit: Fit, channel: str, arma: bool = True
                  ) -> tuple[float, float, np.ndarray, float]:
    """
    Error model of a fit's held-out residual: ``(rho, phi, theta, innovation variance)``.

    ``rho``: the AR(1) coefficient of :func:`residual_ar`; with ``arma``, ``phi`` and the MA
    polynomial ``theta`` of an ARMA(1, 2) model of the AR(1) innovations of the held-out
    parts (:func:`~dcmotor_id.identification.discovery.arma.fit_arma`), else ``0`` and
    ``[1]``.  The variance is that of the held-out innovations of the whole model (the
    filters run from each record's start), at least a tiny positive number.
    """
    from dcmotor_id.identification.discovery.arma import fit_arma
    from dcmotor_id.identification.error_model.criterion import MAX_POSITION_AR, whiten

    lagged = products = 0.0
    errors = []
    for rec, sim, stop in zip(fit.records, fit.simulated, fit.stops):
        error = np.asarray(sim[channel] - getattr(rec, channel), dtype=float)
        heldout = error[stop:]
        heldout = heldout[np.isfinite(heldout)]
        if heldout.shape[0] >= 2:
            lagged += float(heldout[:-1] @ heldout[:-1])
            products += float(heldout[1:] @ heldout[:-1])
            errors.append((error, stop))
    rho = float(np.clip(products / lagged, 0.0, MAX_POSITION_AR)) if lagged > 0 else 0.0
    phi, theta = 0.0, np.ones(1)
    if arma:
        phi, theta = fit_arma([(error[1:] - rho * error[:-1])[max(stop - 1, 0):]
                               for error, stop in errors])
        whitened = [_whitened(error, stop, (rho, phi, theta)) for error, stop in errors]
    else:  # the AR(1) model alone: within the held-out parts (Prais-Winsten)
        whitened = [whiten(error[stop:][np.isfinite(error[stop:])], rho)[1:]
                    for error, stop in errors]
    variance = float(np.mean(np.concatenate(whitened) ** 2)) if whitened else 0.0
    return rho, phi, theta, max(variance, 1e-300)


def _whitened(error: np.ndarray, stop: int, model: tuple[float, float, np.ndarray]
              ) -> np.ndarray:
    """Held-out innovations of one record's residual under ``(rho, phi, theta)``."""
    return _innovation_series(error, model)[max(stop - 1, 0):]


def _innovation_series(error: np.ndarray, model: tuple[float, float, np.ndarray]
                       ) -> np.ndarray:
    """Innovations of a whole residual under ``(rho, phi, theta)``: of samples 1 to n - 1."""
    from dcmotor_id.identification.discovery.arma import arma_filter

    rho, phi, theta = model
    innovations = error[1:] - rho * error[:-1]
    if phi != 0.0 or np.any(theta[1:]):
        innovations = arma_filter(np.where(np.isfinite(innovations), innovations, 0.0),
                                  phi, theta)
    return innovations


def _innovations(current: Fit, fitted: Fit, index: int, channel: str,
                 models: Sequence[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """Held-out innovations of one record: the current fit's, the candidate's (each its model)."""
    out = []
    # A data effect (a sensor delay) shifts and trims the records: the same measured
    # samples (:func:`common_instants`); innovation k is of sample k + 1.
    spans = common_instants(current, fitted, index, channel)
    for fit, model, span in zip((current, fitted), models, spans):
        error = fit.simulated[index][channel] - getattr(fit.records[index], channel)
        series = _innovation_series(error, model[:3])
        out.append(series[max(span.start - 1, 0):max(span.stop - 1, 0)])
    return out[0], out[1]


def unearned(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why a winning candidate has not earned its place on held-out data, or None.

    By the loop's rule (``loop.acceptance``, one of
    :data:`~dcmotor_id.identification.discovery.state.ACCEPTANCE_RULES`): ``heldout-t``:
    :func:`unearned_heldout_t`; ``innovation-t``: the same on the innovations of
    the residuals' AR(1) error models (:func:`innovation_t`); ``innovation-t-alone``:
    that t test without the spread over blocks; ``innovation-arma``: that test
    on the innovations of the ARMA(1, 2) error models (:func:`innovation_arma_t`);
    ``input-noise-null``: that test, then the effect's coefficients against their
    fits to draws of the input current's noise
    (:func:`~dcmotor_id.identification.discovery.input_null.input_noise_doubt`);
    ``input-noise-null-any-gain``: the same without the least gain
    (:func:`least_gain`); ``judged-always`` and ``whole-record-white`` (default): the same
    tests, the loop judging more rounds
    (:func:`~dcmotor_id.identification.discovery.analysis.stops_before_judging`);
    ``blocked-cv`` and ``blocked-cv-white``: blocked cross-validation over the whole records
    and the input noise's null
    (:func:`~dcmotor_id.identification.discovery.crossval.unearned_cross_validated`);
    ``all-data-lr``: the held-out guard and the input noise's null of
    :func:`~dcmotor_id.identification.discovery.likelihood.unearned_ratio` (the training
    parts' likelihood ratio chose it); ``noise-level`` (the former rules, kept to measure
    against): :func:`unearned_noise_level`.
    """
    if loop.acceptance == 'noise-level':
        return unearned_noise_level(loop, current, candidate)
    if loop.acceptance == 'innovation-t':
        return unearned_heldout_t(loop, current, candidate, innovation_t)
    if loop.acceptance == 'innovation-t-alone':
        return unearned_heldout_t(loop, current, candidate, innovation_t, spread=False)
    if loop.acceptance == 'innovation-arma':
        return unearned_heldout_t(loop, current, candidate, innovation_arma_t, spread=False)
    if loop.acceptance == 'all-data-lr':
        from dcmotor_id.identification.discovery.likelihood import unearned_ratio

        return unearned_ratio(loop, current, candidate)
    if loop.acceptance in CROSS_VALIDATED:
        from dcmotor_id.identification.discovery.crossval import unearned_cross_validated

        return unearned_cross_validated(loop, current, candidate)
    if loop.acceptance in ('input-noise-null', 'input-noise-null-any-gain', 'judged-always',
                           'whole-record-white'):
        from dcmotor_id.identification.discovery.input_null import input_noise_doubt

        return (unearned_heldout_t(loop, current, candidate, innovation_t, spread=False)
                or input_noise_doubt(loop, candidate, HELDOUT_ALPHA))
    return unearned_heldout_t(loop, current, candidate)


def unearned_heldout_t(loop: LoopState, current: Fit, candidate: Candidate,
                       test: Callable[[LoopState, Fit, Fit], tuple[float, float]] | None = None,
                       spread: bool = True) -> str | None:
    """
    Why a winning candidate's held-out gain is not significant, or None.

    Its held-out drop must have a t of at least :func:`heldout_t_threshold` on the samples it
    is worth (``test``: :func:`heldout_t` by default, :func:`innovation_t` for the rules
    ``innovation-t`` and ``innovation-t-alone``), the gain must be at least the loop's least
    gain and, with ``spread``, spread over the held-out part (:func:`gain_t` over blocks at
    least :data:`GAIN_T`).  No size rule: a per-sample amplitude below the
    per-sample noise is what many samples resolve.
    """
    t, effective = (test or heldout_t)(loop, current, candidate.fitted)
    achieved = float(candidate.gain or 0.0)
    required = heldout_t_threshold(effective)
    if t >= required and achieved >= least_gain(loop):
        blocks = gain_t(loop, current, candidate.fitted) if spread else GAIN_T
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


def unearned_noise_level(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why a winning candidate has not earned its place by the former rules, or None.

    Its own part of the simulated outputs must exceed the noise (:func:`own_part`); unless
    it stands far out of it (:data:`OWN_PART_STRONG` noise levels), its held-out gain must
    stand out of the gain's own noise over blocks (:func:`gain_t` at least
    :data:`GAIN_T`).  An effect beyond a physical size limit (a cogging ripple larger than
    the Coulomb friction) always needs twice that t and twice the gain.
    """
    own = own_part(loop, candidate)
    if own is not None and own[0] <= 1.0:
        return (f'its own part of the simulated outputs is below the noise ({own[1]}): its '
                'held-out gain comes from moving the other parameters')
    required, gain = GAIN_T, loop.min_gain
    strong = own is not None and own[0] >= OWN_PART_STRONG
    values = candidate.fitted.values
    size = ''
    if candidate.name == 'cogging':
        amplitude = float(np.hypot(values.get('cogging.sin_Nm', 0.0),
                                   values.get('cogging.cos_Nm', 0.0)))
        if amplitude > values.get('Mc', 0.0):
            required, gain, strong = 2.0 * GAIN_T, 2.0 * loop.min_gain, False
            size = (f' (a ripple of {amplitude:.3g} N m, larger than the Coulomb friction '
                    f'{values.get("Mc", 0.0):.3g} N m, needs t >= {required:g} and a gain of '
                    f'{100 * gain:.0f} %)')
    achieved = float(candidate.gain or 0.0)
    if strong and achieved >= gain:
        return None
    t = gain_t(loop, current, candidate.fitted)
    if t >= required and achieved >= gain:
        return None
    return (f'its held-out gain ({100 * achieved:.3g} %, t = {t:.2g} over '
            f'{GAIN_BLOCKS} blocks per record) does not stand out of its own noise{size}')


def own_part(loop: LoopState, candidate: Candidate) -> tuple[float, str] | None:
    """
    Size of an effect's own part of the simulated outputs, in noise levels, and its text.

    The refit is simulated again with the effect's coefficients at zero; the largest
    channel's RMS difference over its noise (the sensor noise, or :data:`OWN_PART_SHARE` of
    the refit's residual RMS when larger: input noise integrated by the motor, or misfit).
    An effect below one noise level explains no part of the signal that stands out: a gain
    it brings comes from moving the other parameters (extra freedom, not an effect).  None
    for data effects (delays), which are not judged so.
    """
    from dcmotor_id.core.noise import noise_level

    fitted = candidate.fitted
    prefix = f'{candidate.name}.'
    terms = [term for term in fitted.terms if term.name.startswith(prefix)]
    if not terms or candidate.effect.TRANSFORM:
        return None
    values = dict(fitted.values)
    for term in terms:
        values[term.name] = 0.0
    model = OutputErrorModel(fitted.records, loop.torque_constant, fitted.terms,
                             loop.quasi_static)
    without = simulate_records(model, values, fitted.estimate.initial_states)
    ratio, texts = 0.0, []
    for channel in loop.outputs:
        difference = np.concatenate([sim[channel] - out[channel] for sim, out
                                     in zip(fitted.simulated, without)])
        sensor = np.sqrt(np.mean([noise_level(getattr(rec, channel)) ** 2
                                  for rec in fitted.records]))
        misfit = float(fitted.estimate.info.get('noise_std', {}).get(channel, 0.0))
        noise = max(float(sensor), OWN_PART_SHARE * misfit, 1e-300)
        rms = float(np.sqrt(np.mean(difference ** 2)))
        if not np.isfinite(rms):
            return None
        ratio = max(ratio, rms / noise)
        texts.append(f'{channel} {rms:.3g} against a noise of {noise:.3g}')
    return ratio, ', '.join(texts)


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
