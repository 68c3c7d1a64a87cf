"""
From checked records to the identification result (the CLI's and the node's common path).

:func:`prepare_records` checks what was read and derives speed from position where needed;
:func:`check_excitation` refuses data that cannot identify the motor, naming the parameters;
:func:`identify` runs an estimator (and the discovery loop) and returns an
:class:`IdentificationResult`, whose :meth:`~IdentificationResult.as_dict` is the JSON layout
of the CLI contract.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.discovery import DiscoveryLoop, DiscoveryResult
from dcmotor_id.effects import VOCABULARY
from dcmotor_id.errors import DcMotorIdError, FitError, InputDataError, NotIdentifiableError
from dcmotor_id.estimators.paper import PaperEstimator
from dcmotor_id.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.model import (DERIVED_NAMES, inadmissible, MECHANICAL_NAMES, PARAMETER_NAMES,
                              POSITIVE_NAMES, UNITS)
from dcmotor_id.plausibility import check_plausibility
from dcmotor_id.records import check_record
from dcmotor_id.residuals import ChannelErrors, model_errors
from dcmotor_id.signals import low_pass, noise_std, speed_from_position

if TYPE_CHECKING:
    from dcmotor_id.effects import Effect
    from dcmotor_id.estimators.base import Estimate
    from dcmotor_id.records import Record

#: Estimators by the name the CLI's ``--method`` takes.
METHODS = {'refined': RefinedEstimator, 'paper': PaperEstimator}
#: Relative standard error above which a parameter counts as not identified.
IDENTIFIABLE_REL_STDERR = 0.5
#: Simulation error (percent of std) above which the model is said not to fit at all.
NO_FIT_NRMSE_PCT = 60.0
#: Simulation error of the base model above which effect discovery is not tried (percent).
HOPELESS_NRMSE_PCT = 100.0
#: Parameters that must be positive (the others non-negative).


def prepare_records(records: Sequence[Record], torque_constant: float | None = None,
                    resample: bool = False,
                    speed_cutoff_hz: float | None = None) -> list[Record]:
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
            assert record.position is not None  # checked above: no speed means a position
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


def check_excitation(records: Sequence[Record], mechanical_only: bool) -> None:
    """
    Refuse data that do not excite the motor, naming what cannot be identified.

    Raises
    ------
    NotIdentifiableError
        Constant voltage with the motor in steady state, a motor that never moves, or a speed
        that never reverses (Coulomb friction then cannot be told from a load torque).

    """
    measured = [np.asarray(rec.speed, dtype=float) for rec in records]
    speeds = np.concatenate(measured)
    smooth = np.concatenate([low_pass(speed, min(0.05, 25.0 * rec.sample_period_s), order=2)
                             for speed, rec in zip(measured, records)])
    noise = max(max(noise_std(speed) for speed in measured),
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


def simulation_errors(estimate: Estimate, records: Sequence[Record],
                      torque_constant: float | None = None, terms: Sequence = ()) -> ChannelErrors:
    """
    Return the simulation error of an estimate over the records (from its initial states).

    The result is ``{current_nrmse_pct, speed_nrmse_pct}``
    (:func:`dcmotor_id.residuals.model_errors`); the current error is ``None`` in
    mechanical-only mode (current is the input there).
    """
    model = OutputErrorModel(records, torque_constant, terms)
    return model_errors(model, dict(estimate.parameters), estimate.initial_states)


def _check_result(estimate):
    """Refuse non-physical or non-identified results instead of reporting made-up numbers."""
    bad = inadmissible(estimate.parameters)
    if bad:
        listing = ', '.join(f'{name} = {value:.4g} {UNITS[name]}' for name, value in bad.items())
        hint = (' Check the signs and units of the columns (current and speed must be positive '
                'for a positive voltage).')
        if estimate.method == 'paper':
            hint += ' The paper method is also not robust to sensor noise: use --method refined.'
        raise FitError(f'the {estimate.method} method gave non-physical values: {listing}.'
                       + hint)
    loose = [name for name in POSITIVE_NAMES
             if name in estimate.parameters and np.isfinite(estimate.stderr.get(name, np.nan))
             and estimate.stderr[name] > IDENTIFIABLE_REL_STDERR * estimate.parameters[name]]
    if loose:
        raise NotIdentifiableError(
            'not identifiable from these data (standard error above 50 %): '
            + ', '.join(f'{name} = {estimate.parameters[name]:.4g} +/- '
                        f'{estimate.stderr[name]:.2g} {UNITS[name]}' for name in loose)
            + '. Use a richer excitation (faster changes for La, larger speed changes for J) or '
            'a longer record.')


@dataclass
class IdentificationResult:
    """
    The result of :func:`identify`: the JSON contract's values plus the objects behind them.

    The fields up to ``discovery`` are the JSON layout (:meth:`as_dict`, the ``--json`` file
    and the node's result); ``sources`` is written as ``records``.  The remaining fields are
    for callers that go further (the report, studies): the final :class:`Estimate`, the
    records identified and the discovery loop's result.

    Attributes
    ----------
    parameters, stderr : dict
        Final values and their standard errors, by name.
    method : str
        Estimator name.
    effects : list of dict
        Effects found, in the order added, each ``{"name", "parameters"}``.
    error_before, error_after : dict
        Simulation error (``{current,speed}_nrmse_pct``) of the base and the final model on
        the held-out data; in-sample when the loop did not run.
    unexplained : bool
        Structure that matters remains that no candidate effect explains.
    mode : str
        ``full`` or ``mechanical``.
    torque_constant : float or None
        Given for the mechanical-only mode.
    initial_states : list of list of float
        Initial state of every record.
    noise_std : dict
        Noise level per channel as the estimator saw it.
    sample_period_s : float
        Sample period.
    n_samples : int
        Samples over all records.
    sources : list of str or None
        Source of every record (the JSON key ``records``).
    units : dict
        Unit of every parameter.
    discover : bool
        Whether discovery was asked for.
    discovery : dict or None
        The loop's JSON account, or ``{"skipped": reason}``, or None when not asked for.
    estimate : Estimate
        The final estimate (all data).
    input_records : list of Record
        The records identified (as given, before any data effect).
    discovery_result : DiscoveryResult or None
        The loop's result, when it ran.

    """

    parameters: dict[str, float]
    stderr: dict[str, float]
    method: str
    effects: list[dict[str, Any]]
    error_before: ChannelErrors
    error_after: ChannelErrors
    unexplained: bool
    mode: str
    torque_constant: float | None
    initial_states: list[list[float]]
    noise_std: dict[str, float]
    sample_period_s: float
    n_samples: int
    sources: list[str | None]
    units: dict[str, str]
    discover: bool
    discovery: dict[str, Any] | None
    estimate: Estimate = field(repr=False)
    input_records: list[Record] = field(repr=False, default_factory=list)
    discovery_result: DiscoveryResult | None = field(repr=False, default=None)

    def as_dict(self) -> dict[str, Any]:
        """Return the JSON layout of the CLI and node contract (a new dict)."""
        from dcmotor_id.validate import model_block
        out = {
            'parameters': self.parameters,
            'stderr': self.stderr,
            'method': self.method,
            'effects': self.effects,
            'error_before': self.error_before,
            'error_after': self.error_after,
            'unexplained': self.unexplained,
            'mode': self.mode,
            'torque_constant': self.torque_constant,
            'initial_states': self.initial_states,
            'noise_std': self.noise_std,
            'sample_period_s': self.sample_period_s,
            'n_samples': self.n_samples,
            'records': self.sources,
            'units': self.units,
            'discover': self.discover,
            'discovery': self.discovery,
        }
        out['model'] = model_block(out)  # all that `dcmotor-id validate` needs to simulate
        return out


def supports_discovery(estimator: Any) -> bool:
    """
    Whether the discovery loop can follow this estimator (it fits effect terms).

    The :class:`~dcmotor_id.estimators.base.Estimator` protocol's ``supports_terms`` says
    whether the estimator fits effect terms (the refined one does, the paper's does not).
    """
    return bool(getattr(estimator, 'supports_terms', False))


def identify(records: Sequence[Record], method: str = 'refined',
             torque_constant: float | None = None, discover: bool = True,
             estimator: Any = None,
             vocabulary: Sequence[type[Effect]] | None = None) -> IdentificationResult:
    """
    Identify the motor from prepared records.

    Parameters
    ----------
    records : list of Record
        From :func:`prepare_records`.
    method : str
        ``refined`` (default) or ``paper``.
    torque_constant : float, optional
        Mechanical-only mode with this torque constant [N m/A].
    discover : bool
        Run the residual analysis and effect discovery (:mod:`dcmotor_id.discovery`; for an
        estimator that :func:`supports_discovery`: the refined method).
    estimator : object, optional
        An estimator instance to use instead of the one named by ``method``.
    vocabulary : sequence of Effect classes, optional
        Candidates of the loop (default :data:`dcmotor_id.effects.VOCABULARY`).

    Returns
    -------
    IdentificationResult
        Its :meth:`~IdentificationResult.as_dict` is the JSON result: ``parameters`` (final
        values), ``stderr``, ``method``, ``effects``, ``error_before`` / ``error_after``,
        ``unexplained``, ``discovery`` (the loop's steps and evidence, or why it did not
        run), plus ``mode``, ``initial_states``, ``noise_std``, ``sample_period_s``,
        ``n_samples``, ``records``, ``units``.

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
    check_plausibility(final.parameters, final.stderr, records, torque_constant)
    names = MECHANICAL_NAMES if mechanical_only else PARAMETER_NAMES + DERIVED_NAMES
    return IdentificationResult(
        parameters={name: final.parameters[name] for name in names},
        stderr={name: final.stderr[name] for name in names},
        method=final.method,
        effects=found.effects_json() if found is not None else [],
        error_before=found.error_before if found is not None else errors,
        error_after=found.error_after if found is not None else dict(errors),
        unexplained=bool(found.unexplained) if found is not None else False,
        mode='mechanical' if mechanical_only else 'full',
        torque_constant=torque_constant,
        initial_states=[list(state) for state in final.initial_states],
        noise_std=final.info.get('noise_std', {}),
        sample_period_s=records[0].sample_period_s,
        n_samples=int(sum(len(rec) for rec in records)),
        sources=[rec.source for rec in records],
        units={name: UNITS[name] for name in names},
        discover=bool(discover),
        discovery=discovery_info,
        estimate=final,
        input_records=list(records),
        discovery_result=found,
    )


def _run_discovery(records, torque_constant, estimator, vocabulary):
    """Run the loop; return ``(DiscoveryResult or None, JSON summary or skip reason)``."""
    if not supports_discovery(estimator):
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
