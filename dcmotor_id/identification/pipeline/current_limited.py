"""
A drive whose amplifier limits the current (the model has no limit): identified in two parts.

The model has no current limit, so the samples at the limit cannot be fitted.  Off the limit
the current follows the quasi-static armature equation: :func:`electrical_part` takes Ra and
CPhi from it by least squares (:func:`electrical_regression`) on the samples off the limit's
band and not next to it (:func:`off_the_limit`), corrected for the noise of the current
(:func:`noise_corrected_lstsq`); the mechanical part is then identified as in the
mechanical-only mode, with the measured current and that CPhi as the torque constant
(:func:`~dcmotor_id.identification.identify.identify` does that), and
:func:`with_electrical_part` completes its result: J, b and Mc carry CPhi's relative
uncertainty too, La is given as the upper bound ``Ra dt``, and Ra's standard error covers
what that unresolved La does to the quasi-static Ra (:func:`la_shift`).
``bench/bench_current_limit.py`` measures Ra through limits of 1-2.5 A (its table "Ra
through the limit").
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import (DERIVED_NAMES, derived_values, MECHANICAL_NAMES,
                                   PARAMETER_NAMES, UNITS)
from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.checks.identifiability import current_limit_warning
from dcmotor_id.identification.estimators.uncertainty import block_scores, robust_covariance
from dcmotor_id.signals.filters import noise_std

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.result import IdentificationResult

#: Groups of the jackknife of the electrical regression off a current limit.
JACKKNIFE_GROUPS = 8
#: Noise levels below the limit's level within which a sample is the limit's
#: (:func:`off_the_limit`): the detector's threshold counts from the peak, noise included.
LIMIT_BAND = 5.0
#: Fewest samples off the limit the electrical regression is fitted on.
MINIMUM_SAMPLES = 10


def electrical_part(records: Sequence[Record],
                    limited: Sequence[np.ndarray]) -> tuple[dict[str, float], dict[str, Any]]:
    """
    Return Ra and CPhi off the current limit and their covariance; refuse non-physical values.

    ``limited`` marks every record's samples at the limit
    (:func:`~dcmotor_id.identification.checks.identifiability.limited_samples`); the values and the
    covariance dict are those of :func:`electrical_regression`.

    Raises
    ------
    FitError
        Ra or CPhi not positive (signs or units of the columns).

    """
    values, robust = electrical_regression(records, limited)
    if not (values['Ra'] > 0 and values['CPhi'] > 0):
        raise FitError('the current sits at an amplifier limit and the samples off the limit '
                       f'give non-physical values (Ra = {values["Ra"]:.4g} Ohm, CPhi = '
                       f'{values["CPhi"]:.4g} V s/rad): check the signs and units of the '
                       'columns')
    return values, robust


def electrical_regression(
        records: Sequence[Record],
        limited: Sequence[np.ndarray]) -> tuple[dict[str, float], dict[str, Any]]:
    """
    Ra and CPhi from ``u[k-1] = Ra i[k] + CPhi w[k]`` on the samples off the current limit.

    The quasi-static armature (the time constant below the sample period, where a current
    limit is seen): the current sampled at ``t_k`` has settled under the voltage held over
    the previous sample.  The samples in the limit's band (:func:`off_the_limit`) are left
    out, and the least squares are corrected for the noise of the current and the speed
    (:func:`noise_corrected_lstsq`: the current is a noisy regressor, and off the limit it
    spreads little).  Returns the values and the
    :func:`~dcmotor_id.identification.estimators.uncertainty.robust_covariance` dict.
    """
    rows, targets, lengths, noise = [], [], [], []
    for rec, mask in zip(records, limited):
        assert rec.current is not None and rec.speed is not None  # a full-mode record
        keep = off_the_limit(np.asarray(rec.current, dtype=float), mask, rec.noise_std('current'))
        if not keep.any():
            continue
        rows.append(np.column_stack([rec.current, rec.speed])[keep])
        targets.append(np.asarray(rec.voltage, dtype=float)[np.flatnonzero(keep) - 1])
        lengths.append(int(keep.sum()))
        noise.append([rec.noise_std('current') ** 2, rec.noise_std('speed') ** 2])
    if sum(lengths) < MINIMUM_SAMPLES:
        raise FitError(f'the current sits at an amplifier limit and only {sum(lengths)} samples '
                       'are off it: too few for the electrical part (record the drive below '
                       'its current limit too)')
    x, y = np.vstack(rows), np.concatenate(targets)
    variance = np.average(noise, axis=0, weights=np.maximum(lengths, 1))
    beta = noise_corrected_lstsq(x, y, variance)
    residual = y - x @ beta
    info = {'normal_matrix': x.T @ x, 'chain': np.ones(2), 'names': ['Ra', 'CPhi'],
            'residual_rms_weighted': float(np.sqrt(residual @ residual
                                                   / max(y.shape[0] - 2, 1))),
            **block_scores(residual, x, lengths, 1)}
    robust = robust_covariance(info)
    assert robust is not None  # the info above has every key
    # The information sits in the few transients off the limit, which batch means spread
    # over too few blocks: a delete-a-group jackknife over contiguous groups is the floor.
    groups = np.array_split(np.arange(y.shape[0]), JACKKNIFE_GROUPS)
    leave_out = []
    for group in groups:
        keep = np.ones(y.shape[0], dtype=bool)
        keep[group] = False
        leave_out.append(noise_corrected_lstsq(x[keep], y[keep], variance))
    spread = np.sqrt((len(groups) - 1) / len(groups)
                     * np.sum((np.array(leave_out) - np.mean(leave_out, axis=0)) ** 2, axis=0))
    robust['stderr'] = np.maximum(robust['stderr'], spread)
    return {'Ra': float(beta[0]), 'CPhi': float(beta[1])}, robust


def off_the_limit(current: np.ndarray, mask: np.ndarray, noise: float | None = None
                  ) -> np.ndarray:
    """
    Return the samples the electrical regression may use: off the limit's band, not next to it.

    ``mask`` marks the plateaus the detector confirmed; a plateau the current's noise breaks
    below the detector's threshold goes on at the limit, so every sample within
    :data:`LIMIT_BAND` noise levels of the plateaus' level (their median ``|i|``) is the
    limit's too.  A sample next to one at the limit is left out (the limit binds within the
    sample period before or after it), and so is the first (no voltage before it).  A band
    over more than half of the record is no plateau's (the detector's own rule): the
    detector's samples are then the limit's.  ``noise``: :func:`noise_std` of ``current``
    when the caller has it (a record's :meth:`~dcmotor_id.core.records.Record.noise_std`;
    else measured here).
    """
    magnitude = np.abs(current)
    band = mask.copy()
    if mask.any():
        level = float(np.median(magnitude[mask]))
        noise = noise_std(current) if noise is None else noise
        wide = band | (magnitude >= level - LIMIT_BAND * max(noise, 1e-3 * level))
        # As the detector: a level held over most of the record is no limit's plateau.
        band = wide if wide.mean() <= 0.5 else band
    keep = ~band
    keep[1:] &= ~band[:-1]
    keep[:-1] &= ~band[1:]
    keep[0] = False
    return keep


def noise_corrected_lstsq(x: np.ndarray, y: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """
    Least squares of ``y`` on the noisy columns ``x`` corrected for their noise (variances).

    The noise of a regressor adds ``n variance`` to the diagonal of ``x^T x`` and pulls its
    coefficient towards zero (attenuation); subtracting it is the classical correction of
    errors in variables (consistent when the noise is white and known: here the noise level
    of each channel, :func:`~dcmotor_id.signals.filters.noise_std`).  Falls back to plain
    least squares when the corrected matrix is not positive definite.
    """
    normal = x.T @ x
    corrected = normal - x.shape[0] * np.diag(variance)
    scale = np.sqrt(np.maximum(np.diag(normal), 1e-300))
    if np.all(np.linalg.eigvalsh(corrected / np.outer(scale, scale)) > 1e-6):
        return np.linalg.solve(corrected, x.T @ y)
    return np.linalg.lstsq(x, y, rcond=None)[0]


def with_electrical_part(mechanical: IdentificationResult, values: dict[str, float],
                         robust: dict[str, Any], records: Sequence[Record],
                         progress: Progress) -> IdentificationResult:
    """
    Complete the mechanical-only result of a current-limited drive with its electrical part.

    ``values`` and ``robust`` are Ra and CPhi off the limit (:func:`electrical_part`);
    ``mechanical`` the result of the mechanical-only identification with that CPhi.  La is
    the upper bound ``Ra dt`` (the samples off the limit follow the quasi-static equation);
    the La that the data do not resolve lowers the regression's Ra by up to :func:`la_shift`,
    half of which joins Ra's standard error (a warning says so when it more than doubles it).
    """
    dt = records[0].sample_period_s
    shift = la_shift(values['CPhi'], mechanical.parameters['J'], dt)
    ra, cphi = values['Ra'], values['CPhi']
    parameters = {'Ra': ra, 'La': ra * dt, 'CPhi': cphi, **mechanical.parameters}
    parameters.update(derived_values(parameters))
    stderr, stderr_model = _standard_errors(mechanical, values, robust)
    regression_ra = stderr['Ra']
    stderr['Ra'] = float(np.hypot(regression_ra, 0.5 * shift))
    stderr['Ka'] = stderr['Ra'] / ra ** 2
    names = PARAMETER_NAMES + DERIVED_NAMES
    reason = ('an amplifier current limit shapes the current rise, and off the limit the '
              f'current follows the quasi-static equation: La < {ra * dt:.3g} H (Ra dt, upper '
              'bound, given as its value)')
    not_identifiable = {'La': reason, 'Ta': reason, **mechanical.not_identifiable}
    warnings = _warnings(mechanical, robust, records)
    if stderr['Ra'] > 2.0 * regression_ra:
        warnings.insert(1, la_warning(shift / ra, dt))
    initial_states, noise = _with_current(mechanical, records)
    return replace(
        mechanical, parameters={name: float(parameters[name]) for name in names},
        stderr={name: float(stderr[name]) for name in names},
        stderr_model={name: float(stderr_model[name]) for name in names},
        mode='full', torque_constant=None,
        initial_states=initial_states,
        noise_std=noise, units={name: UNITS[name] for name in names},
        uncertainty_method=mechanical.uncertainty_method + '; Ra, CPhi: least squares off the '
        'current limit, corrected for the noise of the current and the speed (max of the '
        "batch-means sandwich and an 8-group jackknife); Ra also La's part (La in [0, Ra dt] "
        'raises Ra by up to dt CPhi^2 / J: half of that added as a standard error); J, b, Mc '
        'include the relative uncertainty of CPhi',
        not_identifiable=not_identifiable, warnings=warnings,
        upper_bounds={'La': parameters['La'], 'Ta': parameters['Ta']},
        elapsed_s=progress.elapsed())


def la_shift(cphi: float, inertia: float, dt: float) -> float:
    """
    Return how far La can move Ra in the quasi-static regression [Ohm]: ``dt CPhi^2 / J``.

    Under the quasi-static equation the current lags the speed by ``La / Ra``: ``La di/dt =
    -(La CPhi / Ra) dw/dt`` with ``J dw/dt = CPhi i - b w - Mc``, so the regression's Ra is
    ``Ra - La CPhi^2 / (Ra J)`` (the rest is negligible beside it: ``La b / (Ra J)`` on CPhi).
    The data do not resolve La (below its upper bound ``Ra dt``): Ra lies between the
    regression's value and that plus ``dt CPhi^2 / J``.
    """
    return float(dt * cphi ** 2 / inertia) if inertia > 0 else 0.0


def la_warning(share: float, dt: float) -> str:
    """Say that Ra's standard error is mostly La's part (``share`` of Ra the range spans)."""
    return (f"Ra: its standard error is mostly La's part: La (not resolved at the sample "
            f'period {dt:.2g} s, at most Ra dt) lowers the Ra of the quasi-static equation off '
            f'the current limit by up to {100.0 * share:.2g} %, half of which is added as a '
            'standard error: the true Ra lies between the value and that much above it (sample '
            'faster, or step the voltage without reaching the limit, to resolve La)')


def _standard_errors(mechanical, values, robust):
    """Return ``stderr`` and ``stderr_model``: J, b and Mc carry CPhi's relative error too."""
    ra, cphi = values['Ra'], values['CPhi']
    se = dict(zip(('Ra', 'CPhi'), robust['stderr']))
    se_model = dict(zip(('Ra', 'CPhi'), robust['stderr_model']))
    rel = se['CPhi'] / cphi
    rel_model = se_model['CPhi'] / cphi

    def combined(errors, share):
        return {name: float(np.hypot(errors[name], share * abs(mechanical.parameters[name])))
                for name in MECHANICAL_NAMES}
    stderr = {'Ra': se['Ra'], 'La': np.nan, 'CPhi': se['CPhi'],
              **combined(mechanical.stderr, rel), 'Ka': se['Ra'] / ra ** 2, 'Ta': np.nan}
    stderr_model = {'Ra': se_model['Ra'], 'La': np.nan, 'CPhi': se_model['CPhi'],
                    **combined(mechanical.stderr_model, rel_model),
                    'Ka': se_model['Ra'] / ra ** 2, 'Ta': np.nan}
    return stderr, stderr_model


def _warnings(mechanical, robust, records):
    """Return the warnings: the limit, Ra-CPhi correlation, the mechanical fit's, speed only."""
    warnings = [current_limit_warning(records) or 'current limit']
    if abs(robust['correlation'][0, 1]) > 0.99:
        warnings.append(f'Ra and CPhi are correlated {robust["correlation"][0, 1]:+.3f}: the '
                        'data determine a combination of them better than each')
    warnings += mechanical.warnings
    warnings.append('the current is the input of the mechanical fit here: the simulation '
                    'errors are of the speed only')
    return warnings


def _with_current(mechanical, records):
    """Return the initial states and the noise levels with the current's (the fit's input)."""
    noise = dict(mechanical.noise_std)
    noise['current'] = float(np.sqrt(np.mean([rec.noise_std('current') ** 2
                                              for rec in records])))
    initial_states = [[float(rec.current[0]), *state]
                      for rec, state in zip(records, mechanical.initial_states)]
    return initial_states, noise
