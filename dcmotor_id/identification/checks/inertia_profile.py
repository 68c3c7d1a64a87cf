"""
Whether records with the voltage as the input resolve the inertia J: J's likelihood profile.

With the voltage as the input, J is the mechanical time constant's share of the motion: the
speed's lag behind a change of the voltage.  When that lag (and the armature's) is shorter
than a sample, the speed has settled by the next sample up to a remainder that J and La share:
the data then hold the steady speeds (Ra, CPhi, b, Mc) and at most one number about the lags,
and a fit can put it in J or in La (a SysId log at 20 ms of a motor whose mechanical time
constant is 5 ms: J -94 % and La 0.16 H, a thousand times the truth, with standard errors of
a few tens of percent).

The decision is a likelihood-ratio test on J's profile (:func:`inertia_profile`): the fit is
repeated with J pinned (``RefinedEstimator(pinned=...)``, every other parameter, term and
initial state free) at :func:`settled_inertia`, the J whose mechanical time constant is a
hundredth of a sample (the speed settles within the sample: no acceleration term left).  When
the data do not reject that J at the level :data:`PROFILE_LEVEL` (the ratio below the
chi-square quantile with one degree of freedom), J is not determined by them; the profile is
then followed upwards by factors of :data:`PROFILE_STEP` past the J whose time constant is
:data:`PROFILE_GATE_SAMPLES` samples until the data reject J: the least J rejected above every
accepted one is its upper bound.  The profile is followed up from the fitted J also when the
data reject the settled J: a point that fits better than the fitted J beyond the same level
rejects the fit's J (the fit ended in another optimum, J and La both shorter than a sample:
:attr:`InertiaProfile.fitted_rejected`).  The ratio counts every record's channel by its
effective samples (its length over the best fit's residual's correlation time,
:func:`~dcmotor_id.identification.checks.start.correlation_time`): a residual correlated over
many samples is worth fewer independent ones.

The profile costs fits, so it is computed only when the fitted model's slowest time constant
is below :data:`PROFILE_GATE_SAMPLES` sample periods (:func:`slowest_time_constant`); where it
is longer the transient spans samples and J is resolved (``bench/bench_inertia_profile.py``
measures where it runs, its false alarms on the random motors and the lab classes, and its
power over the mechanical time constant).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import MotorParameters, state_matrix
from dcmotor_id.identification.checks.start import correlation_time
from dcmotor_id.identification.error_model.residuals import simulate_records
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator

if TYPE_CHECKING:
    from dcmotor_id.core.progress import Progress
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm

#: The fitted model's slowest time constant, in sample periods, below which J's profile is
#: computed (a gate for the cost: above it the transient spans samples).
PROFILE_GATE_SAMPLES = 2.0
#: The settled J's mechanical time constant, as a share of the sample period.
SETTLED_SHARE = 0.01
#: Size of the likelihood-ratio test: the settled J is rejected, and the profile's upper end
#: found, beyond the chi-square quantile (one degree of freedom) at this level.
PROFILE_LEVEL = 0.01
#: The chi-square quantile (one degree of freedom) at :data:`PROFILE_LEVEL`.
PROFILE_THRESHOLD = 6.6349
#: Factor between the points of the profile followed upwards, and the most points.
PROFILE_STEP = 2.0
PROFILE_STEPS = 16


@dataclass(frozen=True)
class ProfileSpec:
    """
    The final fit's structure on its records: what every point of the profile refits.

    ``quasi_static``: the armature's La -> 0 limit is the model; ``terms``: the effect terms of
    the final structure; ``criterion``, ``position_error`` and ``initial_state`` as the final
    fit's estimator.
    """

    records: Sequence[Record]
    terms: Sequence[ExogenousTerm]
    quasi_static: bool
    criterion: str
    position_error: str
    initial_state: str
    progress: Progress | None = None

    @property
    def sample_period(self) -> float:
        """Return the sample period [s] (the first record's)."""
        return float(self.records[0].sample_period_s)


@dataclass(frozen=True)
class InertiaProfile:
    """
    J's likelihood profile where it matters: at the settled J and upwards.

    ``settled``: the settled J [kg m^2]; ``statistic``: the likelihood ratio there (against the
    best of the fits); ``points``: ``(J, ratio)`` of every point computed, the fitted J's
    first; ``bound``: the least J above every accepted point that the data reject (None: not
    reached); ``settled_fit``: the fit at the settled J (None: the fitted J is below it).
    """

    settled: float
    statistic: float
    points: tuple[tuple[float, float], ...]
    bound: float | None
    settled_fit: Estimate | None

    @property
    def unresolved(self) -> bool:
        """Whether the data do not reject the settled J (J is not determined)."""
        return self.statistic < PROFILE_THRESHOLD

    @property
    def fitted_rejected(self) -> bool:
        """Whether a point of the profile beats the fitted J (the first point) beyond the test."""
        return self.points[0][1] >= PROFILE_THRESHOLD

    @property
    def accepted(self) -> tuple[float, float]:
        """Return the least and the largest J the data accept (the bound when there is one)."""
        inside = [inertia for inertia, value in self.points if value < PROFILE_THRESHOLD]
        return min(inside), self.bound if self.bound is not None else max(inside)

    def as_dict(self) -> dict[str, Any]:
        """Return the figures (JSON-ready): the test, its points and the bound."""
        return {'settled_J': self.settled, 'ratio': self.statistic,
                'threshold': PROFILE_THRESHOLD, 'unresolved': self.unresolved,
                'fitted_rejected': self.fitted_rejected,
                'bound': self.bound, 'points': [list(point) for point in self.points]}


def slowest_time_constant(parameters: Mapping[str, float], quasi_static: bool) -> float:
    """
    Return the fitted linear model's slowest time constant [s] (inf when it does not decay).

    The quasi-static armature: ``J / (b + CPhi^2 / Ra)``; the full one: the reciprocal of the
    smallest decay rate of the state matrix's eigenvalues (a complex pair's real part).
    """
    ra, cphi, j, b = (float(parameters[name]) for name in ('Ra', 'CPhi', 'J', 'b'))
    if quasi_static or 'La' not in parameters:
        damping = b + cphi * cphi / ra
        return j / damping if damping > 0.0 else math.inf
    matrix = state_matrix(MotorParameters(Ra=ra, La=float(parameters['La']), CPhi=cphi, J=j,
                                          b=b, Mc=float(parameters['Mc'])))
    with np.errstate(all='ignore'):
        rates = -np.real(np.linalg.eigvals(matrix))
    if not np.all(np.isfinite(rates)) or np.min(rates) <= 0.0:
        return math.inf
    return float(1.0 / np.min(rates))


def profile_needed(parameters: Mapping[str, float], quasi_static: bool, dt: float) -> bool:
    """Whether the slowest time constant is below :data:`PROFILE_GATE_SAMPLES` samples."""
    return slowest_time_constant(parameters, quasi_static) < PROFILE_GATE_SAMPLES * dt


def settled_inertia(parameters: Mapping[str, float], dt: float) -> float:
    """Return the J whose time constant ``J / (b + CPhi^2/Ra)`` is a hundredth of ``dt``."""
    damping = float(parameters['b']) + float(parameters['CPhi']) ** 2 / float(parameters['Ra'])
    return SETTLED_SHARE * dt * damping


class _Ratio:
    """
    The likelihood ratio of a fit against the final one, on effective samples.

    ``2 (log L_best - log L) = sum over records and channels of n_eff log(s^2 / s_best^2)``,
    with each channel's residual variance profiled out (the maximum-likelihood weighting of
    the refined estimator) and ``n_eff`` its length over the final fit's residual's
    correlation time.
    """

    def __init__(self, spec: ProfileSpec, best: Estimate) -> None:
        self.model = OutputErrorModel(spec.records, None, spec.terms, spec.quasi_static,
                                      spec.criterion)
        variances = self.variances(best)
        if variances is None:
            raise FloatingPointError('the final fit does not simulate')
        self.best, self.weights = variances[0], variances[1]

    def variances(self, estimate: Estimate) -> tuple[np.ndarray, np.ndarray] | None:
        """Return every record's and channel's residual variance and effective samples."""
        outputs = simulate_records(self.model, estimate.parameters, estimate.initial_states)
        variances, weights = [], []
        for out, rec in zip(outputs, self.model.records):
            for channel in self.model.outputs:
                residual = out[channel] - getattr(rec, channel)
                if not np.all(np.isfinite(residual)):
                    return None
                variances.append(max(float(np.mean(residual ** 2)), 1e-300))
                weights.append(residual.shape[0] / correlation_time(residual))
        return np.array(variances), np.array(weights)

    def __call__(self, estimate: Estimate | None) -> float:
        """Return the ratio of a fit against the final one (inf: no fit, or it diverged)."""
        variances = None if estimate is None else self.variances(estimate)
        if variances is None:
            return math.inf
        return float(np.sum(self.weights * np.log(variances[0] / self.best)))


def pinned_fit(spec: ProfileSpec, start: Mapping[str, float], inertia: float,
               initial_states: Sequence[Sequence[float]] | None = None) -> Estimate | None:
    """Return the fit with J pinned at ``inertia`` from ``start`` (None: it failed)."""
    names = [name for name in ('Ra', 'La', 'CPhi', 'b', 'Mc')
             if not (spec.quasi_static and name == 'La')]
    try:
        return RefinedEstimator(initial={name: float(start[name]) for name in names},
                                quasi_static=spec.quasi_static, initial_state=spec.initial_state,
                                progress=spec.progress, initial_states=initial_states,
                                criterion=spec.criterion, position_error=spec.position_error,
                                pinned={'J': inertia}).fit(spec.records, None, spec.terms)
    except (FitError, np.linalg.LinAlgError, ValueError, FloatingPointError, OverflowError):
        return None


def _corner(spec: ProfileSpec, values: Mapping[str, float]) -> list[dict[str, float]]:
    """
    Return the starts of a point of the profile: ``values``, and with La at its corner.

    The corner (the full armature only): La at a hundredth of the sample period's, the lag left
    to J alone (the other end of the valley J and La share).
    """
    starts = [dict(values)]
    if not spec.quasi_static:
        starts.append({**values, 'La': SETTLED_SHARE * spec.sample_period * float(values['Ra'])})
    return starts


def _point(spec: ProfileSpec, ratio: _Ratio, starts: Sequence[Mapping[str, float]],
           inertia: float, states: Sequence[Sequence[float]] | None
           ) -> tuple[float, Estimate | None]:
    """Return the ratio at a pinned J and its fit: the best of the starts."""
    fits = [pinned_fit(spec, start, inertia, states) for start in starts]
    scored = sorted((ratio(fit), index) for index, fit in enumerate(fits))
    return scored[0][0], fits[scored[0][1]]


def inertia_profile(spec: ProfileSpec, best: Estimate) -> InertiaProfile | None:
    """
    Return J's profile at the settled J and upwards from the fitted J to its bound.

    None: the final fit does not simulate, or the fit at the settled J fails from both starts.
    ``best``: the final fit of ``spec``'s structure.
    """
    try:
        ratio = _Ratio(spec, best)
    except FloatingPointError:
        return None
    fitted = float(best.parameters['J'])
    settled = settled_inertia(best.parameters, spec.sample_period)
    points = [(fitted, 0.0)]
    settled_fit = None
    if fitted > settled:
        statistic, settled_fit = _point(spec, ratio, _corner(spec, best.parameters), settled,
                                        best.initial_states)
        if not math.isfinite(statistic):
            return None
        points.append((settled, statistic))
    points += _upwards(spec, best, ratio, max(fitted, settled))
    return _profile(points, settled, _bound(points), settled_fit)


def _upwards(spec: ProfileSpec, best: Estimate, ratio: _Ratio, inertia: float
             ) -> list[tuple[float, float]]:
    """
    Follow the profile up from ``inertia`` by :data:`PROFILE_STEP`; return its points.

    Up to the J whose time constant is :data:`PROFILE_GATE_SAMPLES` sample periods at least
    (the profile may rise and fall again between the corner where La takes the lag and the one
    where J does), then on until the data reject J (at most :data:`PROFILE_STEPS` points).
    """
    top = settled_inertia(best.parameters, spec.sample_period) * (
        PROFILE_GATE_SAMPLES / SETTLED_SHARE)
    points: list[tuple[float, float]] = []
    start, states = dict(best.parameters), best.initial_states
    floor = 0.0
    for _ in range(PROFILE_STEPS):
        inertia *= PROFILE_STEP
        value, fit = _point(spec, ratio, _corner(spec, start), inertia, states)
        points.append((inertia, value))
        if fit is not None and math.isfinite(value):
            floor = min(floor, value)
            start, states = dict(fit.parameters), fit.initial_states
        if inertia >= top and value - floor >= PROFILE_THRESHOLD:
            break
    return points


def _shifted(points: Sequence[tuple[float, float]]) -> list[tuple[float, float]]:
    """Return the points' ratios against the best of them (a pinned fit may beat the final)."""
    low = min(0.0, min(value for _, value in points))
    return [(inertia, value - low) for inertia, value in points]


def _bound(points: Sequence[tuple[float, float]]) -> float | None:
    """Return the least J rejected above every accepted one (None: none rejected there)."""
    shifted = _shifted(points)
    accepted = max(inertia for inertia, value in shifted if value < PROFILE_THRESHOLD)
    rejected = [inertia for inertia, value in shifted
                if value >= PROFILE_THRESHOLD and inertia > accepted]
    return min(rejected) if rejected else None


def _profile(points: list[tuple[float, float]], settled: float, bound: float | None,
             settled_fit: Estimate | None) -> InertiaProfile:
    """Return the profile with the ratios against the best of its fits."""
    shifted = _shifted(points)
    statistic = next((value for inertia, value in shifted if inertia == settled), 0.0)
    return InertiaProfile(settled, statistic, tuple(shifted), bound, settled_fit)


def shared_la(profile: InertiaProfile, parameters: Mapping[str, float],
              stderr: dict[str, float]) -> str | None:
    """
    Say that La is not determined either when the fit with J settled moves it (else None).

    The move ``|La - La_settled|`` beyond twice La's standard error: La and J share the lag the
    records leave.  La's and Ta's standard errors in ``stderr`` are raised to that move.
    """
    fit = profile.settled_fit
    if fit is None or 'La' not in fit.parameters or 'La' not in parameters:
        return None
    la, settled = float(parameters['La']), float(fit.parameters['La'])
    move = abs(la - settled)
    own = float(stderr.get('La', math.nan))
    if not (math.isfinite(move) and move > 2.0 * own):  # a NaN own error: a bound, not this
        return None
    stderr['La'] = max(own, move)
    if 'Ta' in stderr:
        stderr['Ta'] = max(float(stderr['Ta']), move / float(parameters['Ra']))
    return (f'La is not determined by these records: the armature and the shaft both settle '
            f'within the sample period, and La shares with J the one lag the samples hold '
            f'(with J settled the fit gives La = {settled:.3g} H, with J free {la:.3g} H; its '
            'standard error is raised to that move). Sample faster to determine La and J')


def rejected_reason(profile: InertiaProfile, inertia: float, stderr: float) -> str:
    """Say that the profile of J rejects the fitted J for another, with the range it accepts."""
    low, high = profile.accepted
    best = min(profile.points, key=lambda point: point[1])[0]
    return (f'J is not determined by this fit: the profile of J (the fit repeated with J '
            f'pinned) fits better at J = {best:.3g} kg m^2 than at the fitted {inertia:.3g} '
            f'(likelihood ratio {profile.points[0][1]:.3g}, beyond {PROFILE_THRESHOLD:.3g}, '
            f'the 1 % level): the fit ended in another optimum where the lags of J and La are '
            f'shorter than a sample; the data accept J from {low:.3g} to {high:.3g} kg m^2 '
            f'(J = {inertia:.3g} +/- {stderr:.2g}, the standard error reaching that range). '
            'Sample faster than the speed settles to determine J')


def profile_reason(profile: InertiaProfile, dt: float, inertia: float, stderr: float) -> str:
    """Say why J is not determined, with the profile's figures and the standard error."""
    if profile.bound is not None:
        bound = (f'J is below {profile.bound:.3g} kg m^2 (upper bound: the least J above '
                 'the accepted ones that the data reject at the 1 % level)')
        error = f'J = {inertia:.3g} +/- {stderr:.2g} kg m^2, the standard error reaching the bound'
    else:
        top = max(value for value, _ in profile.points)
        bound = f'the data reject no J up to {top:.3g} kg m^2 either: no upper bound'
        error = f'J = {inertia:.3g} kg m^2, no standard error'
    return (f'J is not determined by these records: the speed settles within about one sample '
            f'period ({dt:.2g} s), so the lag J gives is not resolved: a J so small that the '
            f'speed settles within a hundredth of a sample ({profile.settled:.3g} kg m^2) fits '
            f'as well (likelihood ratio {profile.statistic:.2g}, below {PROFILE_THRESHOLD:.3g}, '
            f'the 1 % level of the profile of J); {bound} ({error}). Ra, CPhi, b and Mc come '
            'from the steady speeds; sample faster than the speed settles to determine J')
