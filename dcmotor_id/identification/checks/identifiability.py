"""
What the data can and cannot identify, said plainly: excitation, bounds, correlations, fit.

:func:`assess_excitation` looks at the measured motion (does the shaft move, does it reverse,
is the voltage constant) at any sample rate; :func:`assess` looks at a fitted estimate and
returns ``not_identifiable`` (parameter -> reason) and ``warnings`` (sentences) for the
result: parameters at their bound zero, pairs correlated beyond 0.99, an electrical time
constant below the sample period, estimated initial states far from the first samples, a
model misfit far above the sensor noise, a current that sits at an amplifier's limit.
:func:`useful` says whether anything worth reporting was identified (else the caller refuses).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.checks import Check, register
from dcmotor_id.core.errors import NotIdentifiableError
from dcmotor_id.core.model import UNITS
from dcmotor_id.identification.checks.input_noise import input_noise_warning
from dcmotor_id.identification.checks.ramp import robust_lstsq
from dcmotor_id.identification.effects.base import torque_spread
from dcmotor_id.signals.filters import low_pass

if TYPE_CHECKING:
    from dcmotor_id.identification.checks.answer import FinalFit

#: Relative standard error above which a parameter counts as not identified.
IDENTIFIABLE_REL_STDERR = 0.5
#: Correlation beyond which a pair of parameters is reported as not separable.
CORRELATION_LIMIT = 0.99
#: b or Mc below this share of its typical size (torque spread, over speed for b) is at zero.
AT_ZERO_SHARE = 1e-6
#: Residual RMS above this multiple of the sensor noise is a model misfit.
MISFIT_FACTOR = 3.0
#: Initial state this many noise levels (and 2 % of the channel's range) off its first sample.
INITIAL_STATE_FACTOR = 5.0
#: Share of the speed an ARX predictor must explain for motion near the Nyquist frequency.
ARX_EXPLAINED = 0.8
#: Samples a current limit holds the current at its peak, per run.
LIMIT_RUN_SAMPLES = 3
#: Share of the peak current below which a limit at the peak cannot bind: the electrical
#: equation of the limit's confirmation is fitted there.
LIMIT_FREE_SHARE = 0.8
#: One-sided size of the limit's confirmation (the plateaus' shortfall against its block null).
LIMIT_TEST_SIZE = 0.01
#: Draws of the block null (a fixed seed: the same records give the same answer).
LIMIT_NULL_DRAWS = 999
#: Effects that on one-direction data are one constant torque with Mc.
ONE_DIRECTION_CONFOUNDED = ('load_torque', 'coulomb_asymmetry', 'viscous_asymmetry')


@dataclass(frozen=True)
class Excitation:
    """
    How the records move: the facts the identification's checks need.

    Attributes
    ----------
    moves : bool
        The speed leaves its noise band.
    positive, negative : bool
        It turns visibly forward / backward.
    constant_voltage_steady : bool
        A constant input with the motor in steady state: the voltage, or the current in the
        mechanical-only mode.
    noise : float
        Speed noise level used [rad/s].
    level : float
        Speed above which a direction counts as visited [rad/s].

    """

    moves: bool
    positive: bool
    negative: bool
    constant_voltage_steady: bool
    noise: float
    level: float

    @property
    def one_direction(self) -> bool:
        """Whether the shaft turns one way only."""
        return self.moves and not (self.positive and self.negative)

    @property
    def direction(self) -> str:
        """``positive``, ``negative`` or ``both``."""
        if self.positive and self.negative:
            return 'both'
        return 'positive' if self.positive else 'negative'


def _smooth_speed(speed: np.ndarray) -> np.ndarray:
    # 5 % of the sample rate keeps the motion of slow logs (a 100 Hz log of a motor that
    # reverses at 2 Hz) while removing most of the noise.
    return low_pass(speed, 0.05, order=2)


def assess_excitation(records: Sequence[Any], mechanical_only: bool) -> Excitation:
    """
    Return how the records move (:class:`Excitation`), at any sample rate.

    The noise level is the second-difference estimate of
    :func:`dcmotor_id.signals.filters.noise_std`;
    at a low sample rate the second differences contain signal, so the estimate is too large,
    and motion is also accepted when the speed's spread is four times that estimate (white
    noise alone has a spread equal to it).
    """
    measured = [np.asarray(rec.speed, dtype=float) for rec in records]
    speeds = np.concatenate(measured)
    smooth = np.concatenate([_smooth_speed(speed) for speed in measured])
    noise = max(max(rec.noise_std('speed') for rec in records),
                1e-12 * max(float(np.max(np.abs(speeds))), 1e-300))
    spread = max(float(np.std(speed)) for speed in measured)
    moves = bool(np.max(np.abs(smooth)) > 10.0 * noise or spread > 4.0 * noise)
    if not moves:
        # Motion near the Nyquist frequency (a 100 Hz log of a fast motor): the smoothing
        # removes it and the second differences count it as noise.  The speed then still
        # follows the input, which noise cannot: an ARX predictor explains most of it.
        explained, predicted = _arx_explained(records, mechanical_only)
        if explained > ARX_EXPLAINED:
            moves = True
            smooth = predicted
            noise = 0.0
    # A reversal must be a visible part of the motion, not filter ringing around a start at rest.
    level = max(min(10.0 * noise, 0.2 * float(np.max(np.abs(smooth)))),
                0.02 * float(np.max(np.abs(smooth))))
    positive = bool(np.sum(smooth > level) >= 3)
    negative = bool(np.sum(smooth < -level) >= 3)
    # The input (the voltage; the current in the mechanical-only mode) held constant with the
    # motor in steady state.
    inputs = np.concatenate([rec.current if mechanical_only else rec.voltage for rec in records])
    constant_input = np.ptp(inputs) <= 1e-9 * max(np.max(np.abs(inputs)), 1e-300)
    speed_change = np.ptp(smooth) / max(np.max(np.abs(smooth)), 1e-300)
    steady = bool(constant_input and speed_change < 0.05)
    return Excitation(moves, positive, negative, steady, noise, level)


def _arx_explained(records: Sequence[Any], mechanical_only: bool) -> tuple[float, np.ndarray]:
    """
    Share of the speed an ARX(2, 5) one-step predictor from its past and the input explains.

    Returns the share (pooled over records) and the predictions (records joined, the first
    samples of each record as measured).
    """
    residual_ss, total_ss, predicted = 0.0, 0.0, []
    for rec in records:
        speed = np.asarray(rec.speed, dtype=float)
        drive = np.asarray(rec.current if mechanical_only else rec.voltage, dtype=float)
        n = speed.shape[0]
        lags = 5
        if n < 4 * (lags + 3):
            predicted.append(speed)
            continue
        rows = [speed[lags - 1:n - 1], speed[lags - 2:n - 2], np.ones(n - lags)]
        rows += [drive[lags - k:n - k] for k in range(1, lags + 1)]
        x = np.column_stack(rows)
        target = speed[lags:]
        beta, *_ = np.linalg.lstsq(x, target, rcond=None)
        fitted = x @ beta
        residual_ss += float(np.sum((target - fitted) ** 2))
        total_ss += float(np.sum((target - np.mean(target)) ** 2))
        predicted.append(np.concatenate([speed[:lags], fitted]))
    explained = 1.0 - residual_ss / total_ss if total_ss > 0 else 0.0
    return explained, np.concatenate(predicted)


def one_direction_note(excitation: Excitation, value: float) -> str:
    """Reason text for Mc (and load torque) on data that turn one way only."""
    return (f'not separately identifiable: the speed never reverses ({excitation.direction} '
            f'direction only), so Coulomb friction and a constant load act as one torque; '
            f'Mc = {value:.4g} N m is that total friction torque of the {excitation.direction} '
            'direction (friction_torque_Nm). Record both directions to separate them.')


def _reference_sizes(estimate: Any, records: Sequence[Any],
                     torque_constant: float | None) -> dict[str, float]:
    spread = torque_spread(records, estimate.parameters, torque_constant)
    speed = max(float(np.std(np.concatenate([rec.speed for rec in records]))), 1e-12)
    return {'Mc': spread, 'b': spread / speed}


def at_bound(estimate: Any, records: Sequence[Any],
             torque_constant: float | None) -> dict[str, str]:
    """Return the friction parameters at their bound zero, with the reason."""
    out = {}
    reference = _reference_sizes(estimate, records, torque_constant)
    kind = {'Mc': 'Coulomb friction', 'b': 'viscous friction'}
    for name, size in reference.items():
        value = float(estimate.parameters.get(name, np.nan))
        if np.isfinite(value) and value < AT_ZERO_SHARE * size:
            out[name] = (f'at its bound zero ({value:.2g} {UNITS[name]}): no {kind[name]} is '
                         'seen in these data; the value and its standard error mean nothing '
                         'beyond "about zero"')
    return out


def loose(estimate: Any, names: Sequence[str]) -> dict[str, str]:
    """
    Return the parameters whose (robust) standard error exceeds half their value.

    With several records, the within-record figure (``between_records.stderr_within`` of the
    estimate's info): records that disagree do not make a parameter undetermined by the data
    (a warning says that they disagree).
    """
    out = {}
    account = estimate.info.get('between_records') or {}
    within = account.get('stderr_within', {})
    for name in names:
        value = estimate.parameters.get(name)
        error = within.get(name, estimate.stderr.get(name, np.nan))
        if value is None or not np.isfinite(error):
            continue
        if error > IDENTIFIABLE_REL_STDERR * abs(value):
            out[name] = (f'standard error above 50 % ({value:.4g} +/- {error:.2g} '
                         f'{UNITS.get(name, "")}): the data do not determine it; use a richer '
                         'excitation or a longer record')
    return out


def correlated_pairs(estimate: Any, skip: Sequence[str] = ()) -> list[str]:
    """Return warnings for pairs of parameters correlated beyond :data:`CORRELATION_LIMIT`."""
    correlation = estimate.info.get('robust_correlation')
    names = list(estimate.info.get('names', []))
    if correlation is None or not names:
        return []
    correlation = np.asarray(correlation)
    out = []
    for first in range(len(names)):
        for second in range(first + 1, len(names)):
            a, b = names[first], names[second]
            if a in skip or b in skip:
                continue
            value = correlation[first, second]
            if np.isfinite(value) and abs(value) > CORRELATION_LIMIT:
                out.append(f'{a} and {b} are correlated {value:+.3f}: the data determine a '
                           'combination of them better than each; their standard errors say '
                           'how far each can move along it')
    return out


def initial_state_warnings(estimate: Any, records: Sequence[Any],
                           outputs: Sequence[str]) -> list[str]:
    """
    Return warnings for estimated initial states far from the records' first samples.

    A speed derived from the position is no measurement of the first instant (its filter
    spreads a step from rest over the first samples): it is not compared.
    """
    out = []
    for index, (rec, state) in enumerate(zip(records, estimate.initial_states)):
        for channel, value in zip(outputs, state):
            if channel == 'speed' and getattr(rec, 'speed_derived', False):
                continue
            measured = np.asarray(getattr(rec, channel), dtype=float)
            noise = max(rec.noise_level(channel), 1e-12)
            first = float(measured[0])
            gap = abs(float(value) - first)
            if gap > INITIAL_STATE_FACTOR * noise and gap > 0.02 * float(np.ptp(measured)):
                name = rec.source or f'record {index + 1}'
                unit = 'A' if channel == 'current' else 'rad/s'
                out.append(f'{name}: the estimated initial {channel} {value:.4g} {unit} is '
                           f'{gap / noise:.0f} noise levels from the first samples '
                           f'({first:.4g} {unit}); the fit moved the start to absorb a misfit. '
                           'Use --initial-state measured to pin it to the first samples')
    return out


def misfit_ratios(records: Sequence[Any], outputs: Sequence[str],
                  residual_rms: Mapping[str, float]) -> dict[str, float]:
    """Return the channels whose residual is beyond :data:`MISFIT_FACTOR` sensor noises."""
    ratios = {}
    for channel in outputs:
        noise = np.sqrt(np.mean([rec.noise_level(channel) ** 2 for rec in records]))
        if noise > 0 and residual_rms.get(channel) is not None:
            ratios[channel] = residual_rms[channel] / noise
    return {channel: ratio for channel, ratio in ratios.items() if ratio > MISFIT_FACTOR}


def input_noise_misfit(estimate: Any, records: Sequence[Any], outputs: Sequence[str],
                       residual_rms: dict[str, float],
                       torque_constant: float | None = None) -> str | None:
    """
    Return the warning of a speed misfit the measured current's noise explains, else None.

    The check of :func:`misfit_warning` in mechanical mode: the speed alone misfits and
    :func:`~dcmotor_id.identification.checks.input_noise.input_noise_warning` explains it.
    """
    bad = misfit_ratios(records, outputs, residual_rms)
    if list(bad) != ['speed'] or tuple(outputs) != ('speed',):
        return None
    return input_noise_warning(estimate.parameters, records, torque_constant,
                               residual_rms['speed'], bad['speed'])


def correlation_check(fit: FinalFit) -> list[str]:
    """Check the answer (:mod:`~.answer`): say which parameters are strongly correlated."""
    return correlated_pairs(fit.estimate, skip=fit.skip)


def initial_states_check(fit: FinalFit) -> list[str]:
    """Check the answer: fitted initial states far from the records' first samples."""
    if fit.initial_state != 'estimate':
        return []
    return initial_state_warnings(fit.estimate, fit.fitted_records, fit.outputs)


def misfit_check(fit: FinalFit) -> list[str]:
    """Check the answer: a fit that misses the data far above their noise."""
    misfit = misfit_warning(fit.estimate, fit.fitted_records, fit.outputs,
                            dict(fit.residual_rms), fit.torque_constant)
    return [misfit] if misfit else []


def misfit_warning(estimate: Any, records: Sequence[Any], outputs: Sequence[str],
                   residual_rms: dict[str, float],
                   torque_constant: float | None = None) -> str | None:
    """
    Return a warning when the model misfits far above the sensor noise, else None.

    In mechanical mode (``torque_constant`` given) a speed misfit that the measured current's
    own noise explains gets the warning of :func:`input_noise_misfit` instead.
    """
    bad = misfit_ratios(records, outputs, residual_rms)
    if not bad:
        return None
    explained = input_noise_misfit(estimate, records, outputs, residual_rms, torque_constant)
    if explained:
        return explained
    return misfit_message(bad)


def misfit_message(bad: Mapping[str, float]) -> str:
    """Return the warning of channels misfitted beyond the noise (``bad``: channel -> ratio)."""
    listing = ', '.join(f'{channel} {ratio:.3g}x' for channel, ratio in bad.items())
    return (f'the model misfits far above the sensor noise (residual / noise: {listing}): the '
            "standard errors cover the noise and the residual's correlation, not the model "
            'error, so the values may be biased by more than they say')


def limited_samples(records: Sequence[Any]) -> list[np.ndarray] | None:
    """
    Return, per record, the samples where the current sits at an amplifier limit (or None).

    A limit shows as plateaus at the largest ``|i|``: the current jumps into them within two
    samples (from below 80 % of the level: an armature time constant near the sample period
    leaves the first sample short of the limit), stays within a few noise levels for at least
    :data:`LIMIT_RUN_SAMPLES` samples, and this happens at least twice.  The peaks of a
    smooth current approach the top gradually; an unlimited current step spikes and decays.
    A current that merely peaks after each switch of a binary input (a slow mechanical time
    constant) looks the same, so the plateaus are confirmed by a test of the physics
    (:func:`limit_shortfall_p` at the one-sided size :data:`LIMIT_TEST_SIZE`): on them the
    electrical equation predicts more current than flows.  ``bench/bench_current_limit.py``
    measures the rule's false alarms and power.
    """
    currents = [np.abs(np.asarray(rec.current, dtype=float)) for rec in records]
    joined = np.concatenate(currents)
    if joined.shape[0] < 20:
        return None
    peak = float(np.max(joined))
    noise = max(float(np.sqrt(np.mean([rec.noise_std('current') ** 2 for rec in records]))),
                2e-3 * peak)
    threshold = peak - 5.0 * noise
    masks, plateaus = [], 0
    for current in currents:
        near = current >= threshold
        mask = np.zeros_like(near)
        padded = np.concatenate([[0], near.astype(int), [0]])
        starts = np.flatnonzero(np.diff(padded) == 1)
        stops = np.flatnonzero(np.diff(padded) == -1)
        for first, last in zip(starts, stops):
            jump = first > 0 and min(current[max(first - 2, 0):first]) < 0.8 * threshold
            if jump and last - first >= LIMIT_RUN_SAMPLES:
                plateaus += 1
                mask[first:last] = True
        masks.append(mask)
    if plateaus < 2 or np.mean(np.concatenate(masks)) > 0.5:
        return None
    p_value = limit_shortfall_p(records, masks, LIMIT_FREE_SHARE * peak)
    return None if p_value is not None and p_value > LIMIT_TEST_SIZE else masks


def _free_fit(record: Any, mask: np.ndarray, free_below: float
              ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """
    Fit ``i[k+1]`` on ``i[k], u[k], w[k], w[k+1], 1`` where ``|i|`` stays below ``free_below``.

    Return ``sign(i) (prediction - i)`` at ``k+1`` (all samples), the mask of the fitted ones
    (robust: beyond 5 noise levels left out) and the variance of its sum over the plateau
    samples (``mask``) that the fit's own uncertainty gives; None when it cannot be fitted (too
    few samples, no speed or voltage).
    """
    if record.speed is None or record.voltage is None:
        return None
    current, volts, speed = (np.asarray(channel, dtype=float) for channel
                             in (record.current, record.voltage, record.speed))
    matrix = np.column_stack([current[:-1], volts[:-1], speed[:-1], speed[1:],
                              np.ones(current.size - 1)])
    free = np.abs(current) < free_below
    fit = robust_lstsq(matrix, current[1:], free[:-1] & free[1:], 4)
    if fit is None:
        return None
    _, residual, sigma, keep = fit
    sign = np.sign(current[1:])
    gradient = (sign[mask[1:], None] * matrix[mask[1:]]).sum(axis=0)
    covariance = sigma ** 2 * np.linalg.pinv(matrix[keep].T @ matrix[keep])
    return -sign * residual, keep, float(gradient @ covariance @ gradient)


def limit_shortfall_p(records: Sequence[Any], masks: Sequence[np.ndarray],
                      free_below: float) -> float | None:
    """
    Return the p-value of the plateaus' shortfall against the electrical equation, or None.

    At a limit the current stays flat while the electrical equation, fitted where the current
    is below ``free_below`` (the limit cannot bind there, :func:`_free_fit`), predicts more:
    the statistic is the mean of ``sign(i) (prediction - i)`` over the plateau samples.  Its
    null is the same mean over windows of the fitted samples' own residual with the plateaus'
    lengths, at :data:`LIMIT_NULL_DRAWS` random places (a block null: the misfit of the
    equation on this record counts in it), plus a normal draw of the fit's own uncertainty in
    the plateaus' prediction.  None when a record with plateaus cannot be fitted.
    """
    fits = [_free_fit(record, mask, free_below) if mask.any() else None
            for record, mask in zip(records, masks)]
    if any(fit is None for fit, mask in zip(fits, masks) if mask.any()):
        return None
    rng = np.random.default_rng(0)
    observed, count, variance = 0.0, 0, 0.0
    null = np.zeros(LIMIT_NULL_DRAWS)
    counts = np.zeros(LIMIT_NULL_DRAWS)
    for mask, fit in zip(masks, fits):
        if fit is None:
            continue
        towards, keep, spread = fit
        observed += float(np.sum(towards[mask[1:]]))
        count += int(np.count_nonzero(mask[1:]))
        variance += spread
        padded = np.concatenate([[0], mask[1:].astype(int), [0]])
        lengths = np.flatnonzero(np.diff(padded) == -1) - np.flatnonzero(np.diff(padded) == 1)
        sums = np.cumsum(np.concatenate([[0.0], np.where(keep, towards, 0.0)]))
        kept = np.cumsum(np.concatenate([[0], keep.astype(int)]))
        for length in lengths:
            starts = rng.integers(0, towards.size - length + 1, LIMIT_NULL_DRAWS)
            null += sums[starts + length] - sums[starts]
            counts += kept[starts + length] - kept[starts]
    if count == 0:
        return None
    null_means = (null / np.maximum(counts, 1)
                  + rng.normal(0.0, np.sqrt(variance), LIMIT_NULL_DRAWS) / count)
    exceed = int(np.count_nonzero(null_means >= observed / count))
    return (1 + exceed) / (1 + LIMIT_NULL_DRAWS)


def current_limit_warning(records: Sequence[Any]) -> str | None:
    """Return a warning when the measured current sits at one peak level (a current limit)."""
    masks = limited_samples(records)
    if masks is None:
        return None
    count = int(sum(mask.sum() for mask in masks))
    peak = max(float(np.max(np.abs(rec.current))) for rec in records)
    return (f'the current sits at its peak {peak:.3g} A over {count} samples, reached in a jump '
            'each time: an amplifier current limit. The electrical part is identified from the '
            'samples off the limit (quasi-static regression u = Ra i + CPhi w) and the '
            'mechanical part with the measured current as its input; La is not identifiable')


def useful(parameters: Sequence[str], not_identifiable: dict[str, str],
           mechanical_only: bool) -> bool:
    """Whether anything worth reporting was identified (J, or CPhi in the full mode)."""
    key = ('J',) if mechanical_only else ('J', 'CPhi', 'Ra')
    return any(name in parameters and name not in not_identifiable for name in key)


def useful_check(fit: FinalFit) -> list[str]:
    """Check the answer (:mod:`~.answer`): refuse it when nothing useful is identified."""
    if not useful(fit.names, dict(fit.said), fit.mechanical_only):
        misfit = misfit_ratios(fit.records, fit.outputs, fit.residual_rms)
        columns = ('' if not misfit else ' The model also misfits the data far beyond their '
                   'noise (' + ', '.join(f'{channel} {ratio:.3g}x' for channel, ratio
                                         in misfit.items()) + '): check that the columns are '
                   'what their names say (units, signs: current and speed positive for a '
                   'positive voltage).')
        raise NotIdentifiableError(
            'nothing useful is identifiable from these data: '
            + '; '.join(f'{name}: {reason}' for name, reason in fit.said.items())
            + '. Use a richer excitation (faster changes for La, larger speed changes for J) '
            'or a longer record.' + columns)
    return []


register(Check('current_limit', 'before_fit', 'records', limited_samples,
               "samples at an amplifier's current limit (their own path)"))
register(Check('at_bound', 'after_fit', 'fit', at_bound,
               'parameters at a bound of the fit: not identifiable'))
register(Check('loose', 'after_fit', 'fit', loose,
               'parameters the data do not determine (standard error beyond the value)'))
