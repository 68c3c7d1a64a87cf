"""
From checked records to the identification result (the CLI's and the node's common path).

:func:`prepare_records` checks what was read and derives speed from position where needed;
:func:`check_excitation` refuses data that cannot identify the motor, naming the parameters;
:func:`identify` runs an estimator and returns the result in the JSON layout of the CLI
contract.
"""

import numpy as np

from dcmotor_id.discovery import DiscoveryLoop
from dcmotor_id.effects import VOCABULARY
from dcmotor_id.errors import DcMotorIdError, FitError, InputDataError, NotIdentifiableError
from dcmotor_id.estimators.base import nrmse_pct
from dcmotor_id.estimators.paper import PaperEstimator
from dcmotor_id.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.model import DERIVED_NAMES, PARAMETER_NAMES, UNITS
from dcmotor_id.records import check_record
from dcmotor_id.signals import low_pass, noise_std, speed_from_position

#: Estimators by the name the CLI's ``--method`` takes.
METHODS = {'refined': RefinedEstimator, 'paper': PaperEstimator}
#: Relative standard error above which a parameter counts as not identified.
IDENTIFIABLE_REL_STDERR = 0.5
#: Simulation error (percent of std) above which the model is said not to fit at all.
NO_FIT_NRMSE_PCT = 60.0
#: Simulation error of the base model above which effect discovery is not tried (percent).
HOPELESS_NRMSE_PCT = 100.0


def prepare_records(records, torque_constant=None, resample=False, speed_cutoff_hz=None):
    """
    Check records and give each a speed; return the list ready for an estimator.

    Parameters
    ----------
    records : list of Record
        As read from files or bags.
    torque_constant : float, optional
        Torque constant [N m/A]: selects the mechanical-only mode (no voltage needed).
    resample : bool
        Interpolate irregularly sampled records onto a uniform grid instead of refusing them.
    speed_cutoff_hz : float, optional
        Cut-off of the differentiating filter used when only position is given.

    """
    if not records:
        raise InputDataError('no records given')
    if torque_constant is not None and not (np.isfinite(torque_constant) and
                                            torque_constant > 0):
        raise InputDataError(f'--torque-constant must be a positive number in N m/A, got '
                             f'{torque_constant}')
    prepared = []
    for record in records:
        if torque_constant is None and record.voltage is None:
            name = record.source or 'record'
            raise InputDataError(
                f'{name}: no voltage column. Name it voltage, or identify the mechanical part '
                'only (J, b, Mc) by giving the torque constant: --torque-constant K [N m/A]')
        record = check_record(record, need_voltage=torque_constant is None, resample=resample)
        if record.speed is None:
            nyquist_hz = 0.5 / record.sample_period_s
            if speed_cutoff_hz is not None and not 0 < speed_cutoff_hz < nyquist_hz:
                raise InputDataError(
                    f'{record.source or "record"}: --speed-cutoff {speed_cutoff_hz:g} Hz is not '
                    f'below the Nyquist frequency {nyquist_hz:.6g} Hz of the record; give a '
                    'lower cut-off (the default is a tenth of the sample rate, at most 100 Hz)')
            record = record.replace(speed=speed_from_position(
                record.position, record.sample_period_s, speed_cutoff_hz))
        prepared.append(record)
    periods = np.array([rec.sample_period_s for rec in prepared])
    if np.max(np.abs(periods / periods[0] - 1.0)) > 1e-6:
        raise InputDataError(
            'the records have different sample periods ('
            + ', '.join(f'{p:.6g} s' for p in periods)
            + '); identify them separately or resample them to one period')
    return prepared


def check_excitation(records, mechanical_only):
    """
    Refuse data that do not excite the motor, naming what cannot be identified.

    Raises
    ------
    NotIdentifiableError
        Constant voltage with the motor in steady state, a motor that never moves, or a speed
        that never reverses (Coulomb friction then cannot be told from a load torque).

    """
    speeds = np.concatenate([rec.speed for rec in records])
    smooth = np.concatenate([low_pass(rec.speed, min(0.05, 25.0 * rec.sample_period_s), order=2)
                             for rec in records])
    noise = max(max(noise_std(rec.speed) for rec in records),
                1e-12 * max(np.max(np.abs(speeds)), 1e-300))
    if np.max(np.abs(smooth)) <= 10.0 * noise:
        raise NotIdentifiableError(
            'the motor never moves (speed stays within its noise): CPhi, J, b and Mc are not '
            'identifiable' + ('' if mechanical_only else ' (Ra and La would be, from the '
                              'current alone, but the model needs motion)')
            + '. Record while the motor turns, e.g. with a sine or PRBS voltage.')
    if not mechanical_only:
        voltages = np.concatenate([rec.voltage for rec in records])
        constant_voltage = np.ptp(voltages) <= 1e-9 * max(np.max(np.abs(voltages)), 1e-300)
        speed_change = np.ptp(smooth) / max(np.max(np.abs(smooth)), 1e-300)
        if constant_voltage and speed_change < 0.05:
            raise NotIdentifiableError(
                'the voltage is constant and the motor stays in steady state: only the '
                'steady-state balance u = Ra i + CPhi w is seen, so La, J, b and Mc are not '
                'identifiable and Ra cannot be separated from CPhi. Excite the motor with a '
                'changing voltage (sine, sawtooth, PRBS, chirp; see dcmotor-id simulate).')
    # A reversal must be a visible part of the motion, not filter ringing around a start at rest.
    level = max(10.0 * noise, 0.02 * float(np.max(np.abs(smooth))))
    positive = np.any(smooth > level)
    negative = np.any(smooth < -level)
    if not (positive and negative):
        raise NotIdentifiableError(
            'the speed never reverses: the Coulomb friction Mc acts as a constant torque and '
            'cannot be told apart from a load torque, so Mc is not identifiable (nor b '
            'reliably). Record with the shaft turning both ways, e.g. a voltage that changes '
            'sign.')


def simulation_errors(estimate, records, torque_constant=None, terms=()):
    """
    Return the simulation error of an estimate over the records.

    The result is ``{current_nrmse_pct, speed_nrmse_pct}``.

    The current error is ``None`` in mechanical-only mode (current is the input there).
    """
    model = OutputErrorModel(records, torque_constant, terms)
    values = dict(estimate.parameters)
    sims = {channel: [] for channel in model.outputs}
    with np.errstate(all='ignore'):
        for index, state in enumerate(estimate.initial_states):
            out = model.simulate(values, index, np.array(state, dtype=float))
            for channel in model.outputs:
                sims[channel].append(out[channel])
    errors = {'current_nrmse_pct': None, 'speed_nrmse_pct': None}
    for channel in model.outputs:
        simulated = np.concatenate(sims[channel])
        measured = np.concatenate([getattr(rec, channel) for rec in records])
        value = nrmse_pct(simulated, measured)
        errors[f'{channel}_nrmse_pct'] = value if np.isfinite(value) else None
    return errors


def _check_result(estimate):
    """Refuse non-physical or non-identified results instead of reporting made-up numbers."""
    bad = {name: value for name, value in estimate.parameters.items()
           if name in PARAMETER_NAMES and not (np.isfinite(value) and (
               value > 0 if name in ('Ra', 'La', 'CPhi', 'J') else value >= 0))}
    if bad:
        listing = ', '.join(f'{name} = {value:.4g} {UNITS[name]}' for name, value in bad.items())
        hint = (' Check the signs and units of the columns (current and speed must be positive '
                'for a positive voltage).')
        if estimate.method == 'paper':
            hint += ' The paper method is also not robust to sensor noise: use --method refined.'
        raise FitError(f'the {estimate.method} method gave non-physical values: {listing}.'
                       + hint)
    loose = [name for name in ('Ra', 'La', 'CPhi', 'J')
             if name in estimate.parameters and np.isfinite(estimate.stderr.get(name, np.nan))
             and estimate.stderr[name] > IDENTIFIABLE_REL_STDERR * estimate.parameters[name]]
    if loose:
        raise NotIdentifiableError(
            'not identifiable from these data (standard error above 50 %): '
            + ', '.join(f'{name} = {estimate.parameters[name]:.4g} +/- '
                        f'{estimate.stderr[name]:.2g} {UNITS[name]}' for name in loose)
            + '. Use a richer excitation (faster changes for La, larger speed changes for J) or '
            'a longer record.')


def identify(records, method='refined', torque_constant=None, discover=True, estimator=None,
             details=False, vocabulary=None):
    """
    Identify the motor from prepared records; return the result as a JSON-ready dict.

    Parameters
    ----------
    records : list of Record
        From :func:`prepare_records`.
    method : str
        ``refined`` (default) or ``paper``.
    torque_constant : float, optional
        Mechanical-only mode with this torque constant [N m/A].
    discover : bool
        Run the residual analysis and effect discovery (:mod:`dcmotor_id.discovery`; the
        refined method only).
    estimator : object, optional
        An estimator instance to use instead of the one named by ``method``.
    details : bool
        Also return the :class:`~dcmotor_id.discovery.DiscoveryResult` (None when the loop
        did not run), for the report.
    vocabulary : sequence of Effect classes, optional
        Candidates of the loop (default :data:`dcmotor_id.effects.VOCABULARY`).

    Returns
    -------
    dict
        ``parameters`` (final values), ``stderr``, ``method``, ``effects`` (in the order
        added, each ``{"name", "parameters"}``), ``error_before`` / ``error_after``
        (simulation error on the held-out data of the base and the final model; in-sample
        when the loop did not run), ``unexplained``, ``discovery`` (the loop's steps and
        evidence, or why it did not run), plus ``mode``, ``initial_states``, ``noise_std``,
        ``sample_period_s``, ``n_samples``, ``records``, ``units``.  With ``details`` a
        tuple ``(dict, DiscoveryResult or None)``.

    """
    if method not in METHODS:
        raise InputDataError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    mechanical_only = torque_constant is not None
    check_excitation(records, mechanical_only)
    estimator = estimator or METHODS[method]()
    estimate = estimator.fit(records, torque_constant=torque_constant)
    _check_result(estimate)
    errors = simulation_errors(estimate, records, torque_constant)
    found, discovery_info = None, None
    base_worst = max([value for value in errors.values() if value is not None] or [np.inf])
    if discover and not base_worst <= HOPELESS_NRMSE_PCT:
        # Worse than the signals' mean: a sign or unit error, which no effect explains (and
        # every candidate fit would diverge slowly); refuse below without the loop.
        discovery_info = {'skipped': f'the base model does not fit ({base_worst:.3g} % '
                                     'simulation error)'}
    elif discover:
        found, discovery_info = _run_discovery(records, torque_constant, estimator, vocabulary)
    final, terms, fitted_records = estimate, (), records
    if found is not None:
        final, terms, fitted_records = found.estimate, found.terms, found.records
    in_sample = simulation_errors(final, fitted_records, torque_constant, terms)
    worst = max(value for value in in_sample.values() if value is not None) \
        if any(value is not None for value in in_sample.values()) else float('inf')
    if not np.isfinite(worst) or worst > NO_FIT_NRMSE_PCT:
        raise FitError(
            f'the identified model does not reproduce the data (simulation error {worst:.3g} % '
            'of the signal spread). Check that the columns are what their names say (units, '
            'signs) and that the data come from a DC motor drive.')
    names = ('J', 'b', 'Mc') if mechanical_only else PARAMETER_NAMES + DERIVED_NAMES
    result = {
        'parameters': {name: final.parameters[name] for name in names},
        'stderr': {name: final.stderr[name] for name in names},
        'method': final.method,
        'effects': found.effects_json() if found is not None else [],
        'error_before': found.error_before if found is not None else errors,
        'error_after': found.error_after if found is not None else dict(errors),
        'unexplained': bool(found.unexplained) if found is not None else False,
        'mode': 'mechanical' if mechanical_only else 'full',
        'torque_constant': torque_constant,
        'initial_states': [list(state) for state in final.initial_states],
        'noise_std': final.info.get('noise_std', {}),
        'sample_period_s': records[0].sample_period_s,
        'n_samples': int(sum(len(rec) for rec in records)),
        'records': [rec.source for rec in records],
        'units': {name: UNITS[name] for name in names},
        'discover': bool(discover),
        'discovery': discovery_info,
    }
    return (result, found) if details else result


def _run_discovery(records, torque_constant, estimator, vocabulary):
    """Run the loop; return ``(DiscoveryResult or None, JSON summary or skip reason)``."""
    if not isinstance(estimator, RefinedEstimator):
        return None, {'skipped': f'effect discovery needs the refined method (the '
                                 f'{getattr(estimator, "name", "given")} method has no effect '
                                 'terms)'}
    try:
        found = DiscoveryLoop(records, torque_constant,
                              vocabulary=vocabulary or VOCABULARY).run()
        _check_result(found.estimate)
    except (DcMotorIdError, np.linalg.LinAlgError) as error:
        return None, {'skipped': f'effect discovery could not run on these data: {error}'}
    return found, found.summary()
