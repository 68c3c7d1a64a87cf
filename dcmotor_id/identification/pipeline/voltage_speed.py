"""
The path of records without a current: the voltage-to-speed model as an identification result.

:func:`identify_voltage_speed` fits ``kS, kV, kA``
(:mod:`~dcmotor_id.identification.estimators.voltage_speed`) and returns an
:class:`~dcmotor_id.identification.result.IdentificationResult` of mode ``voltage_speed``:
``parameters`` and ``stderr`` hold ``kS, kV, kA``; ``not_identifiable`` says plainly that
Ra, CPhi, J, b and Mc are not separable without the current (and kS from kV on one
voltage level in one direction: kS is then taken as 0, :func:`one_level_reason`);
``combined`` gives what each parameter is made of (and the armature time constant when the
data resolve it; the apparent kV and kA when kS was taken as 0).  With discovery on, the
effects that act on the shaft are searched on this model
(:mod:`~dcmotor_id.identification.discovery.voltage_speed`): the ones found are listed in
``effects`` with their parameters in volts (``combined`` gives each with its standard error),
and kS, kV, kA are those of the model with them.
"""

from __future__ import annotations

import time
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import NotIdentifiableError
from dcmotor_id.formats.held import restore_held
from dcmotor_id.identification.checks.gap import replayed_channel, undecided
from dcmotor_id.identification.checks.identifiability import misfit_message, misfit_ratios
from dcmotor_id.identification.discovery.voltage_speed import (discover_voltage_speed, IN_VOLTS,
                                                               VoltageSpeedDiscovery)
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.estimators.voltage_speed import (COMBINATIONS,
                                                                fit_voltage_speed,
                                                                moving_voltage, NAMES,
                                                                NOT_SEPARABLE,
                                                                regression_fit, simulate_speed,
                                                                UNITS,
                                                                VoltageSpeedFit)
from dcmotor_id.identification.pipeline.floor import heldout_stops
from dcmotor_id.identification.result import IdentificationResult
from dcmotor_id.identification.validate import operating_range

if TYPE_CHECKING:
    from dcmotor_id.core.progress import Progress
    from dcmotor_id.core.records import Record

#: The mode of the result (JSON ``mode``).
MODE = 'voltage_speed'
#: Said with every such result: a current recorded under another name is not used.
NO_CURRENT_COLUMN = ('no current in the records: the voltage-to-speed model (kS, kV, kA) was '
                     'fitted; if the current was recorded, name its column current (or give '
                     '--column current=NAME) to identify Ra, La, CPhi, J, b, Mc')
#: What ``combined.acceleration_gain`` is made of.
ACCELERATION_GAIN_OF = 'Ra J / CPhi + (La / Ra) Ra b / CPhi'
#: kA's relative standard error above which (and above twice the acceleration gain's) the
#: result says that the lag and the inertia are split loosely.
LOOSE_KA = 0.02
#: Said when the time budget ran out during the effect search.
DISCOVERY_BUDGET = ('the time budget (--max-time) ran out during the effect search: the '
                    'effects found so far are kept; give more time to search them all')


def identify_voltage_speed(records: Sequence[Record], discover: bool = True,
                           progress: Progress | None = None,
                           structure_bootstrap: int = 0) -> IdentificationResult:
    """
    Identify ``kS, kV, kA`` from records of voltage and speed (no current).

    Parameters
    ----------
    records : list of Record
        Prepared records with a voltage and a speed and no current.
    discover : bool
        Whether to search the effects that act on the shaft (:func:`discover_voltage_speed`).
    progress : Progress, optional
        Progress line and time budget (``--max-time``): past it in the armature-lag fit the
        first-order model is kept, in the effect search the effects so far (warnings say so).
    structure_bootstrap : int
        The resamples asked for: not drawn on voltage and speed (a warning says so).

    Returns
    -------
    IdentificationResult
        Of mode ``voltage_speed`` (method ``voltage_speed``); ``TimeBudgetExceeded`` is
        raised when the budget runs out before the first-order fit.

    """
    began = time.monotonic()
    # A speed sensor refreshing slower than the log: fit on its real updates (as stage 1).
    records, held = restore_held(list(records))
    base = fit_voltage_speed(records, progress)
    found = discover_voltage_speed(records, base, progress) if discover else None
    fit = found.fit if found is not None and found.fit is not None else base  # with effects
    stderr, apparent, one_level = _friction_at_zero(records, fit)
    stderr, said = _undecided(records, fit, stderr, _as_measured(fit.speeds, found, records))
    combined = {**_entries(fit, stderr), **apparent, **_lag_entries(fit), **_effect_entries(found)}
    warnings = ([NO_CURRENT_COLUMN] + held + list(fit.notes) + _lag_warnings(fit)
                + _discovery_warnings(found, structure_bootstrap) + _misfit(fit, records) + said)
    result = IdentificationResult(
        parameters=dict(fit.values), stderr=stderr, method=MODE,
        effects=found.effects_json() if found is not None else [],
        error_before={'current_nrmse_pct': None, 'speed_nrmse_pct': base.nrmse_start_pct},
        error_after={'current_nrmse_pct': None, 'speed_nrmse_pct': fit.nrmse_pct},
        unexplained=False, mode=MODE, torque_constant=None,
        initial_states=[[speed] for speed in fit.initial_speeds],
        noise_std={'speed': fit.noise_std}, sample_period_s=records[0].sample_period_s,
        n_samples=sum(len(rec) for rec in records), sources=[rec.source for rec in records],
        units=dict(UNITS), discover=discover,
        discovery=found.summary if found is not None else None,
        stderr_model={name: value / fit.correlation_factor
                      for name, value in fit.stderr.items()},
        uncertainty_method=('Gauss-Newton of the output-error fit on the speed, scaled by '
                            f'the residual correlation (factor {fit.correlation_factor:.3g})'),
        not_identifiable={**one_level, 'Ra, CPhi, J, b, Mc': NOT_SEPARABLE},
        warnings=warnings, combined=combined, operating_range=operating_range(records),
        input_records=list(records),
        estimate=Estimate(MODE, dict(fit.values), dict(stderr),
                          [[speed] for speed in fit.initial_speeds],
                          {'simulated_speeds': _as_measured(fit.speeds, found, records),
                           'start': base.start}))
    result.elapsed_s = time.monotonic() - began
    return result


def _undecided(records: Sequence[Record], fit: VoltageSpeedFit, stderr: dict[str, float],
               speeds: Sequence[np.ndarray]) -> tuple[dict[str, float], list[str]]:
    """
    Test the fit against the model-free regression on the held-out part (as the full mode).

    :func:`~dcmotor_id.identification.checks.gap.undecided` with the regression
    (:func:`~dcmotor_id.identification.estimators.voltage_speed.regression_fit`) simulated
    from each record's first samples, the fit as it simulates the records (``speeds``, as
    the sensor reads them), both on the held-out ends
    (:func:`~dcmotor_id.identification.pipeline.floor.heldout_stops`).
    """
    try:
        values, floor_stderr = regression_fit(records)
    except NotIdentifiableError:
        return dict(stderr), []
    stops = heldout_stops(records)
    mine, own = [], []
    for record, speed, stop in zip(records, speeds, stops):
        measured = np.asarray(record.speed, dtype=float)
        floor_speed = simulate_speed(values, np.asarray(record.voltage, dtype=float),
                                     record.sample_period_s, float(np.mean(measured[:3])))
        mine.append(np.asarray(speed, dtype=float)[stop:] - measured[stop:])
        own.append(floor_speed[stop:] - measured[stop:])
    residuals = {'speed': (np.concatenate(mine), np.concatenate(own))}
    try:
        replayed = regression_fit([
            record.replace(speed=replayed_channel(speed, record.noise_std('speed')))
            for record, speed in zip(records, speeds)])[0]
    except NotIdentifiableError:
        return dict(stderr), []
    found = undecided((fit.values, stderr), (values, floor_stderr), replayed, residuals, NAMES)
    return found.stderr, found.warnings


def _entries(fit: VoltageSpeedFit, stderr: dict[str, float]) -> dict[str, dict]:
    """Return the ``combined`` entries of kS, kV, kA: value, standard error, unit, make-up."""
    return {name: {'value': fit.values[name], 'stderr': stderr[name], 'of': COMBINATIONS[name],
                   'unit': UNITS[name]} for name in COMBINATIONS}


def _friction_at_zero(records: Sequence[Record], fit: VoltageSpeedFit
                      ) -> tuple[dict[str, float], dict[str, dict], dict[str, str]]:
    """
    Return the standard errors, the apparent values and kS's reason when kS was held at 0.

    One voltage level in one direction (``fit.friction_at_zero``): the standard errors of
    kS, kV and kA reach the far ends of their ranges (kS in [0, |u|): the motor moved, so its
    friction is below the voltage; kV and kA scale with ``(u - kS)/u``); ``apparent_kV`` and
    ``apparent_kA`` give the values with the fit's own standard errors; ``not_identifiable``
    names kS with the reason.  Otherwise the fit's standard errors and nothing else.
    """
    if not fit.friction_at_zero:
        return dict(fit.stderr), {}, {}
    level = float(np.median(moving_voltage(records)[0]))
    kv, ka = fit.values['kV'], fit.values['kA']
    stderr = {'kS': abs(level), 'kV': max(fit.stderr['kV'], kv),
              'kA': max(fit.stderr['kA'], ka)}
    apparent = {'apparent_kV': {'value': kv, 'stderr': fit.stderr['kV'], 'unit': UNITS['kV'],
                                'of': 'u / w at the final speed: kV + kS / w'},
                'apparent_kA': {'value': ka, 'stderr': fit.stderr['kA'], 'unit': UNITS['kA'],
                                'of': 'kA u / (u - kS)'}}
    return stderr, apparent, {'kS': one_level_reason(level, kv, ka)}


def one_level_reason(level: float, kv: float, ka: float) -> str:
    """Say that one voltage level ties kS to kV, what kV and kA are then, and their ranges."""
    return (f'one voltage level ({level:.4g} V) in one direction: the spin-up gives its final '
            f'speed ({level / kv:.4g} rad/s) and its time constant (kA/kV = {ka / kv:.3g} s), '
            'two numbers for kS, kV and kA, and kS + kV w = u at the final speed ties kS to '
            f'kV. kS was taken as 0: kV = {kv:.4g} V s/rad is the apparent ratio u/w (kV + '
            f'kS/w) and kA = {ka:.4g} V s^2/rad the apparent kA u/(u - kS), upper bounds of '
            'the true ones if kS >= 0. The record bounds kS only by the voltage (the motor '
            f'moved: kS < {abs(level):.4g} V), so kV lies in (0, {kv:.4g}] and kA in (0, '
            f'{ka:.4g}] (their standard errors reach the far end; combined apparent_kV and '
            "apparent_kA give the fit's own). Record steps of two or more voltage levels, or "
            'both directions, to separate them')


def _as_measured(speeds: Sequence[np.ndarray], found: VoltageSpeedDiscovery | None,
                 records: Sequence[Record]) -> list[np.ndarray]:
    """Return the simulated speeds as the records' sensor reads them (a delay found, undone)."""
    delay = sum(int(inner.get('samples', 0)) for cls, inner in
                (found.structure.items if found is not None else []) if cls.TRANSFORM)
    if delay <= 0:
        return list(speeds)
    return [np.concatenate([np.full(delay, speed[0]), speed])[:len(record)]
            for speed, record in zip(speeds, records)]


def _effect_entries(found: VoltageSpeedDiscovery | None) -> dict[str, dict]:
    """Return the ``combined`` entries of the effects found: value and stderr in volts."""
    if found is None or found.fit is None:
        return {}
    entries = {}
    for cls, _ in found.structure.items:
        for key, (volts, unit, of) in cls.VOLTAGE_SPEED_NAMES.items():
            name = cls.term_name(key)
            entries[f'{cls.name}.{volts}'] = {
                'value': found.fit.coefficients[name],
                'stderr': found.fit.coefficient_stderr[name],
                'of': of, 'unit': unit}
    return entries


def _discovery_warnings(found: VoltageSpeedDiscovery | None,
                        structure_bootstrap: int) -> list[str]:
    """Return what the effect search says: the effects in volts, a budget run out."""
    ignored = [f'--structure-bootstrap {structure_bootstrap} ignored: its resamples are not '
               'drawn on voltage and speed alone'] * bool(structure_bootstrap)
    if found is None:
        return ignored
    return ignored + [IN_VOLTS] * bool(found.effects) + [DISCOVERY_BUDGET] * found.out_of_time


def _misfit(fit: VoltageSpeedFit, records: Sequence[Record]) -> list[str]:
    """Return the warning of a speed misfit far above its sensor's noise, as in the full mode."""
    bad = misfit_ratios(records, ('speed',), {'speed': fit.noise_std})
    return [misfit_message(bad)] if bad else []


def _lag_entries(fit: VoltageSpeedFit) -> dict[str, dict]:
    """Return the ``combined`` entries of the armature lag (none without it)."""
    if fit.armature_time_constant_s is None:
        return {}
    return {'armature_time_constant_s': {
                'value': fit.armature_time_constant_s, 'stderr': fit.armature_stderr_s,
                'of': 'La / Ra', 'unit': 's'},
            'acceleration_gain': {
                'value': fit.acceleration_gain, 'stderr': fit.acceleration_gain_stderr,
                'of': ACCELERATION_GAIN_OF, 'unit': UNITS['kA']}}


def _lag_warnings(fit: VoltageSpeedFit) -> list[str]:
    """Return the warnings of the second lag: that it was fitted, that kA is loose."""
    lag = fit.armature_time_constant_s
    if lag is None or fit.acceleration_gain is None or fit.acceleration_gain_stderr is None:
        return []
    out = [f'a second, faster lag shapes the speed (Ta = {lag:.3g} s: the armature La/Ra, or '
           'a lag of the drive or the speed sensor): kA was fitted with it (a first-order '
           'model would read it as inertia)']
    spread = fit.stderr['kA'] / fit.values['kA']
    gain_spread = fit.acceleration_gain_stderr / fit.acceleration_gain
    if spread > LOOSE_KA and spread > 2.0 * gain_spread:
        out.append(
            f'kA is split from the lag only to +-{100 * spread:.2g} % (one standard error): the '
            "speed's response fixes kA + Ta Ra b/CPhi = "
            f'{fit.acceleration_gain:.4g} V s^2/rad (+-{100 * gain_spread:.2g} %, combined '
            'acceleration_gain, the acceleration gain of a feedforward that neglects the '
            "jerk), and only the friction's reversals tell kA from Ta Ra b/CPhi; for a "
            'tighter kA record the motor reversing while it runs (a PRBS, or steps from one '
            'direction to the other)')
    return out
