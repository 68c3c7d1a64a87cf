"""
The start check's evidence and judgement: model-free regression, the doubts, the BIC.

What the pipeline's start check (:mod:`~dcmotor_id.identification.pipeline.start_check`, which
fits the further starts and the second start) asks of the data and of a fit, without fitting
the motor model.

An output-error fit whose model lacks a decisive effect (a constant torque offset on records
that turn both ways) can settle where the initial states absorb the misfit: a huge J that
never reaches the steady states, initial speeds moved by hundreds of noise levels.  The
effect screen run from there does not find what is missing.  :func:`start_doubts` says when a
result looks like that, judged against evidence that needs no model fit:

* the steady-state balance and the dynamics, by continuous-time least squares on low-passed
  signals (:func:`regression_evidence`: ``K i = J dw/dt + b w + Mc sgn w [+ offset]``, the
  offset column when both directions are present);
* the records' first samples (initial states moved far beyond the noise);
* the misfit far above the sensor noise.

Then a second start is tried (:mod:`~dcmotor_id.identification.pipeline.second_start`): the
regression's values with every initial state pinned to the record's first samples (and the
offset the regression sees, :func:`offset_supported`, as an effect from the start),
discovery run from that sound base, and the final structure refitted with the initial states
free again.  The best of the candidates by the Bayesian information criterion over all of
the data is kept (:func:`bic`), counting the samples the residuals are worth
(:func:`effective_samples`), not every correlated one.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.checks import Check, register
from dcmotor_id.core.model import make_admissible
from dcmotor_id.identification.checks.identifiability import (initial_state_warnings,
                                                              MISFIT_FACTOR)
from dcmotor_id.identification.error_model.residuals import (output_channels, simulate_records,
                                                             simulated as simulated_outputs,
                                                             Simulation)
from dcmotor_id.signals.filters import low_pass

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate

#: Cut-off of the regression's low-pass filter, as a fraction of the sample rate.
REGRESSION_CUTOFF = 0.02
#: Factor between a fitted J or b and the regression's beyond which the fit is suspect.
EVIDENCE_FACTOR = 3.0
#: Standard errors (effective samples) beyond which the regression's offset is an effect.
OFFSET_T = 3.0
#: Least share of the regression's Coulomb friction of an offset taken as an effect.
OFFSET_SHARE = 0.1
#: Default of the ``evidence`` arguments of the start checks: the regression is computed from
#: the records (:func:`known_evidence`); callers that have it pass it instead (once a run).
FROM_RECORDS = 'from the records'


def both_directions(records: Sequence[Record]) -> bool:
    """Whether the records turn both ways (beyond a fifth of the largest speed)."""
    speed = np.concatenate([np.asarray(rec.speed, dtype=float) for rec in records])
    top = float(np.max(np.abs(speed))) if speed.shape[0] else 0.0
    return bool(np.any(speed > 0.2 * top) and np.any(speed < -0.2 * top))


def regression_evidence(records: Sequence[Record],
                        torque_constant: float | None = None) -> dict[str, float] | None:
    """
    Model-free values by least squares on low-passed signals; None when not determined.

    The mechanical equation ``T = J dw/dt + b w + Mc sgn(w) + offset`` (the offset only when
    both directions are present) with ``T = K i`` in the mechanical-only mode; in the full
    mode also ``u = La di/dt + Ra i + CPhi w`` and ``T = CPhi i``.  Returns the base
    parameters (``Ra, La, CPhi`` in the full mode, ``J, b, Mc``) and ``offset`` [N m].
    """
    offset = both_directions(records)
    mechanical_only = torque_constant is not None
    rows_m, rhs_m, rows_e, rhs_e = regression_rows(records, torque_constant, offset)
    if not rows_m:
        return None
    try:
        matrix, rhs = np.vstack(rows_m), np.concatenate(rhs_m)
        mech = np.linalg.lstsq(matrix, rhs, rcond=None)[0]
        cphi = 1.0
        values: dict[str, float] = {}
        if not mechanical_only:
            la, ra, cphi = np.linalg.lstsq(np.vstack(rows_e), np.concatenate(rhs_e),
                                           rcond=None)[0]
            values = {'Ra': float(ra), 'La': float(la), 'CPhi': float(cphi)}
    except np.linalg.LinAlgError:
        return None
    values.update({'J': float(mech[0] * cphi), 'b': float(mech[1] * cphi),
                   'Mc': float(mech[2] * cphi),
                   'offset': float(mech[3] * cphi) if offset else 0.0})
    if offset:
        values['offset_stderr'] = float(abs(cphi) * _last_stderr(matrix, rhs, mech))
    if not all(np.isfinite(value) for value in values.values()):
        return None
    return values


def regression_rows(records: Sequence[Record], torque_constant: float | None, offset: bool,
                    left_out: Sequence[np.ndarray | None] | None = None,
                    held_voltage: bool = False
                    ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray],
                               list[np.ndarray]]:
    """
    Rows of the regression's two equations, per record, on zero-phase low-passed signals.

    Mechanical: columns ``dw/dt, w, sgn w [, 1]`` against ``i`` (times ``torque_constant`` in
    the mechanical-only mode); electrical (full mode): ``di/dt, i, w`` against ``u``.  The
    filter's settling is trimmed at both ends of each record; ``left_out``: per record, a
    boolean mask of samples the rows must not rest on (None: every sample is used);
    ``held_voltage``: the logged voltage is the one held over the sample period after it (the
    package's model and simulator): its low-passed value at ``t_k - dt/2``, the mean of
    samples ``k-1`` and ``k``, is the one the states at ``t_k`` answer (taken at ``t_k`` the
    hold's half-sample delay reads as an La larger by ``Ra dt/2``).
    Returns ``(rows_m, rhs_m, rows_e, rhs_e)``, one array per record that is long enough.
    """
    mechanical_only = torque_constant is not None
    rows_m, rhs_m, rows_e, rhs_e = [], [], [], []
    for index, rec in enumerate(records):
        n = len(rec)
        trim = min(int(3.0 / (REGRESSION_CUTOFF * 2 * np.pi)) + 2, n // 4)
        keep = np.zeros(n, dtype=bool)
        keep[trim:n - trim] = True
        mask = None if left_out is None else left_out[index]
        if mask is not None and np.any(mask):
            # Every row within the filter's reach of a left-out sample rests on it.
            reach = np.convolve(mask.astype(float), np.ones(2 * trim + 1), mode='same')
            keep &= reach == 0.0
        if np.count_nonzero(keep) < 20:
            continue
        dt = rec.sample_period_s
        measured = np.asarray(rec.speed, dtype=float)
        current = low_pass(np.asarray(rec.current, dtype=float), REGRESSION_CUTOFF)
        speed = low_pass(measured, REGRESSION_CUTOFF)
        sign = low_pass(np.sign(measured), REGRESSION_CUTOFF)
        columns = [np.gradient(speed, dt), speed, sign] + ([np.ones(n)] if offset else [])
        rows_m.append(np.column_stack(columns)[keep])
        rhs_m.append(current[keep] * (torque_constant or 1.0))
        if not mechanical_only:
            rows_e.append(np.column_stack([np.gradient(current, dt), current, speed])[keep])
            volts = low_pass(np.asarray(rec.voltage, dtype=float), REGRESSION_CUTOFF)
            if held_voltage:
                volts = 0.5 * (volts + np.concatenate([volts[:1], volts[:-1]]))
            rhs_e.append(volts[keep])
    return rows_m, rhs_m, rows_e, rhs_e


def known_evidence(records: Sequence[Record], torque_constant: float | None,
                   evidence: dict[str, float] | None | str) -> dict[str, float] | None:
    """Return ``evidence``, or :func:`regression_evidence` when it is :data:`FROM_RECORDS`."""
    if isinstance(evidence, str):
        return regression_evidence(records, torque_constant)
    return evidence


def _last_stderr(matrix: np.ndarray, rhs: np.ndarray, solution: np.ndarray) -> float:
    """
    Return the standard error of the last coefficient of a least-squares fit on low-passed data.

    The residual of low-passed signals is correlated over about ``1 / (2 REGRESSION_CUTOFF)``
    samples: the samples count as that many fewer independent ones.
    """
    n, p = matrix.shape
    effective = max(n * 2.0 * REGRESSION_CUTOFF, p + 1.0)
    residual = rhs - matrix @ solution
    variance = float(residual @ residual) / max(n - p, 1) * n / effective
    try:
        covariance = np.linalg.inv(matrix.T @ matrix)
    except np.linalg.LinAlgError:
        return float('inf')
    return float(np.sqrt(max(variance * covariance[-1, -1], 0.0)))


def offset_supported(evidence: dict[str, float] | None) -> bool:
    """
    Whether the regression sees a constant torque offset between the two directions.

    Its value must exceed :data:`OFFSET_T` standard errors (effective samples) and
    :data:`OFFSET_SHARE` of the regression's Coulomb friction.
    """
    if evidence is None or not np.isfinite(evidence.get('offset_stderr', np.nan)):
        return False
    offset = abs(evidence['offset'])
    return bool(offset > OFFSET_T * evidence['offset_stderr']
                and offset > OFFSET_SHARE * abs(evidence['Mc']))


def pooled_noise(records: Sequence[Record], channel: str) -> float:
    """Sensor noise of a channel over the records: the RMS of their :func:`noise_level`."""
    return float(np.sqrt(np.mean([rec.noise_level(channel) ** 2 for rec in records])))


def misfit_ratio(estimate: Estimate, records: Sequence[Record], model: Any,
                 carried: Simulation | None = None) -> float:
    """
    Largest residual RMS over the sensor noise among the output channels.

    The sensor noise is the :func:`pooled_noise` of the records' own levels, each measured
    once per record (:meth:`~dcmotor_id.core.records.Record.noise_level`).  ``carried``: a
    simulation a stage already ran, used when it is this estimate's on this model
    (:func:`~dcmotor_id.identification.error_model.residuals.simulated`).
    """
    simulated = simulated_outputs(model, estimate.parameters, estimate.initial_states,
                                  carried).outputs
    worst = 0.0
    for channel in model.outputs:
        residual = np.concatenate([out[channel] - getattr(rec, channel)
                                   for out, rec in zip(simulated, records)])
        noise_std = pooled_noise(records, channel)
        rms = float(np.sqrt(np.mean(residual ** 2))) if residual.shape[0] else 0.0
        worst = max(worst, rms / max(noise_std, 1e-300))
    return worst


@dataclass(frozen=True)
class StartDoubts:
    """
    Why a fit may sit in a wrong basin, per remedy (:func:`start_doubts`; empty: no doubt).

    ``further_starts``: reasons to fit the base model again from further starts
    (:mod:`~dcmotor_id.identification.pipeline.further_starts`); ``second_start``: reasons for
    a second
    start with the initial states pinned (:mod:`~dcmotor_id.identification.pipeline.second_start`).
    """

    further_starts: list[str]
    second_start: list[str]


def start_doubts(estimate: Estimate, records: Sequence[Record], model: Any,
                 evidence: dict[str, float] | None,
                 carried: Simulation | None = None) -> StartDoubts:
    """
    Say why a fit may have settled in a wrong basin, for both remedies (one place, one test).

    Both read the misfit over the sensor noise (beyond
    :data:`~dcmotor_id.identification.checks.identifiability.MISFIT_FACTOR`) and J or b
    against the model-free regression (beyond :data:`EVIDENCE_FACTOR`,
    :func:`far_from_evidence`):

    * further starts of the base fit (cheap): either of the two suffices;
    * a second start (a discovery loop of its own): the misfit, and besides it initial states
      moved far from the first samples or J or b far from the regression.

    Every list starts with the misfit when it is beyond the threshold.  ``carried``: a
    simulation a stage already ran (:func:`misfit_ratio`).
    """
    ratio = misfit_ratio(estimate, records, model, carried)
    misfit = [f'the misfit is {ratio:.3g}x the sensor noise'] if ratio > MISFIT_FACTOR else []
    far = far_from_evidence(estimate.parameters, evidence)
    if not misfit:
        return StartDoubts(far, [])
    moved = initial_state_warnings(estimate, records,
                                   output_channels(model.torque_constant is not None))
    second = ([f'{len(moved)} initial state(s) moved far from the first samples']
              if moved else []) + far
    return StartDoubts(misfit + far, misfit + second if second else [])


def far_from_evidence(parameters: dict[str, float],
                      evidence: dict[str, float] | None) -> list[str]:
    """Say which of J and b lie more than :data:`EVIDENCE_FACTOR` from the regression's."""
    reasons: list[str] = []
    if evidence is None:
        return reasons
    for name in ('J', 'b'):
        fitted, seen = parameters[name], evidence[name]
        if seen > 0 and fitted > 0 and not (1 / EVIDENCE_FACTOR < fitted / seen
                                            < EVIDENCE_FACTOR):
            reasons.append(f'{name} = {fitted:.4g} is {fitted / seen:.3g}x the model-free '
                           f'regression ({seen:.4g})')
    return reasons


def regression_start(evidence: dict[str, float] | None, fallback: dict[str, float],
                     names: Sequence[str]) -> dict[str, float]:
    """Start values from the regression where admissible, else from ``fallback``."""
    start = {name: float(fallback[name]) for name in names}
    if evidence is None:
        return start
    admissible = make_admissible({name: evidence[name] for name in names if name in evidence})
    if admissible is not None:
        start.update(admissible)
    return start


def weighted_cost(estimate: Estimate, records: Sequence[Record], model: Any) -> tuple[float, int]:
    """Sum of squared residuals over the channels' noise (as the fit saw it), and the count."""
    simulated = simulate_records(model, estimate.parameters, estimate.initial_states)
    noise = estimate.info.get('noise_std', {})
    total, count = 0.0, 0
    for channel in model.outputs:
        spread = float(np.std(np.concatenate([getattr(rec, channel) for rec in records])))
        weight = max(float(noise.get(channel, 0.0)), 1e-6 * spread, 1e-300)
        for out, rec in zip(simulated, records):
            residual = (out[channel] - getattr(rec, channel)) / weight
            value = float(residual @ residual)
            total += value if np.isfinite(value) else np.inf
            count += residual.shape[0]
    return total, count


def bic(estimate: Estimate, records: Sequence[Record], model: Any,
        noise: dict[str, float], free_states: bool = True,
        effective: float | None = None) -> float:
    """
    Bayesian information criterion of a fit on all of the data, under common weights.

    ``free_states``: the initial states were fitted (they count as parameters).
    ``effective``: the number of independent samples the residuals are worth
    (:func:`effective_samples`; default: every sample counts).
    """
    weighted = replace(estimate, info={**estimate.info, 'noise_std': noise})
    cost, count = weighted_cost(weighted, records, model)
    k = len(estimate.parameters) + (len(records) * len(model.outputs) if free_states else 0)
    if not np.isfinite(cost):
        return float('inf')
    n = float(count if effective is None else min(max(effective, 2.0), count))
    return float(n * np.log(max(cost / max(count, 1), 1e-300)) + k * np.log(max(n, 2.0)))


def correlation_time(residual: np.ndarray) -> float:
    """
    Integrated autocorrelation time of a residual [samples]: 1 for white noise.

    ``1 + 2 sum(rho_k)`` over the lags before the autocorrelation first drops to zero.
    """
    x = np.asarray(residual, dtype=float)
    x = x[np.isfinite(x)] - np.mean(x[np.isfinite(x)]) if x.shape[0] else x
    n = x.shape[0]
    if n < 3 or not np.any(x):
        return 1.0
    spectrum = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:n]
    acf = acf / acf[0]
    negative = np.flatnonzero(acf[1:] <= 0.0)
    stop = int(negative[0]) + 1 if negative.shape[0] else n
    return float(max(1.0 + 2.0 * np.sum(acf[1:stop]), 1.0))


def bic_scores(candidates: dict[Any, tuple[Estimate, Sequence[Record], Any, bool]],
               noise: dict[str, float]) -> tuple[dict[Any, float], float]:
    """
    Score fits of one data set by :func:`bic` on the samples their residuals are worth.

    ``candidates``: key -> ``(fit, records, model, free_states)``.  Every fit is counted on
    the fewest :func:`effective_samples` over the candidates, so that a free parameter
    absorbing a slow misfit does not win on thousands of correlated samples.  Returns the
    scores by key and that number of samples.
    """
    effective = min(effective_samples(fit, records, model)
                    for fit, records, model, _ in candidates.values())
    return ({key: bic(fit, records, model, noise, free_states=free, effective=effective)
             for key, (fit, records, model, free) in candidates.items()}, effective)


def effective_samples(estimate: Estimate, records: Sequence[Record], model: Any) -> float:
    """
    Return the number of independent samples a fit's residuals are worth.

    Each record's length over its residual's correlation time (:func:`correlation_time`),
    summed over records and output channels.

    A slow misfit correlated over seconds is worth a few samples, not thousands: counted as
    independent it makes any free parameter that absorbs part of it (an initial speed moved
    by many noise levels) win the BIC comparison.
    """
    simulated = simulate_records(model, estimate.parameters, estimate.initial_states)
    total = 0.0
    for channel in model.outputs:
        for out, rec in zip(simulated, records):
            residual = out[channel] - getattr(rec, channel)
            total += residual.shape[0] / correlation_time(residual)
    return total


register(Check('start', 'after_fit', 'fit', start_doubts,
               'a base fit far from the model-free evidence or misfitting: a second start'))
