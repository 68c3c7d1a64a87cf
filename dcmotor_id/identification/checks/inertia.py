"""
Whether records with the current as the input resolve the inertia J (the mechanical mode).

J is the area of the accelerating torque ``a = CPhi i - b w - Mc sgn w`` over a speed change
divided by that change: ``J (w[k+1] - w[k]) = integral of a over the sample``.  Point samples
of the current give that integral only between its left Riemann sum (the current at the
sample's start, ``i[k]``) and its right one (``i[k+1]``).  :func:`inertia_half_range` fits the
speed's increments by least squares twice, once with each (the fitted ``b`` subtracted, the
friction level of each direction free), and gets ``1/J_L`` and ``1/J_R``; their relative half
range ``h = |J_L - J_R| / |J_L + J_R|`` is how much the data's J depends on what the current
did between its samples.  A transient resolved over many samples gives ``h`` about
``dt / (2 tau)`` (below 3 % on the simulated records of the corpus); a current transient within
one sample, the speed settling in it, gives ``h`` near 1 (the robot wheel log at 30 ms under
its speed loop: 0.8-1.2).

The decision is a one-sided test: J is not determined when ``h`` exceeds
:data:`IDENTIFIABLE_REL_STDERR` (0.5: the limit by which La becomes an upper bound when La/Ra
is below the sample period) by more than :data:`INERTIA_Z` of its standard error, so that a
record on the limit is flagged with a probability of about 1 % and one whose J is resolved
less often; ``bench/bench_inertia.py`` measures the rate on the corpus, the lab classes, a
sweep of the mechanical time constant and the real records.  The standard error of ``h``
comes from the joint covariance of the two fits (Newey-West: the increments of a noisy speed
are correlated from one sample to the next).

Not caught: a current that steps between samples by itself (not driven by the speed) while the
speed follows within the sample; the samples then see a one-sample decay at both ends and the
fitted J is about ``b dt``, an upper bound that this test does not name.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.checks.identifiability import IDENTIFIABLE_REL_STDERR

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: One-sided normal quantile of the test (level 1 %): ``h`` beyond the limit by this many of
#: its standard errors.
INERTIA_Z = 2.326
#: Fewest increments the two fits need.
INERTIA_MIN_ROWS = 20


@dataclass(frozen=True)
class HalfRange:
    """
    J from the current at the start and at the end of each sample, and their half range.

    ``inertia_left`` / ``inertia_right``: J of the two fits per unit torque constant
    (``J / CPhi``; the ratio needs no torque constant); ``ratio`` is ``h`` and
    ``ratio_stderr`` its standard error; ``z`` the test statistic ``(h - 0.5) / stderr``;
    ``rows`` the increments fitted.
    """

    inertia_left: float
    inertia_right: float
    ratio: float
    ratio_stderr: float
    z: float
    rows: int

    @property
    def upper(self) -> float:
        """Return the largest half range the data allow (one-sided, at the test's level)."""
        return self.ratio + INERTIA_Z * self.ratio_stderr


def _rows(records: Sequence[Record], viscous_per_constant: float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """
    Return the increments [rad/s^2] and the regressors with the current at each end.

    Columns: the current less the viscous part ``b w[k] / CPhi`` (the speed at the sample's
    start for both: its noise is the increment's own), the indicator of each direction of
    motion (the friction levels).  Records with a measured speed only (a speed derived from a
    position smears the increments over several samples).
    """
    parts = []
    for record in records:
        if record.speed is None or record.current is None or record.speed_derived \
                or len(record) < 3:
            continue
        speed = np.asarray(record.speed, dtype=float)
        current = np.asarray(record.current, dtype=float)
        start = speed[:-1]
        common = np.column_stack([start > 0.0, start < 0.0]).astype(float)
        viscous = viscous_per_constant * start
        parts.append((np.diff(speed) / record.sample_period_s, current[:-1] - viscous,
                      current[1:] - viscous, common))
    if not parts:
        return None
    rise = np.concatenate([part[0] for part in parts])
    common = np.vstack([part[3] for part in parts])
    keep = np.any(common != 0.0, axis=0)
    left = np.column_stack([np.concatenate([part[1] for part in parts]), common[:, keep]])
    right = np.column_stack([np.concatenate([part[2] for part in parts]), common[:, keep]])
    if not (np.all(np.isfinite(rise)) and np.all(np.isfinite(left))
            and np.all(np.isfinite(right))):
        return None
    return rise, left, right


def _long_run(scores: np.ndarray) -> np.ndarray:
    """Return the Newey-West long-run covariance of the rows of ``scores`` (Bartlett kernel)."""
    n = scores.shape[0]
    lags = int(math.ceil(4.0 * (n / 100.0) ** (2.0 / 9.0)))
    centred = scores - scores.mean(axis=0)
    covariance = centred.T @ centred
    for lag in range(1, min(lags, n - 1) + 1):
        product = centred[lag:].T @ centred[:-lag]
        covariance += (1.0 - lag / (lags + 1.0)) * (product + product.T)
    return covariance


def inertia_half_range(records: Sequence[Record], viscous_per_constant: float
                       ) -> HalfRange | None:
    """
    Return J's half range between the current at each end of the samples, or None.

    ``viscous_per_constant``: the fitted ``b / CPhi`` [A s/rad] (the viscous torque's part of
    the current).

    None: no record with a measured speed and current, too few increments, or a fit without
    a current coefficient (a current that never changes).
    """
    rows = _rows(records, viscous_per_constant)
    if rows is None or rows[0].shape[0] < INERTIA_MIN_ROWS:
        return None
    rise, left, right = rows
    fits = []
    for matrix in (left, right):
        if np.linalg.matrix_rank(matrix) < matrix.shape[1]:
            return None
        gram_inverse = np.linalg.inv(matrix.T @ matrix)
        solution = gram_inverse @ (matrix.T @ rise)
        fits.append((solution, matrix * (rise - matrix @ solution)[:, None], gram_inverse))
    width = left.shape[1]
    bread = np.zeros((2 * width, 2 * width))
    bread[:width, :width], bread[width:, width:] = fits[0][2], fits[1][2]
    covariance = bread @ _long_run(np.hstack([fits[0][1], fits[1][1]])) @ bread.T
    a, b = float(fits[0][0][0]), float(fits[1][0][0])  # 1/J_L and 1/J_R per unit CPhi
    if a == 0.0 or b == 0.0 or a + b == 0.0:
        return None
    difference, total = b - a, a + b
    ratio = abs(difference) / abs(total)
    gradient = np.array([-math.copysign(1.0, difference) * abs(total)
                         - abs(difference) * math.copysign(1.0, total),
                         math.copysign(1.0, difference) * abs(total)
                         - abs(difference) * math.copysign(1.0, total)]) / total ** 2
    pair = covariance[np.ix_([0, width], [0, width])]
    stderr = math.sqrt(max(float(gradient @ pair @ gradient), 0.0))
    z = (ratio - IDENTIFIABLE_REL_STDERR) / stderr if stderr > 0.0 else (
        math.inf if ratio > IDENTIFIABLE_REL_STDERR else -math.inf)
    return HalfRange(1.0 / a, 1.0 / b, ratio, stderr, z, int(rise.shape[0]))


def inertia_unresolved(half: HalfRange | None) -> bool:
    """Whether the test says J is not determined (``h`` beyond 0.5 at the 1 % level)."""
    return half is not None and half.z > INERTIA_Z


def inertia_reason(half: HalfRange, dt: float, torque_constant: float, j: float,
                   stderr: float) -> str:
    """Say why J is not determined, with the standard error that says it."""
    return (f'J is not determined by these records: the speed settles within about one sample '
            f'period ({dt:.2g} s), so the mechanical time constant is not resolved and the '
            "current's samples do not give the accelerating torque's area over a speed change, "
            'which J is: with the current at the start of each sample J would be '
            f'{torque_constant * half.inertia_left:.3g} kg m^2, at its end '
            f'{torque_constant * half.inertia_right:.3g}, a half '
            f'range of {100.0 * half.ratio:.0f} % (+/- {100.0 * half.ratio_stderr:.0f} %, above '
            f'{100.0 * IDENTIFIABLE_REL_STDERR:.0f} % at the 1 % level) '
            f'(J = {j:.3g} +/- {stderr:.2g} kg m^2, the standard error being that half range '
            'at its upper bound). Sample faster than the speed settles to determine J; b and Mc '
            'come from the steady speeds')


@dataclass(frozen=True)
class OneLevelRange:
    """
    J over the friction split a one-level step leaves open: ``low`` (b = 0), ``high`` (Mc = 0).

    ``level``: the voltage [V] while the motor moves; ``speed``: the final speed [rad/s].
    """

    level: float
    speed: float
    low: float
    high: float


def one_level_range(records: Sequence[Record], parameters: dict[str, float]
                    ) -> OneLevelRange | None:
    """
    J's range when the voltage holds one level in one direction while the motor moves.

    The spin-up is then one first-order lag: with ``A = CPhi^2/Ra`` it gives its time constant
    ``J / (A + b)`` and its final speed ``w = (CPhi u/Ra - Mc) / (A + b)``, two numbers for J,
    b and Mc.  Every ``b`` from 0 to ``b + Mc/w`` (where Mc reaches 0) fits as well, with
    ``J = (A + b) tau``: J lies between ``J A/(A + b)`` and ``J (A + b + Mc/w)/(A + b)`` of the
    fitted values.  None when the voltage takes more than one level or both directions occur
    (:func:`~dcmotor_id.identification.estimators.voltage_speed.one_level_step`).
    """
    from dcmotor_id.identification.estimators.voltage_speed import moving_voltage, one_level_step
    if not one_level_step(records):
        return None
    ra, cphi = parameters['Ra'], parameters['CPhi']
    j, b, mc = parameters['J'], max(parameters['b'], 0.0), max(parameters['Mc'], 0.0)
    level = float(np.median(moving_voltage(records)[0]))
    damping = cphi * cphi / ra + b
    speed = (cphi * abs(level) / ra - mc) / damping
    if not (ra > 0.0 and damping > 0.0 and speed > 0.0 and j > 0.0):
        return None
    return OneLevelRange(level, speed, j * (damping - b) / damping,
                         j * (damping + mc / speed) / damping)


def one_level_reason(span: OneLevelRange, j: float, stderr: float) -> str:
    """Say that one voltage level does not separate J from the friction's split, with J's range."""
    return (f'one voltage level ({span.level:.4g} V) in one direction: the spin-up gives its '
            'time constant J/(CPhi^2/Ra + b) and the friction at its final speed '
            f'({span.speed:.3g} rad/s) Mc + b w, not J, b and Mc each: J lies between '
            f'{span.low:.3g} kg m^2 (no viscous friction) and {span.high:.3g} (no Coulomb '
            f'friction) (J = {j:.3g} +/- {stderr:.2g}, the standard error reaching the farther '
            'end). Record steps of two or more voltage levels, or both directions, to separate '
            'them')
