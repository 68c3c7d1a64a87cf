"""
A logged voltage step that does not reach the motor at once, anywhere in a record.

An amplifier's ramp, slew limit or soft start applies less than the logged voltage for a
while after a step: the current then rises more slowly than the electrical equation says.
The equation sampled with the voltage held over each sample is exactly an ARX model of the
current, ``i[k+1] = a i[k] + beta u[k] + gamma w[k] + c`` (``a = exp(-dt Ra/La)``), which
also holds when La/Ra is below the sample period (``a`` near 0) and needs no derivative of the
current (a derivative smears an armature transient over samples and made such transients look
like ramps).  It is fitted by least squares on all samples, three times without the samples
beyond :data:`OUTLIER_SIGMAS` robust noise levels of its one-step residual ``e``.

After each logged step (:func:`~dcmotor_id.identification.pipeline.floor.step_starts` decides
what a step is) of sign ``s``, the shortfall ``-s e`` is summed over the first ``m`` samples
(``m`` up to :data:`WINDOW_SAMPLES`, at most half the dwell); its largest standardised sum
``z = sum / (sigma sqrt(m))`` is compared with the Bonferroni bound of a one-sided 1 % test over
every window and step of the record (so that a record without a ramp is flagged with a
probability of at most 1 %).  A ramp also has a size: the summed shortfall in units of the
step's first-sample current change ``beta |du|`` is the delay, in samples, by which the current
lags a step reaching the motor at once (half the ramp's length); a ramp is named when it is at
least :data:`MIN_DELAY_SAMPLES` samples over at least :data:`MIN_RUN_SAMPLES` samples, so that a
sensor held or delayed by a sample or two, or a slow model error summed over a long window, is
none.  At a step at the record's start (from rest, logged from t = 0) the one-step fit can
take a ramp as long as the spin-up for a slow armature (``a`` near 1) and measure it no lag:
there the ramp's length is profiled (:func:`ramp_profile`: the ARX refitted with the step
applied as a linear ramp over ``m`` samples, the best ``m`` of at least
:data:`MIN_PROFILE_SAMPLES` against the best below, a likelihood ratio on effective samples
beyond chi-square's bound at the same 1 % per record, :func:`profile_bound`).  Its size held
on 150 random steps from rest and the lab classes; after later steps it is not applied, where
sensors held over two samples or delayed by three pass for a ramp of four to six.  Steps
into an amplifier's current limit
(:func:`~dcmotor_id.identification.checks.identifiability.limited_samples`, or a current flat
at the record's peak over the shortfall) are the limit's, not a ramp.  ``bench/bench_ramp.py``
measures the size and the power.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from statistics import NormalDist
from typing import Callable, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.signals.filters import period_mean_speed

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: The test's level per record (one-sided, Bonferroni over its windows and steps).
RAMP_LEVEL = 0.01
#: Longest window after a step [samples].
WINDOW_SAMPLES = 50
#: Samples beyond this many robust noise levels are left out of the ARX fit.
OUTLIER_SIGMAS = 5.0
#: The smallest lag, in samples, of the current behind a step that reaches the motor at once.
MIN_DELAY_SAMPLES = 1.5
#: A current within this share of the record's peak over the whole shortfall is at a limit.
LIMIT_SPREAD = 0.05
#: The fewest samples of a shortfall (a sensor held or delayed by one or two is none).
MIN_RUN_SAMPLES = 3
#: The shortest ramp the profile names [samples]: one of up to three samples is a step's own
#: sampling (the voltage held over a sample, a speed averaged over it), a lag of at most a
#: sample, below :data:`MIN_DELAY_SAMPLES`.
MIN_PROFILE_SAMPLES = 4
#: The longest ramp the profile tries [samples] (at most half the step's dwell): a soft start
#: of a quarter second at 1 kHz.
PROFILE_SAMPLES = 250


@dataclass(frozen=True)
class Shortfall:
    """
    One step's shortfall of the current after a logged voltage step.

    Its first sample, its length, the largest z over the windows, the delay in samples (both
    at that window), and whether it is named a ramp (its length then runs on to where the
    shortfall's sum reaches 99 % of its largest).
    """

    start: int
    samples: int
    z: float
    delay_samples: float
    ramp: bool


def robust_lstsq(matrix: np.ndarray, target: np.ndarray, allowed: np.ndarray, passes: int
                 ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray] | None:
    """
    Fit by least squares on the allowed rows, refitting without the outliers; or None.

    Each pass fits the rows kept, then keeps the allowed rows within :data:`OUTLIER_SIGMAS`
    robust noise levels (the median absolute deviation of the kept residual) of the fit.
    Return the last fit's coefficients, its residual on every row, its noise level and the
    rows it keeps; None when fewer than four rows per coefficient are left.
    """
    keep = allowed
    solution, residual, sigma = np.zeros(matrix.shape[1]), target, 1e-12
    for _ in range(passes):
        if np.count_nonzero(keep) < 4 * matrix.shape[1]:
            return None
        solution = np.linalg.lstsq(matrix[keep], target[keep], rcond=None)[0]
        residual = target - matrix @ solution
        centred = residual[keep] - np.median(residual[keep])
        sigma = max(1.4826 * float(np.median(np.abs(centred))), 1e-12)
        kept = allowed & (np.abs(residual) <= OUTLIER_SIGMAS * sigma)
        if np.array_equal(kept, keep):
            break  # the same rows kept: a further pass repeats this one exactly
        keep = kept
    return solution, residual, sigma, keep


def _arx(current: np.ndarray, volts: np.ndarray, speed: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Return the ARX coefficients, the one-step residual and its robust noise level."""
    matrix = np.column_stack([current[:-1], volts[:-1], speed[:-1], np.ones(current.size - 1)])
    fit = robust_lstsq(matrix, current[1:], np.ones(current.size - 1, dtype=bool), 3)
    return None if fit is None else fit[:3]


def _sample_speed(record: Record) -> np.ndarray:
    """
    Return the speed the ARX takes over each sample period: the position's own where it has one.

    A speed derived from the position by a zero-phase filter is smeared over the filter's
    length at a spin-up from rest (the record's first samples read the motion of the next
    ones), which the one-step test took for a ramp.  The position's increment over the period
    ``(theta[k+1] - theta[k]) / dt`` is the period's mean speed, free of that smear; the last
    sample (not used by the ARX) repeats the one before.
    """
    if not record.speed_from_position:
        return np.asarray(record.speed, dtype=float)
    assert record.position is not None  # a speed from the position has one
    mean = period_mean_speed(record.position, record.sample_period_s)
    return np.append(mean, mean[-1])


def record_shortfalls(record: Record, steps: Sequence[tuple[int, float]],
                      limited: np.ndarray | None = None) -> list[Shortfall]:
    """
    Return the largest shortfall after each logged step of one record (see the module).

    ``steps``: ``(first sample, sign)`` of each logged step; ``limited``: the samples at a
    current limit (their steps are skipped).
    """
    if record.voltage is None or record.current is None or record.speed is None:
        return []
    volts = np.asarray(record.voltage, dtype=float)
    fit = _arx(np.asarray(record.current, dtype=float), volts, _sample_speed(record))
    if fit is None or not steps:
        return []
    solution, residual, sigma = fit
    starts = [first for first, _ in steps] + [volts.size]
    bound = bonferroni_bound(len(steps))
    current = np.asarray(record.current, dtype=float)
    found = []
    for (first, sign), following in zip(steps, starts[1:]):
        width = min(WINDOW_SAMPLES, max((following - first) // 2, 1), residual.size - first)
        if width < 1 or (limited is not None and limited[first:first + width].any()):
            continue
        total = np.cumsum(-sign * residual[first:first + width])
        z = total / (sigma * np.sqrt(np.arange(1, width + 1)))
        best = int(np.argmax(z))
        jump = abs(volts[first] - (volts[first - 1] if first > 0 else 0.0))
        delay = float(total[best]) / max(abs(float(solution[1])) * jump, 1e-300)
        peak = float(np.abs(current).max())
        ramp = bool(z[best] > bound and best + 1 >= MIN_RUN_SAMPLES
                    and delay >= MIN_DELAY_SAMPLES
                    and not _at_limit(np.abs(current[first + 1:first + best + 2]), peak))
        # a ramp ends where the shortfall's sum reaches 99 % of its largest (not a noisy tail)
        extent = int(np.argmax(total >= 0.99 * float(np.max(total)))) if ramp else best
        longest = min(PROFILE_SAMPLES, max((following - first) // 2, 1), residual.size - first)
        length, ratio = (ramp_profile(current, volts, _sample_speed(record), first, longest)
                         if first == 0 else (1, 0.0))
        profiled = bool(ratio > profile_bound(len(steps), longest)
                        and not _at_limit(np.abs(current[first + 1:first + length]), peak))
        # the ramp over m samples: its first m - 1 at a reduced voltage, whose currents and
        # speeds run to the m-th sample (the masks take one sample beyond the extent)
        extent = max(extent, length - 2) if profiled else extent
        found.append(Shortfall(first, max(best, extent) + 1, float(z[best]), delay,
                               ramp or profiled))
    return found


def ramp_profile(current: np.ndarray, volts: np.ndarray, speed: np.ndarray, first: int,
                 longest: int) -> tuple[int, float]:
    """
    Return the ramp length [samples] that best explains the current after a step, and its ratio.

    The ARX model of the module is fitted with the voltage after the step at ``first`` taken
    as a linear ramp over ``m`` samples (``m`` = 1: the step reaches the motor at once) for
    every ``m`` up to ``longest``; a slow armature (``a`` near 1) and a ramp both make the
    current rise slowly, but only the ramp's rise ends at once where the ramp does.  Returns the
    best ``m`` of at least :data:`MIN_PROFILE_SAMPLES` and twice its log-likelihood ratio over
    the best ``m`` below (a step's own sampling), on the residual's effective samples.  Each
    ``m`` changes only the voltage of the rows in its ramp, so the normal equations are
    updated, not rebuilt: a record of any length costs ``longest`` solves of 4 x 4.
    """
    from dcmotor_id.identification.checks.start import correlation_time

    # the back-EMF over a sample: its speed at both ends (the spin-up moves it within one);
    # under one voltage level an offset would be the voltage's coefficient (a ramp splits
    # them: a freedom that m = 1 lacks), so there is none then
    columns = [current[:-1], volts[:-1], speed[:-1], speed[1:]]
    if np.ptp(volts) > 0.0:
        columns.append(np.ones(current.size - 1))
    matrix = np.column_stack(columns)
    target = current[1:]
    gram, moment, total = matrix.T @ matrix, matrix.T @ target, float(target @ target)
    jump = volts[first] - (volts[first - 1] if first > 0 else 0.0)
    sums, solutions = [], []
    for length in range(1, longest + 1):
        rows = np.arange(first, min(first + length - 1, target.size))
        changed = matrix[rows].copy()
        changed[:, 1] -= jump * (1.0 - (rows - first + 1) / length)
        g = gram - matrix[rows].T @ matrix[rows] + changed.T @ changed
        h = moment + (changed - matrix[rows]).T @ target[rows]
        solution = np.linalg.lstsq(g, h, rcond=None)[0]
        solutions.append(solution)
        sums.append(max(total - 2.0 * solution @ h + solution @ g @ solution, 1e-300))
    if longest < MIN_PROFILE_SAMPLES:
        return 1, 0.0
    best = MIN_PROFILE_SAMPLES - 1 + int(np.argmin(sums[MIN_PROFILE_SAMPLES - 1:]))
    ramp_rows = matrix.copy()
    rows = np.arange(first, min(first + best, target.size))
    ramp_rows[rows, 1] -= jump * (1.0 - (rows - first + 1) / (best + 1))
    effective = target.size / correlation_time(target - ramp_rows @ solutions[best])
    ratio = effective * math.log(min(sums[:MIN_PROFILE_SAMPLES - 1]) / sums[best])
    return best + 1, float(ratio)


def profile_bound(steps: int, longest: int) -> float:
    """Return the ratio a ramp's profile must exceed: chi-square 1 at the record's 1 % level."""
    # chi-square with one degree of freedom as a squared normal quantile (no scipy import)
    tests = max(steps, 1) * max(longest - MIN_PROFILE_SAMPLES + 1, 1)
    return NormalDist().inv_cdf(1.0 - RAMP_LEVEL / (2.0 * tests)) ** 2


def _at_limit(run: np.ndarray, peak: float) -> bool:
    """
    Whether the current sits flat at the record's peak over a shortfall: a current limit.

    An amplifier's limit holds the current at one level (within :data:`LIMIT_SPREAD` of the
    peak) while the speed builds up; a ramp's current rises through the shortfall.
    """
    return bool(run.size and peak > 0.0 and float(run.min()) >= (1.0 - LIMIT_SPREAD) * peak)


def ramp_masks(records: Sequence[Record],
               step_starts: Callable[[np.ndarray], list[tuple[int, float]]],
               limited: Sequence[np.ndarray] | None = None) -> list[np.ndarray]:
    """Return, per record, the samples of the named ramps (from the step over the shortfall)."""
    masks = []
    for index, record in enumerate(records):
        mask = np.zeros(len(record), dtype=bool)
        if record.voltage is not None:
            steps = step_starts(np.asarray(record.voltage, dtype=float))
            for item in record_shortfalls(record, steps,
                                          None if limited is None else limited[index]):
                if item.ramp:
                    mask[item.start:item.start + item.samples + 1] = True
        masks.append(mask)
    return masks


def bonferroni_bound(steps: int) -> float:
    """Return the z bound of the test for a record with this many steps."""
    # the standard library's normal quantile: identify's path does not import scipy
    return (NormalDist().inv_cdf(1.0 - RAMP_LEVEL / (WINDOW_SAMPLES * max(steps, 1))) if steps
            else math.inf)
