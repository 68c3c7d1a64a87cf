"""
Whether records with the current as the input resolve the inertia J (the mechanical mode).

J is the area of the accelerating torque ``a = CPhi i - b w - Mc sgn w`` over a speed change
divided by that change.  The samples give the area only between its left and right Riemann
sums, which differ by one sample period times the transient's peak: for a transient that decays
with a time constant ``tau`` the area ``a0 tau`` is known to a half range of ``dt / (2 tau)`` of
itself.  :func:`accelerating_decay` measures that decay from the data: the ratio ``r`` of the
speed's increment one sample after each transient's largest to that largest (the increments
are the accelerating torque over J; least squares over the peaks that stand out of the
noise), ``tau = -dt / ln r``.  :func:`inertia_unresolved` says J is
not determined when the half range exceeds :data:`IDENTIFIABLE_REL_STDERR` of J, which with its
0.5 is ``tau`` below the sample period: the speed settles within about one sample, the same
limit by which La is given as an upper bound when La/Ra is below the sample period.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.checks.identifiability import IDENTIFIABLE_REL_STDERR
from dcmotor_id.signals.filters import noise_std

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: A transient's peak stands out of the accelerating torque's noise by this many standard
#: deviations (white Gaussian noise exceeds it once in about two million samples).
TRANSIENT_SIGMAS = 5.0


@dataclass(frozen=True)
class Decay:
    """
    The decay of the accelerating torque (the speed's increments) one sample after its peaks.

    ``ratio`` and its standard error ``ratio_stderr`` (the noise over the root sum of the
    squared peaks), the time constant of the ratio, the number of peaks.
    """

    ratio: float
    ratio_stderr: float
    time_constant_s: float
    peaks: int


def accelerating_decay(records: Sequence[Record]) -> Decay | None:
    """
    Return the decay of the speed's increments after its transients, or None without any.

    With the current as the input ``J (w[k+1] - w[k]) = dt a[k]``: the speed's increments are
    the accelerating torque, measured by the speed (a current's ripple can hide it).  Records
    with a measured speed only (a speed derived from a position carries the differentiated
    position's noise, not white).  The increments' noise is the speed's
    (:func:`~dcmotor_id.signals.filters.noise_std`) times sqrt(2), at least the speed's
    resolution (its smallest nonzero increment); a peak is a local maximum of the increments'
    magnitude above :data:`TRANSIENT_SIGMAS` of that noise where the speed changes its level
    too (:func:`_new_level`: an encoder's speed jittering up and back is no transient).
    """
    num = den = noise_sum = 0.0
    peaks = 0
    for record in records:
        if record.speed is None or record.speed_derived or len(record) < 5:
            continue
        speed = np.asarray(record.speed, dtype=float)
        step = np.diff(speed)
        size = np.abs(step)
        moved = size[size > 1e-9 * float(size.max())]
        noise = max(math.sqrt(2.0) * noise_std(speed), float(moved.min()) if moved.size else 0.0)
        inner = size[1:-1]
        peak = np.flatnonzero((inner > TRANSIENT_SIGMAS * noise) & (inner >= size[:-2])
                              & (inner > size[2:])) + 1
        peak = peak[[_new_level(speed, int(k), TRANSIENT_SIGMAS * noise) for k in peak]] \
            if peak.size else peak
        num += float(np.sum(step[peak + 1] * step[peak]))
        den += float(np.sum(step[peak] ** 2))
        noise_sum += float(np.sum(noise ** 2 * step[peak] ** 2))
        peaks += int(peak.size)
    if peaks == 0 or den <= 0.0:
        return None
    ratio = num / den
    dt = records[0].sample_period_s
    return Decay(ratio, math.sqrt(noise_sum) / den, _time_constant(ratio, dt), peaks)


def _new_level(speed: np.ndarray, k: int, threshold: float) -> bool:
    """
    Whether the speed holds a new level after increment ``k``: medians of three samples.

    The median of the three samples after the increment against that of the three up to it
    (a median of three passes over a one- or two-sample spike).
    """
    after = speed[k + 1:k + 4]
    before = speed[max(k - 2, 0):k + 1]
    return bool(abs(float(np.median(after)) - float(np.median(before))) > threshold)


def _time_constant(ratio: float, dt: float) -> float:
    """Return the time constant of a decay by ``ratio`` per sample (0 at once, inf for none)."""
    return -dt / math.log(ratio) if 0.0 < ratio < 1.0 else (0.0 if ratio <= 0.0 else math.inf)


def inertia_unresolved(decay: Decay | None, dt: float) -> float | None:
    """
    Return J's relative half range from the samples when it exceeds the limit, else None.

    The half range is ``dt / (2 tau)`` for the slowest decay the peaks allow (the ratio two
    of its standard errors up: a few noise peaks do not decide it); infinite when even that
    decay is within one sample (``tau`` 0).
    """
    if decay is None:
        return None
    slowest = _time_constant(decay.ratio + 2.0 * decay.ratio_stderr, dt)
    half = math.inf if slowest <= 0.0 else dt / (2.0 * slowest)
    return half if half > IDENTIFIABLE_REL_STDERR else None


def inertia_reason(decay: Decay, dt: float, j: float, stderr: float) -> str:
    """Say why J is not determined, with the standard error that says it."""
    settles = (f"the speed's increment falls to {decay.ratio:.2g} of its largest one sample "
               f'later (a time constant of {decay.time_constant_s:.2g} s'
               if decay.time_constant_s > 0.0 else
               "the speed's increment is gone one sample after its largest (a time constant of "
               '0 s')
    return (f'J is not determined by these records: the speed settles within about one sample '
            f'period ({settles} against the sample period {dt:.2g} s, over {decay.peaks} '
            "transients), so the mechanical time constant is not resolved and the current's "
            "samples do not give the torque's area over a speed change, which J is "
            f"(J = {j:.3g} +/- {stderr:.2g} kg m^2, the standard error being that area's "
            'half range for the slowest decay the samples allow). Sample faster than the speed '
            'settles to determine J; b and Mc come from the steady speeds')
