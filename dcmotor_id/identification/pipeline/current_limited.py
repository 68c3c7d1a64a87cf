"""
A drive whose amplifier limits the current (the model has no limit): identified in two parts.

The model has no current limit, so the samples at the limit cannot be fitted.  Off the limit
the current follows the quasi-static armature equation: :func:`electrical_part` takes Ra and
CPhi from it by least squares (:func:`electrical_regression`); the mechanical part is then
identified as in the mechanical-only mode, with the measured current and that CPhi as the
torque constant (:func:`~dcmotor_id.identification.identify.identify` does that), and
:func:`with_electrical_part` completes its result: J, b and Mc carry CPhi's relative
uncertainty too, and La is given as the upper bound ``Ra dt``.
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
    the previous sample.  Samples at the limit, or right after it, are left out.  Returns the
    values and the :func:`~dcmotor_id.identification.estimators.uncertainty.robust_covariance`
    dict.
    """
    rows, targets, lengths = [], [], []
    for rec, mask in zip(records, limited):
        assert rec.current is not None and rec.speed is not None  # a full-mode record
        keep = ~mask
        keep[1:] &= ~mask[:-1]
        keep[0] = False
        rows.append(np.column_stack([rec.current, rec.speed])[keep])
        targets.append(np.asarray(rec.voltage, dtype=float)[np.flatnonzero(keep) - 1])
        lengths.append(int(keep.sum()))
    x, y = np.vstack(rows), np.concatenate(targets)
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
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
        leave_out.append(np.linalg.lstsq(x[keep], y[keep], rcond=None)[0])
    spread = np.sqrt((len(groups) - 1) / len(groups)
                     * np.sum((np.array(leave_out) - np.mean(leave_out, axis=0)) ** 2, axis=0))
    robust['stderr'] = np.maximum(robust['stderr'], spread)
    return {'Ra': float(beta[0]), 'CPhi': float(beta[1])}, robust


def with_electrical_part(mechanical: IdentificationResult, values: dict[str, float],
                         robust: dict[str, Any], records: Sequence[Record],
                         progress: Progress) -> IdentificationResult:
    """
    Complete the mechanical-only result of a current-limited drive with its electrical part.

    ``values`` and ``robust`` are Ra and CPhi off the limit (:func:`electrical_part`);
    ``mechanical`` the result of the mechanical-only identification with that CPhi.  La is
    the upper bound ``Ra dt`` (the samples off the limit follow the quasi-static equation).
    """
    ra, cphi = values['Ra'], values['CPhi']
    dt = records[0].sample_period_s
    parameters = {'Ra': ra, 'La': ra * dt, 'CPhi': cphi, **mechanical.parameters}
    parameters.update(derived_values(parameters))
    stderr, stderr_model = _standard_errors(mechanical, values, robust)
    names = PARAMETER_NAMES + DERIVED_NAMES
    reason = ('an amplifier current limit shapes the current rise, and off the limit the '
              f'current follows the quasi-static equation: La < {ra * dt:.3g} H (Ra dt, upper '
              'bound, given as its value)')
    not_identifiable = {'La': reason, 'Ta': reason, **mechanical.not_identifiable}
    warnings = _warnings(mechanical, robust, records)
    initial_states, noise = _with_current(mechanical, records)
    return replace(
        mechanical, parameters={name: float(parameters[name]) for name in names},
        stderr={name: float(stderr[name]) for name in names},
        stderr_model={name: float(stderr_model[name]) for name in names},
        mode='full', torque_constant=None,
        initial_states=initial_states,
        noise_std=noise, units={name: UNITS[name] for name in names},
        uncertainty_method=mechanical.uncertainty_method + '; Ra, CPhi: least squares off the '
        'current limit (max of the batch-means sandwich and an 8-group jackknife); J, b, Mc '
        'include the relative '
        'uncertainty of CPhi',
        not_identifiable=not_identifiable, warnings=warnings,
        upper_bounds={'La': parameters['La'], 'Ta': parameters['Ta']},
        elapsed_s=progress.elapsed())


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
    noise['current'] = float(np.sqrt(np.mean([noise_std(rec.current) ** 2
                                              for rec in records])))
    initial_states = [[float(rec.current[0]), *state]
                      for rec, state in zip(records, mechanical.initial_states)]
    return initial_states, noise
