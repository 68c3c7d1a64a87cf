"""
Rule ``all-data-lr``: a likelihood-ratio test on effective samples over the training parts.

The held-out tests (``innovation-t-alone``, ``input-noise-null``) see the 30 % of the
excitation held out: an effect in the 70 % the fits train on may not stand out there
(``bench/discovery_results.md``, round 9: 8 records whose true effect's training likelihood
ratio is 20-133 against 10.3 or 13.2 needed while its held-out t is -0.6 to 2.6). This rule
judges a candidate on the training parts instead (:func:`training_ratio`): per output channel
``n_eff log(mse_current / mse_candidate)``, ``n_eff`` the training samples over the candidate
residual's integrated correlation time, summed over the channels; under no effect it follows
chi-square with the effect's coefficients as degrees of freedom (:func:`coefficient_count`),
judged at the held-out test's size
(:data:`~dcmotor_id.identification.discovery.judging.HELDOUT_ALPHA`, :func:`ratio_needed`). The
round's winner is the candidate with the strongest evidence (:func:`choose_by_ratio`); the
held-out part only guards against a contradiction: its innovations' drop must not be
significantly negative (:func:`heldout_guard`, one-sided :data:`GUARD_ALPHA`). No least gain
and no BIC: the test is the criterion. Where the measured current drives the model, the
effect's coefficients must also stand out of the input noise's null
(:func:`~dcmotor_id.identification.discovery.input_null.input_noise_doubt`), as under the
default rule. Its false-effect rate and power: ``bench/bench_discovery.py`` and
``bench/bench_discovery_real.py`` (a column per rule; ``bench/discovery_results.md``, round 10:
false effects on real records and logs, where a misfit model gains on the training parts and on
the held-out part with any effect that takes the misfit up; not the default). The loop judges
no candidate where the base's held-out residual is white, which is where the effects of round 9
that only the training data show lie.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from dcmotor_id.identification.discovery.state import LoopState
    from dcmotor_id.identification.discovery.structure import Candidate, Fit

#: One-sided size of the held-out guard: a drop of the held-out innovations below this
#: Student quantile's negative contradicts the training evidence (:func:`heldout_guard`).
GUARD_ALPHA = 0.05


def coefficient_count(candidate: Candidate) -> int:
    """
    Return the coefficients a candidate's effect fits: its terms (at least 1).

    A data effect (a sensor delay) fits none but chooses its delay: counted as one.
    """
    prefix = f'{candidate.name}.'
    return max(sum(1 for term in candidate.fitted.terms if term.name.startswith(prefix)), 1)


def training_ratio(loop: LoopState, current: Fit, fitted: Fit) -> float:
    """
    Return the likelihood-ratio statistic of ``fitted`` against ``current`` on the training parts.

    Per output channel ``n_eff log(mse_current / mse_fitted)``, each fit's mean squared
    training residual over its own training samples (a delay trims a few), ``n_eff`` the
    candidate's training samples over its residual's integrated correlation time
    (:func:`~dcmotor_id.identification.checks.start.correlation_time`); summed over the
    channels.  ``-inf`` when a residual is not finite or empty.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    total = 0.0
    for channel in loop.outputs:
        before = current.channel_residual(channel, 'train')
        after = fitted.channel_residual(channel, 'train')
        if not (before.shape[0] > 2 and after.shape[0] > 2 and np.all(np.isfinite(before))
                and np.all(np.isfinite(after))):
            return float('-inf')
        mse_before, mse_after = float(np.mean(before ** 2)), float(np.mean(after ** 2))
        if not (mse_before > 0.0 and mse_after > 0.0):
            return float('-inf')
        effective = after.shape[0] / correlation_time(after)
        total += effective * float(np.log(mse_before / mse_after))
    return total


def ratio_needed(coefficients: int) -> float:
    """Return the chi-square quantile a ratio must reach: the held-out test's size."""
    from scipy.stats import chi2

    from dcmotor_id.identification.discovery.judging import HELDOUT_ALPHA

    return float(chi2.ppf(1.0 - HELDOUT_ALPHA, coefficients))


def ratio_evidence(loop: LoopState, current: Fit, candidate: Candidate) -> tuple[float, float]:
    """
    Return a candidate's :func:`training_ratio` and the log of its chi-square p-value.

    The log p-value ranks candidates of different coefficient counts (the smaller, the
    stronger); ``0`` when the ratio is not positive.
    """
    from scipy.stats import chi2

    ratio = training_ratio(loop, current, candidate.fitted)
    if not ratio > 0.0:
        return ratio, 0.0
    return ratio, float(chi2.logsf(ratio, coefficient_count(candidate)))


def choose_by_ratio(loop: LoopState, current: Fit, admissible: list[Candidate],
                    order: dict[str, int]) -> tuple[Candidate | None, list[Candidate]]:
    """
    Return the candidate with the strongest training evidence when it passes, and its ties.

    Passing: its :func:`training_ratio` reaches :func:`ratio_needed` for its coefficients.
    Ties: the passing candidates whose training cost drop is at least
    :data:`~dcmotor_id.identification.discovery.judging.TIE_SHARE` of the strongest one's; the
    vocabulary's order chooses among them.
    """
    from dcmotor_id.identification.discovery.judging import TIE_SHARE

    passing = []
    for candidate in admissible:
        ratio, log_p = ratio_evidence(loop, current, candidate)
        if ratio >= ratio_needed(coefficient_count(candidate)):
            passing.append((log_p, candidate))
    if not passing:
        return None, []
    strongest = min(passing, key=lambda item: item[0])[1]
    drop = current.train_cost - strongest.fitted.train_cost
    ties = [candidate for _, candidate in passing
            if current.train_cost - candidate.fitted.train_cost >= TIE_SHARE * drop]
    winner = min(ties, key=lambda candidate: order[candidate.name])
    return winner, [candidate for candidate in ties if candidate is not winner]


def heldout_guard(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why the held-out part contradicts a candidate, or None.

    The drop of the held-out innovations
    (:func:`~dcmotor_id.identification.discovery.judging.innovation_t`) must not be
    significantly negative: its t at least minus the one-sided :data:`GUARD_ALPHA` quantile
    of Student's t on its effective innovations.
    """
    from scipy.stats import t as student

    from dcmotor_id.identification.discovery.judging import innovation_t

    t, effective = innovation_t(loop, current, candidate.fitted)
    floor = -float(student.ppf(1.0 - GUARD_ALPHA, max(effective - 1.0, 1.0)))
    if t >= floor:
        return None
    return (f'its held-out part contradicts the training evidence (held-out gain '
            f'{100 * float(candidate.gain or 0.0):.3g} %, t = {t:.2g} on {effective:.0f} '
            f'effective innovations, at least {floor:.3g} needed)')


def unearned_ratio(loop: LoopState, current: Fit, candidate: Candidate) -> str | None:
    """
    Why a winner of :func:`choose_by_ratio` has not earned its place, or None.

    The held-out guard (:func:`heldout_guard`), then, where the measured current drives the
    model, the input noise's null
    (:func:`~dcmotor_id.identification.discovery.input_null.input_noise_doubt`).
    """
    from dcmotor_id.identification.discovery.input_null import input_noise_doubt
    from dcmotor_id.identification.discovery.judging import HELDOUT_ALPHA

    return (heldout_guard(loop, current, candidate)
            or input_noise_doubt(loop, candidate, HELDOUT_ALPHA))
