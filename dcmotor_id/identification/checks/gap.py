"""
The gap between the answer and the model-free floor: a parameter the record does not decide.

The output-error fit and the model-free regression (the floor: the regression of both
equations, :mod:`~dcmotor_id.identification.pipeline.floor`, or the voltage-speed regression,
:func:`~dcmotor_id.identification.estimators.voltage_speed.regression_fit`) are both
simulated on the held-out end of every record.  Where they predict it equally well and yet
give a parameter far apart, the record holds no evidence for either value: the stated
standard error of the fit (its curvature at the optimum) then claims a precision the data do
not give.  :func:`undecided` tests both and returns the warning and the widened standard
errors.  The voltage-speed mode calls it; the full mode does not (on random motors of the
issue's recording classes it named a parameter on 3 of 32 answers within their goals: a rate
far above its size, so it is not trusted there yet).

Two tests, each at a stated size:

* equal prediction (Diebold-Mariano): the held-out loss difference ``d = e_fit^2 - e_floor^2``
  of each output channel, its mean against its standard error on the samples it is worth
  (:func:`~dcmotor_id.identification.checks.start.correlation_time`); equal when ``|z|``
  stays within the two-sided bound of :data:`HELDOUT_SIZE` (Bonferroni over the channels);
* a gap the floor's own bias does not explain: the floor on the records against the floor on
  the fit's own simulation of the records with white noise at the sensor's level
  (:func:`replayed_channel`),
  ``|b - b_sim| / sqrt(sa^2 + 2 sb^2)`` with the stated standard errors of the fit and the
  floor (the floor's twice: two noisy regressions), beyond the two-sided bound of
  :data:`GAP_SIZE` (Bonferroni over the parameters compared).  Where the fitted model is
  the record's, the regression on its simulation carries the regression's own bias (the
  smoothing of a fast transient, the attenuation by the noise) and lands where it lands on
  the record: only a record that holds something the model does not (two time scales, a
  structure neither has) moves it.

A parameter with both is named; its standard error becomes ``sqrt(sa^2 + (a - b)^2)``, which
covers the regression's value.  ``bench/bench_gap.py`` measures how often the warning comes
on answers within their goals and on the recordings of its class.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Mapping, Sequence

import numpy as np

from dcmotor_id.identification.checks.start import correlation_time

#: Two-sided size of the test that the fit and the floor predict the held-out part equally
#: well (over the output channels together).
HELDOUT_SIZE = 0.01
#: Two-sided size of the test of a gap between the fit's and the floor's value (over the
#: parameters compared together).
GAP_SIZE = 0.01
#: Fewest held-out samples the test of equal prediction needs.
MIN_HELDOUT = 20
#: The words that begin the warning (benches find it by them).
UNDECIDED = 'the record does not decide'


@dataclass(frozen=True)
class Undecided:
    """What :func:`undecided` found: the warning (or None), the standard errors, the tests."""

    warning: str | None
    stderr: dict[str, float]
    heldout_z: dict[str, float] = field(default_factory=dict)
    gap_z: dict[str, float] = field(default_factory=dict)

    @property
    def warnings(self) -> list[str]:
        """Return the warning as a list (empty when none)."""
        return [self.warning] if self.warning else []


def heldout_z(fit_residual: np.ndarray, floor_residual: np.ndarray) -> float:
    """
    Return the Diebold-Mariano z of two held-out residuals (negative: the fit predicts better).

    NaN when fewer than :data:`MIN_HELDOUT` samples are finite in both.
    """
    fit = np.asarray(fit_residual, dtype=float)
    own = np.asarray(floor_residual, dtype=float)
    keep = np.isfinite(fit) & np.isfinite(own)
    loss = fit[keep] ** 2 - own[keep] ** 2
    if loss.shape[0] < MIN_HELDOUT:
        return float('nan')
    spread = float(np.std(loss, ddof=1)) * np.sqrt(correlation_time(loss) / loss.shape[0])
    mean = float(np.mean(loss))
    if not spread > 0:
        return 0.0 if mean == 0 else float(np.sign(mean) * np.inf)
    return mean / spread


def undecided(fit: tuple[Mapping[str, float], Mapping[str, float]],
              floor: tuple[Mapping[str, float], Mapping[str, float]],
              replayed: Mapping[str, float],
              residuals: Mapping[str, tuple[np.ndarray, np.ndarray]],
              names: Sequence[str]) -> Undecided:
    """
    Test the fit against the floor on the held-out part and on ``names``.

    ``fit`` and ``floor``: (values, standard errors), the floor's on the records;
    ``replayed``: the floor's values on the fit's own simulation of the records (what the
    regression makes of data the fitted model would give: its bias under that model);
    ``residuals``: per output channel, the held-out residual of the fit and of the floor.  A
    parameter is compared where the fit and the floor state a finite standard error, and
    named where the floor on the records is farther from the floor on the fit's simulation
    than chance allows (the record holds what the fitted model does not) while both predict
    the held-out part equally well.  Returns the fit's standard errors, widened where named.
    """
    values, stderr = fit
    floor_values, floor_stderr = floor
    out = {name: float(value) for name, value in stderr.items()}
    tests = {channel: heldout_z(*pair) for channel, pair in residuals.items()}
    # the standard library's normal quantile: identify's path does not import scipy
    bound = NormalDist().inv_cdf(1.0 - HELDOUT_SIZE / (2.0 * max(len(tests), 1)))
    if not tests or not all(abs(z) <= bound for z in tests.values()):
        return Undecided(None, out, tests)  # not equal, or nothing held out: the data decide
    compared = [name for name in names if _finite(stderr.get(name), values.get(name))
                and _finite(floor_stderr.get(name), floor_values.get(name))
                and np.isfinite(replayed.get(name, np.nan))]
    gap_bound = NormalDist().inv_cdf(1.0 - GAP_SIZE / (2.0 * max(len(compared), 1)))
    gaps = {name: abs(floor_values[name] - replayed[name]) / float(np.sqrt(
        stderr[name] ** 2 + 2.0 * floor_stderr[name] ** 2)) for name in compared}
    far = [name for name in compared if gaps[name] > gap_bound]
    if not far:
        return Undecided(None, out, tests, gaps)
    for name in far:
        out[name] = float(np.hypot(stderr[name], values[name] - floor_values[name]))
    worst = max(tests.values(), key=abs)
    said = '; '.join(
        f'{name}: the fit gives {values[name]:.4g}, the model-free regression '
        f'{floor_values[name]:.4g}, and {replayed[name]:.4g} on the fit' "'s own simulation "
        f'of the records ({gaps[name]:.1f} combined standard errors from it)' for name in far)
    return Undecided(
        f'{UNDECIDED} between the fit and the model-free regression on {", ".join(far)} '
        f'({said}): the regression sees in the records what the fitted model does not make '
        'of them, and both predict the held-out part equally well (loss difference z '
        f'{worst:+.2f}, within +-{bound:.2f}), so the data hold no evidence for either '
        'value (a structure neither model has, such as two time scales in the speed, can '
        'do this); the standard error of ' + ', '.join(far) + ' is widened to cover the gap '
        '(sqrt(stderr^2 + gap^2)): the record gives it only to that precision', out, tests,
        gaps)


def replayed_channel(simulated: np.ndarray, noise_std: float) -> np.ndarray:
    """
    Return a channel as the fitted model would log it: its simulation plus white noise.

    The noise has the sensor's level as the record shows it (``Record.noise_std``, from its
    sample-to-sample differences), drawn from a generator seeded by the length: the same
    replay on every run.
    """
    simulated = np.asarray(simulated, dtype=float)
    draws = np.random.default_rng(simulated.shape[0]).standard_normal(simulated.shape[0])
    level = float(noise_std) if np.isfinite(noise_std) else 0.0
    return simulated + level * draws


def _finite(stderr: float | None, value: float | None) -> bool:
    """Whether a standard error and its value are finite, the error above zero."""
    return stderr is not None and value is not None and bool(
        np.isfinite(stderr) and stderr > 0 and np.isfinite(value))
