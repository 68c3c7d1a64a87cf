"""
Whether records that leave J open determine the armature's La: La's likelihood profile.

When J's profile (:mod:`~dcmotor_id.identification.checks.inertia_profile`) finds J not
determined, the speed and the current settle within about a sample and the records hold at
most one number about the lags.  The fit may put it in La instead of J: a SysId log at 20 ms
of a motor whose shaft settles in 5 ms and whose armature in 0.1 ms gave La 0.14 H, a
thousand times the truth, at a stated 4 % (and Ta at 6 %), while J was said not determined.
The standard errors of the output-error fit measure La's curvature at that optimum, not the
valley La shares with J.

La's profile asks the data the same question as J's, at the same level
(:data:`~dcmotor_id.identification.checks.inertia_profile.PROFILE_LEVEL`): the fit is repeated
with La pinned (``RefinedEstimator(pinned={'La': ...})``; J, every other parameter, term and
initial state free) at :func:`settled_armature`, the La whose time constant La/Ra is a
hundredth of a sample (the armature settles within the sample).  When the data do not reject
that La (the likelihood ratio on effective samples below the chi-square quantile with one
degree of freedom), La is not determined by them; the profile is then followed upwards from
the fitted La by factors of :data:`PROFILE_STEP` until the data reject La: the least La
rejected above every accepted one is its upper bound, which La's (and Ta's) standard error is
raised to reach.  The pinned fit at the settled La starts from the final fit and from its
corner where J carries the fitted model's slowest time constant (the lag the samples hold).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.identification.checks.inertia_profile import (
    _bound, _Ratio, _shifted, PROFILE_STEP, PROFILE_STEPS, PROFILE_THRESHOLD, ProfileSpec,
    SETTLED_SHARE, slowest_time_constant)
from dcmotor_id.identification.estimators.refined import RefinedEstimator

if TYPE_CHECKING:
    from dcmotor_id.identification.estimators.base import Estimate


@dataclass(frozen=True)
class ArmatureProfile:
    """
    La's likelihood profile: at the settled La and upwards from the fitted La.

    ``settled``: the settled La [H]; ``statistic``: the likelihood ratio there (against the
    best of the fits); ``points``: ``(La, ratio)`` of every point computed, the fitted La's
    first; ``bound``: the least La above every accepted point that the data reject (None: not
    reached or not followed).
    """

    settled: float
    statistic: float
    points: tuple[tuple[float, float], ...]
    bound: float | None

    @property
    def unresolved(self) -> bool:
        """Whether the data do not reject the settled La (La is not determined)."""
        return self.statistic < PROFILE_THRESHOLD

    def as_dict(self) -> dict[str, Any]:
        """Return the figures (JSON-ready): the test, its points and the bound."""
        return {'settled_La': self.settled, 'ratio': self.statistic,
                'threshold': PROFILE_THRESHOLD, 'unresolved': self.unresolved,
                'bound': self.bound, 'points': [list(point) for point in self.points]}


def settled_armature(parameters: Mapping[str, float], dt: float) -> float:
    """Return the La whose time constant La/Ra is a hundredth of ``dt``."""
    return SETTLED_SHARE * dt * float(parameters['Ra'])


def la_pinned_fit(spec: ProfileSpec, start: Mapping[str, float], armature: float,
                  initial_states: Sequence[Sequence[float]] | None = None
                  ) -> Estimate | None:
    """Return the full armature's fit with La pinned at ``armature`` (None: it failed)."""
    names = ('Ra', 'CPhi', 'J', 'b', 'Mc')
    try:
        return RefinedEstimator(initial={name: float(start[name]) for name in names},
                                quasi_static=False, initial_state=spec.initial_state,
                                progress=spec.progress, initial_states=initial_states,
                                criterion=spec.criterion, position_error=spec.position_error,
                                pinned={'La': armature}).fit(spec.records, None, spec.terms)
    except (FitError, np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError):
        return None


def _lag_to_j(values: Mapping[str, float]) -> dict[str, float]:
    """Return ``values`` with J carrying the fitted model's slowest time constant."""
    lag = slowest_time_constant(values, False)
    damping = float(values['b']) + float(values['CPhi']) ** 2 / float(values['Ra'])
    if not (math.isfinite(lag) and damping > 0.0):
        return dict(values)
    return {**values, 'J': lag * damping}


def armature_profile(spec: ProfileSpec, best: Estimate) -> ArmatureProfile | None:
    """
    Return La's profile at the settled La and upwards from the fitted La to its bound.

    None: the quasi-static armature (no La), the final fit does not simulate, the fitted La is
    at or below the settled one, or the fits at the settled La fail.  ``best``: the final fit
    of ``spec``'s structure.
    """
    if spec.quasi_static or 'La' not in best.parameters:
        return None
    try:
        ratio = _Ratio(spec, best)
    except FloatingPointError:
        return None
    fitted = float(best.parameters['La'])
    settled = settled_armature(best.parameters, spec.sample_period)
    if not fitted > settled:
        return None
    starts = (dict(best.parameters), _lag_to_j(best.parameters))
    fits = [la_pinned_fit(spec, start, settled, best.initial_states) for start in starts]
    statistic = min(ratio(fit) for fit in fits)
    if not math.isfinite(statistic):
        return None
    points = [(fitted, 0.0), (settled, statistic)]
    if statistic < PROFILE_THRESHOLD:
        points += _upwards(spec, best, ratio)
    shifted = _shifted(points)
    bound = _bound(points) if statistic < PROFILE_THRESHOLD else None
    return ArmatureProfile(settled, shifted[1][1], tuple(shifted), bound)


def _upwards(spec: ProfileSpec, best: Estimate, ratio: _Ratio) -> list[tuple[float, float]]:
    """Follow the profile up from the fitted La by :data:`PROFILE_STEP` until La is rejected."""
    points: list[tuple[float, float]] = []
    armature = float(best.parameters['La'])
    start, states = dict(best.parameters), best.initial_states
    floor = 0.0
    for _ in range(PROFILE_STEPS):
        armature *= PROFILE_STEP
        fit = la_pinned_fit(spec, start, armature, states)
        value = ratio(fit)
        points.append((armature, value))
        if fit is not None and math.isfinite(value):
            floor = min(floor, value)
            start, states = dict(fit.parameters), fit.initial_states
        if value - floor >= PROFILE_THRESHOLD:
            break
    return points


def armature_reason(profile: ArmatureProfile, parameters: Mapping[str, float],
                    stderr: dict[str, float]) -> str:
    """
    Say that La is not determined, with the profile's figures; raise La's and Ta's errors.

    La's standard error in ``stderr`` reaches the profile's bound (NaN without one), Ta's is
    La's over Ra.
    """
    la, ra = float(parameters['La']), float(parameters['Ra'])
    if profile.bound is not None:
        stderr['La'] = max(float(stderr.get('La', 0.0)), profile.bound - la)
        bound = (f'La is below {profile.bound:.3g} H (upper bound: the least La above the '
                 'accepted ones that the data reject at the 1 % level)')
        error = (f'La = {la:.3g} +/- {stderr["La"]:.2g} H, Ta = La/Ra likewise, the standard '
                 'errors reaching the bound')
    else:
        stderr['La'] = float('nan')
        top = max(value for value, _ in profile.points)
        bound = f'the data reject no La up to {top:.3g} H either: no upper bound'
        error = f'La = {la:.3g} H, no standard error'
    if 'Ta' in stderr:
        stderr['Ta'] = stderr['La'] / ra
    return (f'La is not determined by these records: the armature and the shaft both settle '
            "within about a sample, and the one lag the samples hold can be La's or J's: an "
            f'La so small that the armature settles within a hundredth of a sample '
            f'({profile.settled:.3g} H) fits as well (likelihood ratio '
            f'{profile.statistic:.2g}, below {PROFILE_THRESHOLD:.3g}, the 1 % level of the '
            f'profile of La); {bound} ({error}). Sample faster to determine La and J')
