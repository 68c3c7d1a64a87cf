"""
A floor under every answer: the model-free regression, its standard errors, and the choice.

The output-error fit can fail where a two-line regression does not: a simulation that
diverges from a poor start, an evaluation budget spent in a flat valley, a step whose logged
voltage does not reach the motor at once.  :func:`regression_floor` computes the equation
error regression (zero-phase low-passed signals and their derivatives, as IDIM-LS does; the
rows are those of the start check,
:func:`~dcmotor_id.identification.checks.start.regression_rows`) for both equations::

    u = Ra i + La di/dt + CPhi w              (electrical; full mode)
    CPhi i = J dw/dt + b w + Mc sgn w [+ c]   (mechanical; c when both directions are present)

with standard errors counted on the samples the residual is worth (its correlation time,
:func:`~dcmotor_id.identification.checks.start.correlation_time`); the logged voltage is read
as held over the sample after it (the package's model).  An electrical time constant below the
sample period, an undetermined La, or one the current's raw samples reject as slower than they
show (:func:`~dcmotor_id.identification.checks.armature_lag.lag_profile`: the filtered di/dt
absorbs a misfit at the steps, such as a status frame's lag) makes the electrical equation
static (``u = Ra i + CPhi w``, La and Ta upper bounds).  Samples where the logged voltage does
not reach the motor (an amplifier's ramp or slew after a step: the electrical residual far
beyond its noise for several samples in a row from the step on, and the one-step test of the
current beyond its 1 % bound) are left out of both equations and named (:func:`ramp_samples`).

:func:`heldout_error` measures a parameter set on the held-out end of every record (the one
the discovery loop holds out, :func:`~dcmotor_id.identification.discovery.parts.excited_stop`),
simulated from the records' first samples or the fit's own initial states, so that the caller
keeps the output-error result only where it predicts at least as well as the regression
(:func:`floor_choice`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import (DERIVED_NAMES, derived_values, MECHANICAL_NAMES,
                                   PARAMETER_NAMES, UNITS)
from dcmotor_id.identification.checks.armature_lag import lag_profile
from dcmotor_id.identification.checks.identifiability import (IDENTIFIABLE_REL_STDERR,
                                                              limited_samples)
from dcmotor_id.identification.checks.ramp import (bonferroni_bound, ramp_masks,
                                                   record_shortfalls)
from dcmotor_id.identification.checks.start import (both_directions, correlation_time,
                                                    regression_rows)
from dcmotor_id.identification.discovery.parts import excited_stop
from dcmotor_id.identification.error_model.residuals import output_channels
from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm
from dcmotor_id.identification.estimators.least_squares import nonnegative_lstsq
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.pipeline.fit_outcome import simulation_errors
from dcmotor_id.identification.pipeline.run import identify_checked
from dcmotor_id.identification.pipeline.segments import split_tests
from dcmotor_id.identification.pipeline.state import Request
from dcmotor_id.identification.result import IdentificationResult
from dcmotor_id.identification.validate import operating_range

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: Robust noise levels of the electrical residual beyond which a sample is an outlier.
RAMP_NOISE_FACTOR = 8.0
#: Fewest consecutive outlying samples from a step on that make a ramp (one or two samples
#: are a step's own sampling).
RAMP_MIN_SAMPLES = 4
#: Share of a run's residual a larger La must explain for it to be an armature transient.
INDUCTIVE_R2 = 0.95
#: Relative standard error of La beyond which La counts as undetermined.
LA_UNDETERMINED_REL = 0.5
#: How the standard errors of the regression's answer are obtained (``uncertainty_method``).
FLOOR_UNCERTAINTY = ("the regression's: least squares on the samples its residual is worth "
                     '(its correlation time)')
#: Likelihood-ratio threshold (chi-square, one degree of freedom, 0.1 %) La's column must pass.
LA_CHI2 = 10.83
#: Margin (percentage points of NRMSE) by which the regression must predict the held-out
#: part better before it replaces the output-error result.
FLOOR_MARGIN_PCT = 1.0
#: Largest simulation error [% of the spread] of the regression's answer given as a fallback
#: (the output-error path's own limit, ``NO_FIT_NRMSE_PCT`` of the identification).
FALLBACK_NRMSE_PCT = 60.0
#: Largest ratio of the regression's held-out error to the fit's at which it replaces the fit.
FLOOR_RATIO = 0.8


@dataclass(frozen=True)
class EquationFit:
    """One equation's least-squares fit: values, standard errors, residual, sample worth."""

    values: dict[str, float]
    stderr: dict[str, float]
    residual_rms: float
    effective_samples: float


@dataclass(frozen=True)
class LeftOut:
    """Samples of a record left out of the regression (a command that did not reach the motor)."""

    source: str
    start_sample: int
    end_sample: int
    start_s: float
    end_s: float


@dataclass(frozen=True)
class RegressionFloor:
    """
    The regression's answer for both equations (:func:`regression_floor`).

    ``parameters`` and ``stderr``: ``Ra, La, CPhi, J, b, Mc, Ka, Ta`` in the full mode, ``J, b,
    Mc`` in the mechanical-only one (NaN where not determined).  ``static_electrical``: the
    electrical equation was fitted without La (La is then an upper bound, ``la_upper_bound``).
    ``left_out``: the samples not used; ``usable``: the values are physical (Ra, CPhi, J > 0).
    """

    parameters: dict[str, float]
    stderr: dict[str, float]
    electrical: EquationFit | None
    mechanical: EquationFit | None
    static_electrical: bool
    la_upper_bound: float | None
    left_out: tuple[LeftOut, ...]
    usable: bool

    def left_out_text(self) -> str:
        """Name the samples left out (empty when none)."""
        return '; '.join(f'{item.source or "record"} samples {item.start_sample}-'
                         f'{item.end_sample - 1} ({item.start_s:.4g}-{item.end_s:.4g} s)'
                         for item in self.left_out)


def _solve(matrix: np.ndarray, rhs: np.ndarray,
           names: Sequence[str]) -> EquationFit | None:
    """Least squares with standard errors on the samples the residual is worth."""
    if matrix.shape[0] <= matrix.shape[1] + 2:
        return None
    # Normal equations on columns scaled to unit norm (a few columns, many rows: fast).
    norms = np.sqrt(np.einsum('ij,ij->j', matrix, matrix))
    if not np.all(norms > 0):
        return None
    scaled = matrix / norms
    try:
        inverse = np.linalg.inv(scaled.T @ scaled)
    except np.linalg.LinAlgError:
        return None
    solution = inverse @ (scaled.T @ rhs) / norms
    covariance = inverse / np.outer(norms, norms)
    residual = rhs - matrix @ solution
    n, p = matrix.shape
    effective = max(n / correlation_time(residual), p + 1.0)
    variance = float(residual @ residual) / max(n - p, 1) * n / effective
    stderr = np.sqrt(np.maximum(np.diag(covariance) * variance, 0.0))
    if not np.all(np.isfinite(solution)):
        return None
    return EquationFit(dict(zip(names, map(float, solution))),
                       dict(zip(names, map(float, stderr))),
                       float(np.sqrt(np.mean(residual ** 2))), float(effective))


def _solve_admissible(matrix: np.ndarray, rhs: np.ndarray,
                      names: Sequence[str]) -> EquationFit | None:
    """
    Solve the mechanical equation by least squares with J, b and Mc at least zero.

    Where the unconstrained solution gives one of them below zero (a spin-up the filtered
    derivative smears, one speed level that cannot separate b from Mc), the bounded problem is
    solved (:func:`~dcmotor_id.identification.estimators.least_squares.nonnegative_lstsq`) and
    the columns it holds at zero are left out: the others and their standard errors are the
    least squares without them, the held ones are 0 with no standard error
    (:func:`_floor_values` names them).
    """
    free = _solve(matrix, rhs, names)
    signed = [name != 'offset' for name in names]
    if free is None or all(free.values[name] >= 0.0 for name, sign in zip(names, signed)
                           if sign):
        return free
    held = nonnegative_lstsq(matrix, rhs, signed)[1]
    keep = [index for index in range(len(names)) if not held[index]]
    reduced = _solve(matrix[:, keep], rhs, [names[index] for index in keep]) if keep else None
    if reduced is None:
        return None
    values = {name: reduced.values.get(name, 0.0) for name in names}
    stderr = {name: reduced.stderr.get(name, float('nan')) for name in names}
    return EquationFit(values, stderr, reduced.residual_rms, reduced.effective_samples)


def ramp_samples(records: Sequence[Record]) -> list[np.ndarray]:
    """
    Per record, the samples after a step where the logged voltage did not reach the motor.

    Those after a step at the record's start (:func:`start_ramp_samples`, kept where the
    one-step test also finds the current short at the start, :func:`_start_shortfall`) and
    those after any step by the one-step test of the electrical equation
    (:func:`~dcmotor_id.identification.checks.ramp.ramp_masks`; steps into a current limit
    are the limit's).  ``bench/bench_ramp.py`` measures both rules' size and power.
    """
    limited = limited_samples(records) if all(rec.current is not None for rec in records) \
        else None
    starts = start_ramp_samples(records)
    for index, record in enumerate(records):
        if starts[index].any() and not _start_shortfall(
                record, None if limited is None else limited[index]):
            starts[index] = np.zeros_like(starts[index])
    after = ramp_masks(records, _step_starts, limited)
    return [first | later for first, later in zip(starts, after)]


def _start_shortfall(record: Record, limited: np.ndarray | None) -> bool:
    """
    Whether the current after a record's first step falls short beyond chance (a ramp's sign).

    The one-step test of the electrical equation (an ARX model of the current,
    :func:`~dcmotor_id.identification.checks.ramp.record_shortfalls`) at the record's start:
    its z beyond the Bonferroni bound of the record's 1 % test.  The start check's runs of
    outlying residual (:func:`start_ramp_samples`, on raw derivatives) also follow a fast
    armature or spin-up that the derivatives smear (La/Ra near the sample period, a
    mechanical time constant of a few samples): those fall short by no more than chance.
    """
    steps = _step_starts(np.asarray(record.voltage, dtype=float))
    first = [item for item in record_shortfalls(record, steps, limited) if item.start == 0]
    return bool(first) and first[0].z > bonferroni_bound(len(steps))


def start_ramp_samples(records: Sequence[Record]) -> list[np.ndarray]:
    """
    Per record, the samples after a step at its start where the voltage did not reach the motor.

    The electrical equation ``u = Ra i + La di/dt + CPhi w`` is fitted on the raw samples
    (twice, the second time without the outliers of the first); a run of at least
    :data:`RAMP_MIN_SAMPLES` samples beyond :data:`RAMP_NOISE_FACTOR` robust noise levels of
    its residual, with the sign of the step and starting at a logged voltage step (or the
    record's first samples), is a command the motor did not get at once.
    """
    if not any(first == 0 for rec in records
               for first, _ in _step_starts(np.asarray(rec.voltage, dtype=float))[:1]):
        return [np.zeros(len(rec), dtype=bool) for rec in records]  # no step at a start
    raw = []
    for rec in records:
        dt = rec.sample_period_s
        current = np.asarray(rec.current, dtype=float)
        raw.append((np.column_stack([np.gradient(current, dt), current,
                                     np.asarray(rec.speed, dtype=float)]),
                    np.asarray(rec.voltage, dtype=float)))
    matrix = np.vstack([rows for rows, _ in raw])
    rhs = np.concatenate([volts for _, volts in raw])
    inliers = np.concatenate([~_after_steps(volts) for _, volts in raw])
    if np.count_nonzero(inliers) < 4 * matrix.shape[1]:
        inliers[:] = True
    sigma = 0.0
    for _ in range(3):
        try:
            solution = np.linalg.lstsq(matrix[inliers], rhs[inliers], rcond=None)[0]
        except np.linalg.LinAlgError:
            return [np.zeros(len(rec), dtype=bool) for rec in records]
        residual = rhs - matrix @ solution
        centred = residual[inliers] - np.median(residual[inliers])
        sigma = 1.4826 * float(np.median(np.abs(centred)))
        inliers = np.abs(residual) <= RAMP_NOISE_FACTOR * max(sigma, 1e-12)
    masks, start = [], 0
    for rows, volts in raw:
        part = residual[start:start + volts.shape[0]]
        start += volts.shape[0]
        masks.append(_ramp_runs(part, volts, rows[:, 0],
                                RAMP_NOISE_FACTOR * max(sigma, 1e-12)))
    return masks


def _step_starts(volts: np.ndarray) -> list[tuple[int, float]]:
    """Return the logged voltage steps (beyond a tenth of the range) and signs; a start too."""
    n = volts.shape[0]
    span = max(float(np.ptp(volts)) if n else 0.0, 1e-12)
    jumps = np.flatnonzero(np.abs(np.diff(volts)) > 0.1 * span) + 1
    starts = [(0, float(np.sign(volts[0])))] if n and abs(volts[0]) > 0.1 * span else []
    return starts + [(int(k), float(np.sign(volts[k] - volts[k - 1]))) for k in jumps]


def _after_steps(volts: np.ndarray) -> np.ndarray:
    """Mark the samples just after each logged step (up to 50, at most a quarter of the dwell)."""
    mask = np.zeros(volts.shape[0], dtype=bool)
    starts = [first for first, _ in _step_starts(volts)]
    for first, following in zip(starts, starts[1:] + [volts.shape[0]]):
        mask[first:first + min(50, max((following - first) // 4, 1))] = True
    return mask


def _ramp_runs(residual: np.ndarray, volts: np.ndarray, slope: np.ndarray,
               limit: float) -> np.ndarray:
    """Mark the runs of outlying residual, of the step's sign, that start at a voltage step."""
    n = volts.shape[0]
    mask = np.zeros(n, dtype=bool)
    # Only a step at the record's start: mid-record steps of a well-fitted armature showed
    # runs too (an La the raw-derivative fit underrates), which this test cannot tell apart.
    starts = [(first, sign) for first, sign in _step_starts(volts) if first == 0]
    for first, sign in starts:
        k = first
        while k < n and k < first + 2 and not sign * residual[k] > limit:
            k += 1  # the step may show one sample late
        stop = k
        while stop < n and sign * residual[stop] > limit:
            stop += 1
        if stop - k >= RAMP_MIN_SAMPLES and not _inductive(residual[k:stop], slope[k:stop]):
            mask[first:stop] = True
    return mask


def _inductive(residual: np.ndarray, slope: np.ndarray) -> bool:
    """
    Whether a run of residual is an armature transient the fit's La underrates.

    Such a residual is proportional to the current's slope (``dLa di/dt``): a line through
    the origin explains at least :data:`INDUCTIVE_R2` of it.  A ramp's residual falls while
    the current rises at a steady rate, which no La explains.
    """
    power = float(slope @ slope)
    if power <= 0.0:
        return False
    explained = float(slope @ residual) ** 2 / power
    return explained >= INDUCTIVE_R2 * float(residual @ residual)


def _left_out(records: Sequence[Record], masks: Sequence[np.ndarray]) -> tuple[LeftOut, ...]:
    """Describe every run of left-out samples."""
    items = []
    for rec, mask in zip(records, masks):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
        time_s = np.asarray(rec.time_s, dtype=float)
        for first, stop in zip(edges[::2], edges[1::2]):
            items.append(LeftOut(rec.source, int(first), int(stop), float(time_s[first]),
                                 float(time_s[stop - 1])))
    return tuple(items)


def _electrical(rows_e, rhs_e, records: Sequence[Record], masks: Sequence[np.ndarray],
                on_samples: EquationFit | None
                ) -> tuple[EquationFit | None, bool, float | None]:
    """
    Fit the electrical equation: dynamic, or static (La a bound) when La is unresolved.

    The choice is made on the filtered rows and checked on the raw samples: a dynamic La whose
    time constant, even at the lower end of its interval, the current's samples reject as too
    slow (:func:`~dcmotor_id.identification.checks.armature_lag.lag_profile`: a misfit at the
    steps that the filtered di/dt absorbed) is not kept.  The static values are ``on_samples``
    (the static equation on the samples as logged, :func:`_static_on_samples`) where it has
    them.
    """
    dt = records[0].sample_period_s
    matrix, rhs = np.vstack(rows_e), np.concatenate(rhs_e)
    dynamic = _solve(matrix, rhs, ('La', 'Ra', 'CPhi'))
    if dynamic is None:
        return None, False, None
    la, ra = dynamic.values['La'], dynamic.values['Ra']
    la_se = dynamic.stderr['La']
    static = _solve(matrix[:, 1:], rhs, ('Ra', 'CPhi'))
    if static is None:
        return None, True, None
    # La earns its column when it lowers the residual beyond chance on the effective samples
    # (likelihood ratio, one degree of freedom, 0.1 %).
    gain = 2.0 * dynamic.effective_samples * (np.log(max(static.residual_rms, 1e-300))
                                              - np.log(max(dynamic.residual_rms, 1e-300)))
    profile = None
    if ra > 0 and la > 0 and la / ra >= dt and la_se <= LA_UNDETERMINED_REL * la and \
            gain > LA_CHI2:
        # Its time constant at the lower end of La's interval (the same level) must not be
        # slower than the current's samples show.
        lowest = (la - np.sqrt(LA_CHI2) * la_se) / ra
        profile = lag_profile(records, masks, lowest) if lowest > 0 else None
        if profile is None or not profile.claimed_too_slow:
            return dynamic, False, None
    static = on_samples or static
    ra = static.values['Ra']
    # A dynamic La inside the resolved range that the data do not confirm bounds La; one
    # beyond it (a time constant the records would show) says nothing, unless the current's
    # samples bound the time constant (the profile's bound, which errs on the long side).
    resolved = ra > 0 and 0 < la < abs(ra) * dt
    bound = max(abs(ra) * dt, la + 2.0 * la_se if resolved else 0.0,
                abs(ra) * profile.upper_s if profile is not None else 0.0)
    values = {'La': bound, **static.values}
    stderr = {'La': float('nan'), **static.stderr}
    return (EquationFit(values, stderr, static.residual_rms, static.effective_samples), True,
            bound)


def _static_on_samples(records: Sequence[Record],
                       masks: Sequence[np.ndarray]) -> EquationFit | None:
    """
    Fit the static electrical equation ``u = Ra i + CPhi w`` on the samples as logged.

    It has no derivative, so it needs neither the low-pass nor the trim of the filter's
    settling at the records' ends, which on a short spin-up (a step from rest on a motor whose
    mechanical time constant is a few samples) would leave only the steady state, where ``i``
    and ``w`` are constant and Ra and CPhi not separable.  Every sample but the left-out ones
    (``masks``) counts; None when a record's speed was derived from its position (that speed
    is low-passed, the current is not: the filtered equation pairs them) or the fit fails.
    """
    if any(rec.speed_derived for rec in records):
        return None
    keep = [~mask & np.isfinite(np.asarray(rec.current, dtype=float))
            & np.isfinite(np.asarray(rec.speed, dtype=float))
            & np.isfinite(np.asarray(rec.voltage, dtype=float))
            for rec, mask in zip(records, masks)]
    matrix = np.vstack([np.column_stack([np.asarray(rec.current, dtype=float)[kept],
                                         np.asarray(rec.speed, dtype=float)[kept]])
                        for rec, kept in zip(records, keep)])
    rhs = np.concatenate([np.asarray(rec.voltage, dtype=float)[kept]
                          for rec, kept in zip(records, keep)])
    fit = _solve(matrix, rhs, ('Ra', 'CPhi'))
    if fit is None or not (fit.values['Ra'] > 0 and fit.values['CPhi'] != 0):
        return None
    return fit


def regression_floor(records: Sequence[Record],
                     torque_constant: float | None = None) -> RegressionFloor | None:
    """
    Return the regression's answer for both equations (None when the records are too short).

    In the full mode the samples of a command that did not reach the motor
    (:func:`ramp_samples`) are left out first.
    """
    mechanical_only = torque_constant is not None
    masks = ([np.zeros(len(rec), dtype=bool) for rec in records] if mechanical_only
             else ramp_samples(records))
    offset = both_directions(records)
    rows_m, rhs_m, rows_e, rhs_e = regression_rows(records, torque_constant, offset, masks,
                                                   held_voltage=True)
    if not rows_m or (not mechanical_only and not rows_e):
        return None
    electrical, static, bound = (None, False, None) if mechanical_only else _electrical(
        rows_e, rhs_e, records, masks, _static_on_samples(records, masks))
    names = ('J', 'b', 'Mc') + (('offset',) if offset else ())
    mechanical = _solve_admissible(np.vstack(rows_m), np.concatenate(rhs_m), names)
    if mechanical is None or (not mechanical_only and electrical is None):
        return None
    parameters, stderr = _combined(electrical, mechanical)
    usable = all(np.isfinite(parameters[name]) and parameters[name] > 0
                 for name in ('Ra', 'CPhi', 'J') if name in parameters)
    return RegressionFloor(parameters, stderr, electrical, mechanical, static, bound,
                           _left_out(records, masks), bool(usable))


def _combined(electrical: EquationFit | None,
              mechanical: EquationFit) -> tuple[dict[str, float], dict[str, float]]:
    """Physical values and standard errors: the mechanical equation scaled by CPhi."""
    cphi, cphi_rel = 1.0, 0.0
    parameters: dict[str, float] = {}
    stderr: dict[str, float] = {}
    if electrical is not None:
        cphi = electrical.values['CPhi']
        cphi_rel = electrical.stderr['CPhi'] / abs(cphi) if cphi else float('inf')
        for name in ('Ra', 'La', 'CPhi'):
            parameters[name] = electrical.values[name]
            stderr[name] = electrical.stderr[name]
    for name in ('J', 'b', 'Mc'):
        value = mechanical.values[name]
        parameters[name] = value * cphi
        relative = mechanical.stderr[name] / abs(value) if value else float('inf')
        stderr[name] = abs(value * cphi) * float(np.hypot(relative, cphi_rel)) if value else \
            abs(cphi) * mechanical.stderr[name]
    if electrical is not None:
        derived = derived_values(parameters)
        parameters.update(derived)
        ra, la = parameters['Ra'], parameters['La']
        stderr['Ka'] = stderr['Ra'] / ra ** 2 if ra else float('nan')
        stderr['Ta'] = float('nan') if not np.isfinite(stderr['La']) else float(
            abs(la / ra) * np.hypot(stderr['La'] / la, stderr['Ra'] / ra))
    return parameters, stderr


def first_states(records: Sequence[Record], mechanical_only: bool) -> list[list[float]]:
    """Return initial states from the records' first samples (mean of up to 3), per output."""
    return [[float(np.mean(np.asarray(getattr(rec, channel), dtype=float)[:3]))
             for channel in output_channels(mechanical_only)] for rec in records]


def heldout_stops(records: Sequence[Record]) -> list[int]:
    """Return the first held-out sample of each record (:func:`heldout_error`'s ``stops``)."""
    return [excited_stop(rec) for rec in records]


def heldout_error(parameters: dict[str, float], initial_states: Sequence[Sequence[float]],
                  records: Sequence[Record], torque_constant: float | None,
                  quasi_static: bool, terms: Sequence[ExogenousTerm] = (),
                  stops: Sequence[int] | None = None) -> float:
    """
    Worst channel's NRMSE [%] over the held-out ends of the records (whole record's spread).

    The held-out end is the one the discovery loop holds out
    (:func:`~dcmotor_id.identification.discovery.parts.excited_stop`); inf when the
    simulation does not stay finite.  ``terms``: the effect terms of a fit with effects (its
    ``records`` then those the terms were built on: data effects applied).  ``stops``: the
    records' :func:`heldout_stops`, when the caller has them (else computed here).  Each
    record is simulated once and its held-out ends found once, for every channel.
    """
    model = OutputErrorModel(records, torque_constant, tuple(terms), quasi_static)
    stops = heldout_stops(records) if stops is None else stops
    with np.errstate(all='ignore'):
        simulated = [model.simulate(parameters, index, np.array(initial_states[index], float))
                     for index in range(len(records))]
    worst = 0.0
    for channel in model.outputs:
        squares, spread, count = 0.0, 0.0, 0
        for rec, out, stop in zip(records, simulated, stops):
            measured = np.asarray(getattr(rec, channel), dtype=float)
            residual = np.asarray(out[channel], dtype=float)[stop:] - measured[stop:]
            squares += float(residual @ residual)
            count += residual.shape[0]
            spread += float(np.var(measured)) * residual.shape[0]
        if count == 0 or spread <= 0:
            continue
        value = 100.0 * np.sqrt(squares / spread)
        worst = max(worst, float(value) if np.isfinite(value) else float('inf'))
    return worst


@dataclass(frozen=True)
class FitEffects:
    """The effects of a fit, for its held-out error: their terms, the records they are on."""

    terms: tuple
    records: list


@dataclass(frozen=True)
class FloorChoice:
    """Which answer is kept, the two held-out errors, and the warning when it is the floor."""

    use_floor: bool
    fit_heldout_pct: float
    floor_heldout_pct: float
    warning: str | None


def floor_choice(floor: RegressionFloor, fit_parameters: dict[str, float],
                 fit_states: Sequence[Sequence[float]], records: Sequence[Record],
                 torque_constant: float | None, quasi_static: bool,
                 effects: FitEffects | None = None) -> FloorChoice:
    """
    Keep the output-error fit unless the regression predicts the held-out parts better.

    The fit is simulated from its own initial states with its effects (``effects``: their
    terms and the records they were built on; none: the base model), the regression (which
    has no effects) with the base model from the records' first samples.  The regression
    replaces the fit
    when its held-out error is lower by more than :data:`FLOOR_MARGIN_PCT` points and below
    :data:`FLOOR_RATIO` of the fit's (a structure both lack, e.g. held samples, moves both
    errors by some per cent; the fit's values were then the better ones).
    """
    mechanical_only = torque_constant is not None
    stops = heldout_stops(records)
    fit = heldout_error(fit_parameters, fit_states,
                        records if effects is None else effects.records, torque_constant,
                        quasi_static, () if effects is None else effects.terms,
                        stops if effects is None else None)
    values = {**{name: value for name, value in fit_parameters.items() if '.' not in name},
              **{name: floor.parameters[name] for name in fit_parameters
                 if name in floor.parameters}}
    values['b'], values['Mc'] = max(values['b'], 0.0), max(values['Mc'], 0.0)
    own = heldout_error(values, first_states(records, mechanical_only), records,
                        torque_constant, quasi_static or floor.static_electrical, stops=stops)
    if not floor.usable or not (own + FLOOR_MARGIN_PCT < fit and own < FLOOR_RATIO * fit):
        return FloorChoice(False, fit, own, None)
    return FloorChoice(True, fit, own, (
        f'the output-error fit predicts the held-out part worse ({fit:.3g} % simulation error) '
        f'than the model-free regression ({own:.3g} %): the values are the regression' "'s "
        '(equation error on zero-phase filtered signals), with its standard errors'))


def trimmed_records(records: Sequence[Record],
                    floor: RegressionFloor | None) -> tuple[list[Record], list[str]]:
    """
    Cut the left-out samples out of the records (a ramp after a step).

    Returns the records and a warning naming every left-out stretch (empty when none).  A
    stretch at a record's start is cut when at least 100 samples remain; one after a later
    step splits the record in two where both parts keep 100 samples (else it is only left out
    of the regression).
    """
    if floor is None or not floor.left_out:
        return list(records), []
    out, split = [], False
    for rec in records:
        first = [item for item in floor.left_out
                 if item.source == rec.source and item.start_sample == 0]
        cut = first[0].end_sample if first else 0
        cut = cut if cut and len(rec) - cut >= 100 else 0
        later = [item for item in floor.left_out
                 if item.source == rec.source and item.start_sample > 0]
        pieces = _split_at(rec.slice(cut, len(rec)) if cut else rec, later, cut)
        split = split or len(pieces) > 1
        out.extend(pieces)
    return out, [
        'the logged voltage did not reach the motor at once after a step (the residual of the '
        'electrical equation stays far beyond its noise: a ramp or slew of the amplifier, or its '
        f'current limit); left out of the regression: {floor.left_out_text()}; those at the '
        'start of a record are cut for every fit' + (
            ', and the records are split at the later ones' if split else '')]


def _split_at(rec: Record, stretches: Sequence[LeftOut], shift: int) -> list[Record]:
    """Return ``rec`` without the stretches after later steps (parts of 100 samples or more)."""
    pieces, begin = [], 0
    for item in sorted(stretches, key=lambda item: item.start_sample):
        start, stop = item.start_sample - shift, item.end_sample - shift
        if start - begin >= 100 and len(rec) - stop >= 100:
            pieces.append(rec.slice(begin, start))
            begin = stop
    return pieces + [rec.slice(begin, len(rec)) if begin else rec]


def _floor_values(floor: RegressionFloor, names: Sequence[str]
                  ) -> tuple[dict[str, float], dict[str, float], dict[str, str]]:
    """Return the floor's values for ``names``: b and Mc below zero set to zero, said so."""
    values = {name: float(floor.parameters.get(name, np.nan)) for name in names}
    stderr = {name: float(floor.stderr.get(name, np.nan)) for name in names}
    reasons: dict[str, str] = {}
    for name in ('b', 'Mc'):
        if name in values and not values[name] > 0.0:
            reasons[name] = (f'the regression holds {name} at zero (unconstrained it would '
                             'fall below zero): the data do not separate it (one direction or '
                             'one speed level)')
            values[name], stderr[name] = 0.0, float('nan')
    for name in ('J', 'b', 'Mc'):
        if name in values and name not in reasons and \
                not stderr[name] <= IDENTIFIABLE_REL_STDERR * abs(values[name]):
            reasons[name] = (f'the regression does not determine {name} (standard error '
                             f'{stderr[name]:.3g} of {values[name]:.3g})')
    if floor.static_electrical and 'La' in values:
        reasons['La'] = (f'the electrical equation shows no La the data resolve: La < '
                         f'{floor.la_upper_bound:.3g} H (upper bound); Ra and CPhi from the '
                         'static electrical equation u = Ra i + CPhi w')
    return values, stderr, reasons


def with_floor(result: IdentificationResult, floor: RegressionFloor | None,
               records: Sequence[Record]) -> IdentificationResult:
    """
    Keep ``result`` unless the regression predicts the held-out parts better (then its values).

    A result with effects is compared with its effects (the loop's all-data structure,
    :class:`FitEffects`): the regression has none, and replaces it (the effects dropped, said
    so) only where it predicts the held-out parts better all the same.
    """
    estimate = result.estimate
    if floor is None or estimate is None or not floor.usable:
        return result
    result = _tighter_la(result, floor)
    found = result.discovery_result
    if (result.effects and found is None) or not all(name in estimate.parameters
                                                     for name in result.parameters):
        return result  # effects not simulated here, or a result assembled from two fits
    torque_constant = result.torque_constant
    used = result.input_records or list(records)
    if len(used) != len(records) or any(a is not b for a, b in zip(used, records)):
        # The fit saw the records as its first stage left them (held samples restored): the
        # regression is compared on those.
        records, floor = used, regression_floor(used, torque_constant)
        if floor is None or not floor.usable:
            return result
    base = {name: float(estimate.parameters[name]) for name in result.parameters
            if name in estimate.parameters}
    effects = None
    if result.effects and found is not None:
        effects = FitEffects(tuple(found.terms), list(found.records))
        base.update({name: float(value) for name, value in estimate.parameters.items()
                     if '.' in name})
    choice = floor_choice(floor, base, estimate.initial_states, records, torque_constant,
                          bool(estimate.info.get('quasi_static')), effects)
    if not choice.use_floor:
        return result
    warning = choice.warning or ''
    if result.effects:
        warning += ('; the effects the loop found (' + ', '.join(
            str(effect['name']) for effect in result.effects) + ') did not make the fit '
            'predict better than the regression without them, and are not reported')
    return _as_floor(replace(result, effects=[]), floor, records, warning)


def _tighter_la(result: IdentificationResult, floor: RegressionFloor) -> IdentificationResult:
    """
    Give La the regression's upper bound when both bound it and the regression's is tighter.

    The output-error bound comes from a full fit whose La may have run off where the data hold
    no trace of it; a warning that read the time unit from that La goes with it.
    """
    old = result.upper_bounds.get('La')
    new = floor.la_upper_bound
    if old is None or new is None or not floor.static_electrical or not new < old:
        return result
    parameters = {**result.parameters, 'La': float(new)}
    parameters.update({key: value for key, value in derived_values(parameters).items()
                       if key in result.parameters})
    bounds = {**result.upper_bounds, 'La': float(new)}
    if 'Ta' in bounds:
        bounds['Ta'] = float(parameters['Ta'])
    warnings = [text for text in result.warnings
                if not text.startswith('the time looks like')]
    reasons = dict(result.not_identifiable)
    marker = '(upper bound, given as its value)'
    reason = reasons.get('La', '')
    reasons['La'] = (f'{reason.split(": La <")[0] or "La is not determined"}: La < {new:.3g} H '
                     '(upper bound from the model-free regression, whose electrical equation '
                     'shows no La the data resolve; given as its value)'
                     + (reason.split(marker, 1)[1] if marker in reason else ''))
    estimate = result.estimate
    if estimate is not None:
        estimate = replace(estimate, parameters={**estimate.parameters, **parameters})
    return replace(result, parameters=parameters, upper_bounds=bounds, warnings=warnings,
                   estimate=estimate, not_identifiable=reasons)


def _as_floor(result: IdentificationResult, floor: RegressionFloor, records: Sequence[Record],
              warning: str) -> IdentificationResult:
    """Return the result with the regression's values, standard errors and the reasons."""
    values, stderr, reasons = _floor_values(floor, list(result.parameters))
    states = first_states(records, result.torque_constant is not None)
    estimate = result.estimate
    if estimate is not None:
        kept = {name: value for name, value in estimate.parameters.items() if '.' not in name}
        estimate = replace(estimate, parameters={**kept, **values},
                           stderr={**estimate.stderr, **stderr}, initial_states=states,
                           info={**estimate.info, 'quasi_static': floor.static_electrical})
    bounds = dict(result.upper_bounds)
    if floor.static_electrical and 'La' in values:
        bounds.update(_la_bounds(values))
        stderr.update({name: float('nan') for name in _la_bounds(values)})
    return replace(result, parameters=values, stderr=stderr, stderr_model=dict(stderr),
                   initial_states=[list(state) for state in states], estimate=estimate,
                   upper_bounds=bounds, not_identifiable={**result.not_identifiable, **reasons},
                   uncertainty_method=FLOOR_UNCERTAINTY, warnings=[warning] + result.warnings)


def _la_bounds(values: dict[str, float]) -> dict[str, float]:
    """Return La's upper bound and, where the answer has it, Ta's (La/Ra of that bound)."""
    return {name: float(values[name]) for name in ('La', 'Ta') if name in values}


def floor_fallback(floor: RegressionFloor | None, records: Sequence[Record],
                   torque_constant: float | None, error: Exception, criterion: str,
                   elapsed_s: float) -> IdentificationResult | None:
    """
    Return the regression's answer when the output-error path failed (None: it has none).

    A failure of the time budget is not replaced (the user asked for less time), nor one where
    the regression's own simulation misses the data by more than :data:`FALLBACK_NRMSE_PCT`
    or leaves Ra, CPhi or J undetermined (standard error above half the value).
    """
    if floor is None or not floor.usable or 'time budget' in str(error):
        return None
    mechanical_only = torque_constant is not None
    names = MECHANICAL_NAMES if mechanical_only else PARAMETER_NAMES + DERIVED_NAMES
    values, stderr, reasons = _floor_values(floor, names)
    states = first_states(records, mechanical_only)
    estimate = Estimate('regression', dict(values), dict(stderr), states,
                        {'quasi_static': floor.static_electrical})
    with np.errstate(all='ignore'):
        errors = simulation_errors(estimate, records, torque_constant,
                                   quasi_static=floor.static_electrical)
    worst = max([value for value in errors.values() if value is not None] or [np.inf])
    # Ra and CPhi carry the answer (J too without the electrical equation); an undetermined
    # J is named (:func:`_floor_values`), not a reason to give no answer.
    needed = ('J',) if mechanical_only else ('Ra', 'CPhi')
    determined = all(stderr[name] < IDENTIFIABLE_REL_STDERR * abs(values[name])
                     for name in needed)
    if not (worst <= FALLBACK_NRMSE_PCT and determined):
        return None  # the regression does not reproduce the data either
    reason = str(error).split('. ')[0]
    warning = (f'the output-error fit failed ({reason}): the values are the model-free '
               "regression's (equation error on zero-phase filtered signals), with its "
               'standard errors; no effect discovery ran')
    return IdentificationResult(
        parameters=values, stderr=stderr, method='regression', effects=[],
        error_before=errors, error_after=dict(errors), unexplained=False,
        mode='mechanical' if mechanical_only else 'full', torque_constant=torque_constant,
        initial_states=[list(state) for state in states], noise_std={},
        sample_period_s=records[0].sample_period_s,
        n_samples=int(sum(len(rec) for rec in records)), sources=[rec.source for rec in records],
        units={name: UNITS[name] for name in names}, discover=False,
        discovery={'skipped': 'the output-error fit failed'}, stderr_model=dict(stderr),
        uncertainty_method=FLOOR_UNCERTAINTY, not_identifiable=reasons, warnings=[warning],
        upper_bounds=_la_bounds(values) if 'La' in reasons else {},
        elapsed_s=elapsed_s, operating_range=operating_range(records), estimate=estimate,
        input_records=list(records), criterion=criterion)


def identify_above_floor(criterion: str, request: Request) -> IdentificationResult:
    """
    Run the pipeline above the floor (the regression's answer), as one stage around it.

    The pipeline is :func:`~dcmotor_id.identification.pipeline.run.identify_checked`.

    The records are split into their tests
    (:func:`~dcmotor_id.identification.pipeline.segments.split_tests`); the model-free
    regression (:func:`regression_floor`) is computed first, unless the caller gave its own
    estimator; a command that did not reach the motor at a record's start is cut
    (:func:`trimmed_records`); a failed fit falls back to the regression
    (:func:`floor_fallback`), and a fit that predicts the held-out part worse gives way to it
    (:func:`with_floor`).  What was split or cut is said first among the warnings.
    """
    tests = split_tests(request.records)
    floor = (_floor_or_none(list(tests.records), request.torque_constant)
             if request.estimator is None else None)
    records, left_out = trimmed_records(list(tests.records), floor)
    left_out = ([tests.note] if tests.note else []) + left_out
    try:
        result = identify_checked(criterion, replace(request, records=records))
    except FitError as error:
        fallback = floor_fallback(floor, records, request.torque_constant, error, criterion,
                                  request.progress.elapsed())
        if fallback is None:
            raise
        result = fallback
    result = with_floor(result, floor, records)
    return replace(result, warnings=left_out + result.warnings) if left_out else result


def _floor_or_none(records: list[Record], torque_constant: float | None) -> RegressionFloor | None:
    """
    Return :func:`regression_floor`, or None when its arithmetic fails on these records.

    Data that cannot carry a regression (no motion, a constant channel) are refused by the
    pipeline's own checks, with what to do; the floor then has nothing to add.
    """
    try:
        return regression_floor(records, torque_constant)
    except (ArithmeticError, ValueError, np.linalg.LinAlgError):
        return None
