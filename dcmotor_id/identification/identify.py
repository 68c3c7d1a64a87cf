"""
From checked records to the identification result (the CLI's and the node's common path).

:func:`prepare_records` checks what was read and derives speed from position where needed;
:func:`check_excitation` refuses data that cannot identify anything (no motion, steady state);
:func:`identify` runs an estimator (and the discovery loop) within a time budget, replaces the
standard errors by data-based ones (:mod:`dcmotor_id.identification.estimators.uncertainty`), says
what is
not identifiable (:mod:`dcmotor_id.identification.identifiability`: one direction only, bounds, La
below the
sample period, correlations, misfit) and returns an :class:`IdentificationResult`, whose
:meth:`~IdentificationResult.as_dict` is the JSON layout of the CLI contract.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import time
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.blas import single_threaded
from dcmotor_id.core.errors import DcMotorIdError, FitError, InputDataError, NotIdentifiableError
from dcmotor_id.core.model import (DERIVED_NAMES, derived_values, inadmissible, MECHANICAL_NAMES,
                                   PARAMETER_NAMES, parameter_names, POSITIVE_NAMES, UNITS)
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.core.records import check_record
from dcmotor_id.formats.held import restore_held
from dcmotor_id.formats.quality import coarse_speed
from dcmotor_id.identification.basin import bic, regression_evidence, regression_start, suspect
from dcmotor_id.identification.criterion import resolve_criterion
from dcmotor_id.identification.discovery import (DiscoveryLoop, DiscoveryResult, refit_all_data,
                                                 refit_start, Structure)
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.estimators.uncertainty import (block_scores, robust_covariance,
                                                              with_robust_stderr)
from dcmotor_id.identification.identifiability import (assess_excitation, at_bound,
                                                       correlated_pairs, current_limit_warning,
                                                       Excitation, IDENTIFIABLE_REL_STDERR,
                                                       initial_state_warnings, limited_samples,
                                                       loose, misfit_warning,
                                                       ONE_DIRECTION_CONFOUNDED,
                                                       one_direction_note, useful)
from dcmotor_id.identification.plausibility import check_plausibility
from dcmotor_id.identification.residuals import (ChannelErrors, model_errors, output_channels,
                                                 simulate_records, simulation_error_pct)
from dcmotor_id.identification.units_check import unit_warnings
from dcmotor_id.identification.validate import operating_range
from dcmotor_id.signals.filters import noise_std, speed_from_position

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate

#: Estimators by the name the CLI's ``--method`` takes.
METHODS = {'refined': RefinedEstimator, 'paper': PaperEstimator}
#: Simulation error (percent of std) above which the model is said not to fit at all.
NO_FIT_NRMSE_PCT = 60.0
#: Simulation error of the base model above which effect discovery is not tried (percent).
HOPELESS_NRMSE_PCT = 100.0
#: Time given to effect discovery when the base model is off by more than NO_FIT_NRMSE_PCT [s].
HOPELESS_DISCOVERY_S = 3.0
#: Groups of the jackknife of the electrical regression off a current limit.
JACKKNIFE_GROUPS = 8
#: Default time budget [s] (``--max-time``).
DEFAULT_MAX_TIME_S = 120.0
#: How the held-out part of every record is chosen (the JSON ``errors.heldout_choice``).
HELDOUT_CHOICE = ('the end of each record carrying the last 30 % of its excitation (the change '
                  'of the outputs beyond their noise; standstill and steady-speed tails add '
                  'none), at most 40 % and at least 15 % of its motion')
#: Largest relative difference of the records' sample periods taken as one period: the logged
#: time of one clock differs between records by its jitter and rounding (EMPS: 0.999984 ms and
#: 1.00001 ms, 2.6e-5), far below what changes a fit; larger differences are refused.
PERIOD_RTOL = 1e-4
#: Choices of ``--initial-state``.
INITIAL_STATES = ('estimate', 'measured')


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
                record.position, record.sample_period_s, speed_cutoff_hz), speed_derived=True)
        prepared.append(record)
    return common_period(prepared)


def common_period(records: Sequence[Record]) -> list[Record]:
    """
    Put records sampled at one period within :data:`PERIOD_RTOL` on that common period.

    The common period is the mean sample interval over all the records; each record's time
    becomes a uniform grid of it from its first instant (records already at one period are
    returned as they are).

    Raises
    ------
    InputDataError
        Periods that differ by more than :data:`PERIOD_RTOL` (relative).

    """
    periods = np.array([rec.sample_period_s for rec in records])
    if np.all(periods == periods[0]):
        return list(records)
    if np.max(periods) / np.min(periods) - 1.0 > PERIOD_RTOL:
        raise InputDataError(
            'the records have different sample periods ('
            + ', '.join(f'{p:.6g} s' for p in periods)
            + '); identify them separately or resample them to one period')
    period = (sum(float(rec.time_s[-1] - rec.time_s[0]) for rec in records)
              / sum(len(rec) - 1 for rec in records))
    return [rec.replace(time_s=rec.time_s[0] + period * np.arange(len(rec)))
            for rec in records]


def check_excitation(records: Sequence[Record], mechanical_only: bool) -> Excitation:
    """
    Refuse data that do not excite the motor at all; return how they move.

    Data that turn one way only are not refused (J, b and the direction's total friction
    torque are identified; the caller says so).

    Raises
    ------
    NotIdentifiableError
        A motor that never moves, or a constant voltage with the motor in steady state.

    """
    excitation = assess_excitation(records, mechanical_only)
    if not excitation.moves:
        raise NotIdentifiableError(
            'the motor never moves (speed stays within its noise): CPhi, J, b and Mc are not '
            'identifiable' + ('' if mechanical_only else ' (Ra and La would be, from the '
                              'current alone, but the model needs motion)')
            + '. Record while the motor turns, e.g. with a sine or PRBS voltage.')
    if excitation.constant_voltage_steady:
        raise NotIdentifiableError(
            'the voltage is constant and the motor stays in steady state: only the '
            'steady-state balance u = Ra i + CPhi w is seen, so La, J, b and Mc are not '
            'identifiable and Ra cannot be separated from CPhi. Excite the motor with a '
            'changing voltage (sine, sawtooth, PRBS, chirp; see dcmotor-id simulate).')
    return excitation


#: Samples at the start of a record a current step may take to settle.
SETTLE_SAMPLES = 3


def single_current_level(records: Sequence[Record]) -> float | None:
    """
    Return the level when every record's current is one constant value, else None.

    A current held by a current-controlled drive at one level (a torque step from rest, the
    first samples rising to it) is constant within its noise (or 2 % of the level).
    """
    settled = [np.asarray(rec.current, dtype=float)[SETTLE_SAMPLES:] for rec in records
               if rec.current is not None and len(rec) > 4 * SETTLE_SAMPLES]
    if not settled or len(settled) != len(records):
        return None
    joined = np.concatenate(settled)
    level = float(np.median(joined))
    band = max(6.0 * max(noise_std(values) for values in settled), 0.02 * abs(level))
    smooth = np.concatenate([np.convolve(values, np.ones(9) / 9, mode='valid')
                             for values in settled if len(values) >= 9])
    if level == 0.0 or smooth.size == 0 or np.max(np.abs(smooth - level)) > band:
        return None
    return level


def one_level_reason(level: float, failure: str) -> str:
    """Say why one constant current cannot separate J, b and Mc, and what to record."""
    return (f'the current is one constant level ({level:.4g} A) in every record and the fit '
            f'failed ({failure.split(":")[0]}): with a known torque constant a constant current '
            'shows only two numbers in the speed, the mechanical time constant J/b and the '
            'final speed (K i - Mc)/b; J, b and Mc are then separated only by the '
            "current's small fluctuations, too little here. Record a second current "
            'level (a step between two non-zero levels, or a step in the other '
            'direction) and give the records together')


def simulation_errors(estimate: Estimate, records: Sequence[Record],
                      torque_constant: float | None = None, terms: Sequence = (),
                      quasi_static: bool = False) -> ChannelErrors:
    """
    Return the simulation error of an estimate over the records (from its initial states).

    The result is ``{current_nrmse_pct, speed_nrmse_pct}``
    (:func:`dcmotor_id.identification.residuals.model_errors`); the current error is ``None`` in
    mechanical-only mode (current is the input there).
    """
    model = OutputErrorModel(records, torque_constant, terms, quasi_static)
    return model_errors(model, dict(estimate.parameters), estimate.initial_states)


def _check_physical(estimate):
    """Refuse non-physical results instead of reporting made-up numbers."""
    bad = inadmissible(estimate.parameters)
    if bad:
        listing = ', '.join(f'{name} = {value:.4g} {UNITS[name]}' for name, value in bad.items())
        hint = (' Check the signs and units of the columns (current and speed must be positive '
                'for a positive voltage).')
        if estimate.method == 'paper':
            hint += ' The paper method is also not robust to sensor noise: use --method refined.'
        raise FitError(f'the {estimate.method} method gave non-physical values: {listing}.'
                       + hint)


@dataclass
class IdentificationResult:
    """
    The result of :func:`identify`: the JSON contract's values plus the objects behind them.

    The fields up to ``upper_bounds`` are the JSON layout (:meth:`as_dict`, the ``--json``
    file and the node's result); ``sources`` is written as ``records``.  The remaining fields
    are for callers that go further (the report, studies): the final :class:`Estimate`, the
    records identified and the discovery loop's result.

    Attributes
    ----------
    parameters, stderr : dict
        Final values and their standard errors, by name.  ``stderr`` is the larger of the
        model-based (Gauss-Newton) and the data-based figure (``uncertainty_method``), with
        the part from the choice of structure added when ``structure_uncertainty`` says so;
        NaN (JSON null) for a parameter at its bound or given as an upper bound.
    method : str
        Estimator name.
    effects : list of dict
        Effects found, in the order added, each ``{"name", "parameters"}``.
    error_before, error_after : dict
        Simulation error (``{current,speed}_nrmse_pct``) of the base and the final model on
        the held-out data, in percent of the spread of all records joined; in-sample when the
        loop did not run.  ``errors`` has the per-record figures.
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
    stderr_model : dict
        The Gauss-Newton standard errors (white residual, exact model assumed).
    uncertainty_method : str
        How ``stderr`` was obtained.
    not_identifiable : dict
        Parameter (or effect) -> why the data do not determine it.
    warnings : list of str
        What the user must know to trust the numbers.
    errors : dict
        Per-record simulation errors (:func:`record_errors`).
    combined : dict
        Combinations reported instead of their parts, e.g. ``friction_torque_Nm``
        (``{"value", "stderr", "direction", "of"}``) on one-direction data.
    upper_bounds : dict
        Parameters given as an upper bound (``La``, ``Ta`` when the electrical time constant
        is below the sample period); ``parameters`` holds the bound.
    initial_state : str
        ``estimate`` or ``measured``.
    elapsed_s : float
        Run time.
    operating_range : dict
        Speed and current ranges and directions of the records
        (:func:`~dcmotor_id.identification.validate.operating_range`; copied into ``model``
        for ``validate``).
    start_check : dict or None
        The fit checked against model-free evidence
        (:mod:`~dcmotor_id.identification.basin`): ``evidence``
        (the regression's values), ``doubts``, and when doubted ``second_start``, ``bic`` and
        ``chosen``; None when not checked (pinned initial states, other estimators).
    estimate : Estimate
        The final estimate (all data).
    input_records : list of Record
        The records identified (as given, before any data effect).
    discovery_result : DiscoveryResult or None
        The loop's result, when it ran.
    criterion : str
        The channels the fit compared: ``speed``, ``position`` or ``both``
        (:mod:`dcmotor_id.identification.criterion`).
    structure_uncertainty : dict or None
        The noise bootstrap over the structure choice
        (:mod:`~dcmotor_id.identification.structure_uncertainty`; its part is in ``stderr``),
        ``{"skipped": reason}``, or None when not asked for.

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
    stderr_model: dict[str, float] = field(default_factory=dict)
    uncertainty_method: str = ''
    not_identifiable: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    errors: dict[str, Any] = field(default_factory=dict)
    combined: dict[str, Any] = field(default_factory=dict)
    upper_bounds: dict[str, float] = field(default_factory=dict)
    initial_state: str = 'estimate'
    elapsed_s: float = 0.0
    start_check: dict[str, Any] | None = None
    operating_range: dict[str, Any] = field(default_factory=dict)
    estimate: Estimate | None = field(repr=False, default=None)
    input_records: list[Record] = field(repr=False, default_factory=list)
    discovery_result: DiscoveryResult | None = field(repr=False, default=None)
    criterion: str = 'speed'
    structure_uncertainty: dict[str, Any] | None = None

    def as_dict(self) -> dict[str, Any]:
        """Return the JSON layout of the CLI and node contract (a new dict)."""
        from dcmotor_id.identification.validate import model_block
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
            'stderr_model': self.stderr_model,
            'uncertainty_method': self.uncertainty_method,
            'not_identifiable': self.not_identifiable,
            'warnings': self.warnings,
            'errors': self.errors,
            'combined': self.combined,
            'upper_bounds': self.upper_bounds,
            'initial_state': self.initial_state,
            'elapsed_s': self.elapsed_s,
            'start_check': self.start_check,
            'operating_range': self.operating_range,
            'criterion': self.criterion,
            'structure_uncertainty': self.structure_uncertainty,
        }
        out['model'] = model_block(out)  # all that `dcmotor-id validate` needs to simulate
        return out


def supports_discovery(estimator: Any) -> bool:
    """
    Whether the discovery loop can follow this estimator (it fits effect terms).

    The :class:`~dcmotor_id.identification.estimators.base.Estimator` protocol's ``supports_terms``
    says whether the estimator fits effect terms (the refined one does, the paper's does not).
    """
    return bool(getattr(estimator, 'supports_terms', False))


def _make_estimator(method, initial_state, progress, criterion='speed'):
    if method == 'refined':
        return RefinedEstimator(initial_state=initial_state, progress=progress,
                                criterion=criterion)
    return METHODS[method]()


def _criterion_of(records, criterion, method, estimator):
    """Return the criterion the fit uses: resolved for the refined method, else speed."""
    resolved = resolve_criterion(records, criterion)
    if estimator is not None:
        return getattr(estimator, 'criterion', 'speed')
    if method != 'refined':
        if criterion not in ('auto', 'speed'):
            raise InputDataError(f'--criterion {criterion} needs the refined method (the '
                                 f'{method} method fits the speed)')
        return 'speed'
    return resolved


@single_threaded
def identify(records: Sequence[Record], method: str = 'refined',
             torque_constant: float | None = None, discover: bool = True,
             estimator: Any = None,
             vocabulary: Sequence[type[Effect]] | None = None, *,
             max_time_s: float | None = DEFAULT_MAX_TIME_S,
             progress: Progress | None = None,
             initial_state: str = 'estimate',
             criterion: str = 'auto', structure_bootstrap: int = 0) -> IdentificationResult:
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
        Run the residual analysis and effect discovery (:mod:`dcmotor_id.identification.discovery`;
        for an
        estimator that :func:`supports_discovery`: the refined method).
    estimator : object, optional
        An estimator instance to use instead of the one named by ``method``.
    vocabulary : sequence of Effect classes, optional
        Candidates of the loop (default :data:`dcmotor_id.identification.effects.VOCABULARY`).
    max_time_s : float or None
        Time budget [s]: past it the best result so far is returned with a warning (ignored
        when ``progress`` is given: its deadline counts).
    progress : Progress, optional
        Progress report and deadline (:mod:`dcmotor_id.core.progress`); default silent.
    initial_state : str
        ``estimate`` (every record's initial state is fitted) or ``measured`` (pinned to the
        first samples).
    criterion : str
        ``auto`` (default), ``speed``, ``position`` or ``both``: the channels the output-error
        fit compares (:func:`dcmotor_id.identification.criterion.resolve_criterion`; ``auto``
        compares the
        position when the speed was derived from it).  The JSON key ``criterion`` holds the
        one used.
    structure_bootstrap : int
        Noise resamples over which the discovery is rerun so that ``stderr`` covers the choice
        of structure (:mod:`dcmotor_id.identification.structure_uncertainty`; JSON key
        ``structure_uncertainty``); 0 (default): not run.

    Returns
    -------
    IdentificationResult
        Its :meth:`~IdentificationResult.as_dict` is the JSON result: ``parameters`` (final
        values), ``stderr``, ``method``, ``effects``, ``error_before`` / ``error_after``,
        ``unexplained``, ``discovery`` (the loop's steps and evidence, or why it did not
        run), plus ``mode``, ``initial_states``, ``noise_std``, ``sample_period_s``,
        ``n_samples``, ``records``, ``units`` and the honesty fields ``stderr_model``,
        ``uncertainty_method``, ``not_identifiable``, ``warnings``, ``errors``,
        ``combined``, ``upper_bounds``, ``initial_state``, ``elapsed_s``.

    Raises
    ------
    NotIdentifiableError
        Nothing useful can be identified (no motion, steady state, or every key parameter
        undetermined).
    FitError
        The model does not reproduce the data, or no fit finished within the time budget.

    """
    if method not in METHODS:
        raise InputDataError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    if initial_state not in INITIAL_STATES:
        raise InputDataError(f'initial state must be one of {", ".join(INITIAL_STATES)}, not '
                             f'{initial_state!r}')
    if structure_bootstrap:
        from dcmotor_id.identification.structure_uncertainty import bootstrapped
        return bootstrapped(identify, records, structure_bootstrap, method=method,
                            torque_constant=torque_constant, discover=discover,
                            estimator=estimator, vocabulary=vocabulary, max_time_s=max_time_s,
                            progress=progress, initial_state=initial_state, criterion=criterion)
    progress = progress if progress is not None else Progress(max_time_s)
    resolved = _criterion_of(records, criterion, method, estimator)
    arguments = (records, method, torque_constant, discover, estimator, vocabulary, progress,
                 initial_state)
    try:
        return _identify(*arguments, resolved)
    except FitError as error:
        if criterion != 'auto' or resolved == 'speed' or 'time budget' in str(error):
            raise
        # The position integrates every force the model lacks over the whole record: a base
        # model that cannot follow it (a load the loop did not find) is refused there, and
        # ``auto`` falls back to the speed, as before the position criterion.
        result = _identify(*arguments, 'speed')
        reason = str(error).split('. Check')[0]
        result.warnings.insert(0, f'the fit on the position failed ({reason}): the integral '
                                  'of a force the model lacks drifts over the record (the loop '
                                  'looks for it unless --no-discover); the result is the fit '
                                  'on the speed (--criterion speed)')
        return result


def _identify(records, method, torque_constant, discover, estimator, vocabulary, progress,
              initial_state, criterion):
    """Identify with a resolved criterion (:func:`identify`'s body)."""
    mechanical_only = torque_constant is not None
    # Sensors refreshing slower than the log: fit on their real updates (said in a warning).
    records, warnings = restore_held(list(records))
    warnings += [text for text in map(coarse_speed, records) if text]
    excitation = check_excitation(records, mechanical_only)
    not_identifiable: dict[str, str] = {}
    vocabulary = list(vocabulary or VOCABULARY)
    limited = None if mechanical_only or estimator is not None or method != 'refined' else \
        limited_samples(records)
    if limited is not None:
        return replace(_identify_current_limited(records, limited, discover, vocabulary,
                                                 progress, initial_state), criterion='speed')
    if excitation.one_direction:
        vocabulary = [cls for cls in vocabulary if cls.name not in ONE_DIRECTION_CONFOUNDED]
    estimator = estimator or _make_estimator(method, initial_state, progress, criterion)
    progress.set_stage('base fit', _names(records))
    try:
        estimate = estimator.fit(records, torque_constant=torque_constant)
    except FitError as error:
        level = single_current_level(records) if mechanical_only else None
        if level is None:
            raise
        raise NotIdentifiableError(one_level_reason(level, str(error))) from None
    except TimeBudgetExceeded:
        raise FitError(f'no fit finished within the time budget ({progress.max_time_s:g} s): '
                       'give more time with --max-time, or shorten or decimate the records'
                       ) from None
    _check_physical(estimate)
    errors = simulation_errors(estimate, records, torque_constant)
    quasi, full_la = False, None
    if not mechanical_only and isinstance(estimator, RefinedEstimator):
        # La first: when the data cannot resolve it, the quasi-static armature is the model
        # of everything that follows (discovery included).
        robust = with_robust_stderr(estimate)
        full_la = (robust.parameters['La'], robust.stderr['La'], robust.parameters['Ra'])
        if _la_unresolved(*full_la, records[0].sample_period_s):
            refit = _quasi_static_refit(estimate, records, errors, initial_state, progress,
                                        criterion)
            if refit is None:
                not_identifiable['La'] = _la_reason(*full_la, records[0].sample_period_s,
                                                    None)
            else:
                estimate, quasi = refit, True
                errors = simulation_errors(estimate, records, None, quasi_static=True)
    found, discovery_info = None, None
    checkable = initial_state == 'estimate' and isinstance(estimator, RefinedEstimator)
    start_check: dict[str, Any] | None = None
    if checkable:
        # A base in a wrong basin misleads the effect screen: checked before the loop.
        found, estimate, discovery_info, start_check = _check_start(
            records, torque_constant, quasi, discover, vocabulary, progress, estimate, None,
            None)
        if start_check['chosen'] == 'first start':
            start_check = None if not start_check['doubts'] else start_check
        else:
            errors = simulation_errors(estimate, records, torque_constant, quasi_static=quasi)
    base_worst = max([value for value in errors.values() if value is not None] or [np.inf])
    if criterion != 'speed':
        # The base model's position may be far off for lack of the very effect (a load) the
        # loop is there to find: the loop gets its full time, the final model is checked.
        base_worst = min(base_worst, NO_FIT_NRMSE_PCT)
    if start_check is not None and start_check['chosen'] != 'first start':
        pass  # the second start ran its own discovery
    elif discover and not base_worst <= HOPELESS_NRMSE_PCT:
        # Worse than the signals' mean: a sign or unit error, which no effect explains (and
        # every candidate fit would diverge slowly); refuse below without the loop.
        discovery_info = {'skipped': f'the base model does not fit ({base_worst:.3g} % '
                                     'simulation error)'}
    elif discover:
        deadline = progress.deadline
        if base_worst > NO_FIT_NRMSE_PCT:
            # A base model this far off is rarely rescued by one effect: a short look only, so
            # that a record that cannot be fitted is refused in seconds.
            progress.deadline = min(deadline if deadline is not None else np.inf,
                                    time.monotonic() + HOPELESS_DISCOVERY_S)
        try:
            found, discovery_info = _run_discovery(records, torque_constant, estimator,
                                                   vocabulary, progress, initial_state, quasi,
                                                   estimate, criterion)
        finally:
            progress.deadline = deadline
        if found is not None and found.out_of_time:
            warnings.append(f'the time budget ({progress.max_time_s:g} s) ran out during '
                            'effect discovery: the result is the best structure so far'
                            + (' fitted on the training parts only (first '
                               f'{100 * (1 - found.holdout_fraction):.0f} % of the motion)'
                               if found.estimate is found.final.estimate else '')
                            + '; give more time with --max-time')
        elif found is None and discovery_info and 'time budget' in discovery_info.get(
                'skipped', ''):
            warnings.append(discovery_info['skipped'])
    if checkable and start_check is None:
        # The base looked sound; check where discovery led.
        found, estimate, discovery_info, start_check = _check_start(
            records, torque_constant, quasi, discover, vocabulary, progress, estimate, found,
            discovery_info)
    if start_check is not None and start_check['chosen'] != 'first start':
        warnings.append(_second_start_warning(start_check))
    elif start_check is not None and start_check['doubts']:
        outcome = start_check.get('second_start')
        warnings.append('the fit disagrees with the model-free evidence ('
                        + '; '.join(start_check['doubts']) + ') and a second start '
                        + (f'could not help ({outcome})' if isinstance(outcome, str) else
                           'explains the data no better')
                        + ': the values may come from a wrong basin; compare with '
                        '--initial-state measured')
    final, terms, fitted_records = estimate, (), list(records)
    if found is not None:
        final, terms, fitted_records = found.estimate, found.terms, found.records
    in_sample = simulation_errors(final, fitted_records, torque_constant, terms, quasi)
    worst = max(value for value in in_sample.values() if value is not None) \
        if any(value is not None for value in in_sample.values()) else float('inf')
    if not np.isfinite(worst) or worst > NO_FIT_NRMSE_PCT:
        raise FitError(
            f'the identified model does not reproduce the data (simulation error {worst:.3g} % '
            'of the signal spread). Check that the columns are what their names say (units, '
            'signs) and that the data come from a DC motor drive.')
    final = with_robust_stderr(final)
    stderr_model = dict(final.info.get('stderr_model', final.stderr))
    upper_bounds: dict[str, float] = {}
    if quasi and full_la is not None:
        final, upper_bounds = _with_la_bound(final, *full_la, records[0].sample_period_s)
        stderr_model = dict(final.info['stderr_model'])
        not_identifiable['La'] = _la_reason(*full_la, records[0].sample_period_s,
                                            upper_bounds['La'])
    names = MECHANICAL_NAMES if mechanical_only else PARAMETER_NAMES + DERIVED_NAMES
    parameters = {name: float(final.parameters[name]) for name in names}
    stderr = {name: float(final.stderr.get(name, np.nan)) for name in names}
    stderr_model = {name: float(stderr_model.get(name, np.nan)) for name in names}
    for name in upper_bounds:
        stderr[name] = stderr_model[name] = float('nan')
    combined: dict[str, Any] = {}
    bound = at_bound(final, fitted_records, torque_constant)
    if excitation.one_direction:
        note = one_direction_note(excitation, parameters['Mc'])
        not_identifiable['Mc'] = note
        not_identifiable['load_torque'] = note
        combined['friction_torque_Nm'] = {
            'value': parameters['Mc'], 'stderr': stderr['Mc'],
            'direction': excitation.direction, 'of': ['Mc', 'load_torque']}
        bound.pop('Mc', None)
    for name, reason in bound.items():
        not_identifiable[name] = reason
        stderr[name] = float('nan')
    checked = [name for name in names if name not in not_identifiable and name not in
               upper_bounds and name not in ('Ka',)]
    not_identifiable.update(loose(final, [name for name in checked if name in POSITIVE_NAMES
                                          or name == 'Ta']))
    # Orders of magnitude against the data's own scales: refused there, else warnings (the
    # parameters already said to be at a bound are not repeated).
    warnings += [text for text in check_plausibility(final.parameters, final.stderr, records,
                                                     torque_constant)
                 if not any(text.startswith(f'{name} = ') for name in not_identifiable)]
    warnings += unit_warnings(final.parameters, records, mechanical_only)
    if not useful(list(parameters), not_identifiable, mechanical_only):
        raise NotIdentifiableError(
            'nothing useful is identifiable from these data: '
            + '; '.join(f'{name}: {reason}' for name, reason in not_identifiable.items())
            + '. Use a richer excitation (faster changes for La, larger speed changes for J) '
            'or a longer record.')
    outputs = output_channels(mechanical_only)
    warnings += _result_warnings(final, fitted_records, terms, outputs, torque_constant,
                                 quasi, list(bound) + list(upper_bounds), initial_state)
    if found is not None and found.effects:
        shift = _structure_shift(found.base_estimate, parameters, stderr)
        if shift:
            warnings.append(shift)
    errors_detail = record_errors(records, estimate, final, found, torque_constant, terms,
                                  quasi)
    if errors_detail.get('note'):
        warnings.append(errors_detail['note'])
    if errors_detail.get('worse_than_constant'):
        warnings.append('on the held-out part the model predicts worse than a constant (the '
                        "record's mean): " + ', '.join(errors_detail['worse_than_constant'])
                        + '; the fit may sit in a wrong basin or miss an effect: compare with '
                        '--initial-state measured and --no-discover')
    return IdentificationResult(
        parameters=parameters,
        stderr=stderr,
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
        stderr_model=stderr_model,
        uncertainty_method=final.info.get('uncertainty_method',
                                          f"the {final.method} estimator's own"),
        not_identifiable=not_identifiable,
        warnings=warnings,
        errors=errors_detail,
        combined=combined,
        upper_bounds=upper_bounds,
        initial_state=initial_state,
        elapsed_s=progress.elapsed(),
        start_check=start_check,
        operating_range=operating_range(records),
        estimate=final,
        input_records=list(records),
        discovery_result=found,
        criterion=criterion,
    )


def _electrical_regression(records, limited):
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


def _identify_current_limited(records, limited, discover, vocabulary, progress, initial_state):
    """
    Identify a drive whose amplifier limits the current (the model has no limit).

    The electrical part by :func:`_electrical_regression` off the limit, then the mechanical
    part as in the mechanical-only mode with the measured current and that CPhi as the torque
    constant; J, b and Mc carry CPhi's relative uncertainty too.  La is given as the upper
    bound ``Ra dt`` (the samples off the limit follow the quasi-static equation).
    """
    values, robust = _electrical_regression(records, limited)
    if not (values['Ra'] > 0 and values['CPhi'] > 0):
        raise FitError('the current sits at an amplifier limit and the samples off the limit '
                       f'give non-physical values (Ra = {values["Ra"]:.4g} Ohm, CPhi = '
                       f'{values["CPhi"]:.4g} V s/rad): check the signs and units of the '
                       'columns')
    mechanical = identify(records, torque_constant=values['CPhi'], discover=discover,
                          vocabulary=vocabulary, progress=progress,
                          initial_state=initial_state)
    ra, cphi = values['Ra'], values['CPhi']
    dt = records[0].sample_period_s
    se = dict(zip(('Ra', 'CPhi'), robust['stderr']))
    se_model = dict(zip(('Ra', 'CPhi'), robust['stderr_model']))
    parameters = {'Ra': ra, 'La': ra * dt, 'CPhi': cphi, **mechanical.parameters}
    parameters.update(derived_values(parameters))
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
    names = PARAMETER_NAMES + DERIVED_NAMES
    reason = ('an amplifier current limit shapes the current rise, and off the limit the '
              f'current follows the quasi-static equation: La < {ra * dt:.3g} H (Ra dt, upper '
              'bound, given as its value)')
    not_identifiable = {'La': reason, 'Ta': reason, **mechanical.not_identifiable}
    warnings = [current_limit_warning(records) or 'current limit']
    if abs(robust['correlation'][0, 1]) > 0.99:
        warnings.append(f'Ra and CPhi are correlated {robust["correlation"][0, 1]:+.3f}: the '
                        'data determine a combination of them better than each')
    warnings += mechanical.warnings
    warnings.append('the current is the input of the mechanical fit here: the simulation '
                    'errors are of the speed only')
    noise = dict(mechanical.noise_std)
    noise['current'] = float(np.sqrt(np.mean([noise_std(rec.current) ** 2
                                              for rec in records])))
    return replace(
        mechanical, parameters={name: float(parameters[name]) for name in names},
        stderr={name: float(stderr[name]) for name in names},
        stderr_model={name: float(stderr_model[name]) for name in names},
        mode='full', torque_constant=None,
        initial_states=[[float(rec.current[0]), *state]
                        for rec, state in zip(records, mechanical.initial_states)],
        noise_std=noise, units={name: UNITS[name] for name in names},
        uncertainty_method=mechanical.uncertainty_method + '; Ra, CPhi: least squares off the '
        'current limit (max of the batch-means sandwich and an 8-group jackknife); J, b, Mc '
        'include the relative '
        'uncertainty of CPhi',
        not_identifiable=not_identifiable, warnings=warnings,
        upper_bounds={'La': parameters['La'], 'Ta': parameters['Ta']},
        elapsed_s=progress.elapsed())


def _check_start(records, torque_constant, quasi, discover, vocabulary, progress, estimate,
                 found, discovery_info):
    """
    Check the fit against model-free evidence; when doubted, try a second start, keep the best.

    Returns ``(found, base estimate, discovery summary, start_check)``, the first three
    replaced by the second start's when it explains all of the data better (lower BIC).
    ``start_check`` is the JSON account (:mod:`dcmotor_id.identification.basin`).
    """
    evidence = regression_evidence(records, torque_constant)
    first = found.estimate if found is not None else estimate
    first_records = found.records if found is not None else list(records)
    first_terms = found.terms if found is not None else ()
    model = OutputErrorModel(first_records, torque_constant, first_terms, quasi)
    doubts = suspect(first, first_records, model, evidence)
    check: dict[str, Any] = {'evidence': evidence, 'doubts': doubts, 'chosen': 'first start'}
    if not doubts:
        return found, estimate, discovery_info, check
    names = [name for name in parameter_names(torque_constant is not None)
             if not (quasi and name == 'La')]
    start = regression_start(evidence, estimate.parameters, names)
    progress.set_stage('second start (initial states pinned)', _names(records))
    second, second_info, freed = None, None, None
    try:
        pinned = RefinedEstimator(initial=start, initial_state='measured', quasi_static=quasi,
                                  progress=progress).fit(records, torque_constant=torque_constant)
        _check_physical(pinned)
    except (DcMotorIdError, np.linalg.LinAlgError, TimeBudgetExceeded) as error:
        check['second_start'] = f'failed: {error}'
        return found, estimate, discovery_info, check
    structure, values, states = Structure(), pinned.parameters, pinned.initial_states
    if discover:
        second, second_info = _run_discovery(
            records, torque_constant, RefinedEstimator(), vocabulary, progress, 'measured',
            quasi, pinned)
        if second is not None:
            structure = second.final.structure
            values, states = second.estimate.parameters, second.estimate.initial_states
    pinned_final = second.estimate if second is not None else pinned
    second_records = structure.transformed(records)
    second_model = OutputErrorModel(second_records, torque_constant,
                                    second.terms if second is not None else (), quasi)
    try:
        freed = refit_all_data(structure, records, torque_constant, values,
                               refit_start(values, records, torque_constant), progress=progress,
                               initial_states=states, initial_state='estimate',
                               quasi_static=quasi)[2]
        _check_physical(freed)
    except (DcMotorIdError, np.linalg.LinAlgError, TimeBudgetExceeded) as error:
        check['freed'] = f'failed: {error}'  # the pinned fit is still a candidate
        freed = None
    noise = dict(first.info.get('noise_std', {}))
    scores = {'first start': bic(first, first_records, model, noise),
              'second start, initial states pinned': bic(pinned_final, second_records,
                                                         second_model, noise,
                                                         free_states=False)}
    if freed is not None:
        scores['second start'] = bic(freed, second_records, second_model, noise)
    chosen = min(scores, key=lambda key: scores[key])
    shown = freed if freed is not None else pinned_final
    check.update({'second_start': {'effects': structure.names(),
                                   'J': float(shown.parameters['J']),
                                   'b': float(shown.parameters['b'])},
                  'bic': scores, 'chosen': chosen})
    if chosen == 'first start':
        return found, estimate, discovery_info, check
    final = freed if chosen == 'second start' and freed is not None else pinned_final
    if second is None:
        return None, final, discovery_info, check
    second = replace(second, estimate=final, effects=structure.effects(final.parameters))
    return second, pinned, second_info, check


def _second_start_warning(check: dict[str, Any]) -> str:
    """Return the warning of a result taken from the second start."""
    how = ("the fit with every initial state pinned to the records' first samples"
           if check['chosen'].endswith('pinned') else
           'from a second start (the regression on the data, initial states pinned to the '
           'first samples while the effects were searched, then freed)')
    return ('the fit from the default start landed where the model-free evidence disagrees ('
            + '; '.join(check['doubts']) + f'); the result is {how}, which explains all of the '
            'data better (BIC)')


def _structure_shift(base: Estimate, parameters: dict[str, float],
                     stderr: dict[str, float]) -> str | None:
    """Say how far the effects found moved the base parameters, when beyond 3 stderr."""
    moved = {}
    for name in ('Ra', 'CPhi', 'J', 'b', 'Mc'):
        if name in base.parameters and np.isfinite(stderr.get(name, np.nan)) and \
                stderr[name] > 0:
            ratio = abs(parameters[name] - base.parameters[name]) / stderr[name]
            if ratio > 3.0:
                moved[name] = (_relative_change(parameters[name], base.parameters[name]), ratio)
    if not moved:
        return None
    listing = ', '.join(f'{name} {change} ({ratio:.0f} stderr)'
                        for name, (change, ratio) in moved.items())
    return (f'the effects found move the base parameters beyond their standard errors ({listing}'
            '): the structure matters more than the noise here, and the standard errors do not '
            'cover the choice of structure; compare with --no-discover')


def _relative_change(value: float, base: float) -> str:
    """Change from ``base`` to ``value`` in percent, or absolute when the base is zero."""
    if base == 0.0 or not np.isfinite(base):
        return f'{base:.3g} -> {value:.3g}'
    return f'{100.0 * (value / base - 1.0):+.3g} %'


def _names(records):
    names = [rec.source for rec in records if rec.source]
    if not names:
        return None
    return names[0] if len(names) == 1 else f'{len(records)} records'


def _la_unresolved(la: float, la_stderr: float, ra: float, dt: float) -> bool:
    """Whether La is below what the sample period resolves, or undetermined."""
    return bool(la / ra < dt or la_stderr > IDENTIFIABLE_REL_STDERR * la)


def _quasi_static_refit(estimate, records, errors, initial_state, progress, criterion='speed'):
    """
    Refit with the quasi-static armature (La -> 0); return the estimate or None.

    The refit is kept when its current simulation error is at most 25 % (and 0.5 points)
    worse than the full model's: the full model's La then adds nothing the data resolve.
    """
    values = estimate.parameters
    start = {name: values[name] for name in parameter_names(False) if name != 'La'}
    progress.set_stage('quasi-static armature refit')
    try:
        quasi = RefinedEstimator(initial=start, quasi_static=True, initial_state=initial_state,
                                 progress=progress, criterion=criterion).fit(records)
        quasi_errors = simulation_errors(quasi, records, None, quasi_static=True)
    except (DcMotorIdError, np.linalg.LinAlgError, ValueError):
        return None
    full_current = errors.get('current_nrmse_pct') or 0.0
    quasi_current = quasi_errors.get('current_nrmse_pct')
    if quasi_current is None or quasi_current > 1.25 * full_current + 0.5:
        return None
    return quasi


def _with_la_bound(quasi, la, la_stderr, ra_full, dt):
    """
    Give a quasi-static estimate La, Ka and Ta: La by its upper bound, Ta from it.

    The bound is the larger of ``Ra dt`` (a time constant below the sample period) and the
    full fit's ``La + 2 stderr``; ``stderr`` of La and Ta is NaN, Ka's follows Ra's.
    """
    bound = max(quasi.parameters['Ra'] * dt, la + 2.0 * la_stderr)
    parameters = dict(quasi.parameters)
    parameters['La'] = bound
    parameters.update(derived_values(parameters))
    ra = parameters['Ra']
    stderr = dict(quasi.stderr)
    stderr.update({'La': float('nan'), 'Ta': float('nan'), 'Ka': quasi.stderr['Ra'] / ra ** 2})
    model = dict(quasi.info.get('stderr_model', quasi.stderr))
    model.update({'La': float('nan'), 'Ta': float('nan'),
                  'Ka': model.get('Ra', np.nan) / ra ** 2})
    info = {**quasi.info, 'stderr_model': model}
    result = replace(quasi, parameters=parameters, stderr=stderr, info=info)
    return result, {'La': bound, 'Ta': parameters['Ta']}


def _la_reason(la, la_stderr, ra, dt, bound):
    ta = la / ra
    why = (f'the electrical time constant La/Ra = {ta:.2g} s is below the sample period '
           f'{dt:.2g} s' if ta < dt else
           f'La = {la:.3g} +/- {la_stderr:.2g} H is not determined')
    if bound is None:
        return why + ': La is not identifiable from these data (sample faster to see it)'
    return (why + f': La < {bound:.3g} H (upper bound, given as its value); Ra, CPhi, J, b and '
            'Mc come from the quasi-static armature equation (La -> 0): '
            'J dw/dt = CPhi (u - CPhi w)/Ra - b w - Mc sgn w, i = (u - CPhi w)/Ra')


def _result_warnings(estimate, records, terms, outputs, torque_constant, quasi, skip,
                     initial_state):
    """Warnings of the final fit: correlations, initial states, misfit, current limit."""
    warnings = correlated_pairs(estimate, skip=skip)
    if initial_state == 'estimate':
        warnings += initial_state_warnings(estimate, records, outputs)
    model = OutputErrorModel(records, torque_constant, terms, quasi)
    simulated = simulate_records(model, estimate.parameters, estimate.initial_states)
    rms = {channel: float(np.sqrt(np.mean(np.concatenate(
        [out[channel] - getattr(rec, channel) for out, rec in zip(simulated, records)]) ** 2)))
        for channel in outputs}
    misfit = misfit_warning(estimate, records, outputs, rms)
    if misfit:
        warnings.append(misfit)
    return warnings


def _run_discovery(records, torque_constant, estimator, vocabulary, progress, initial_state,
                   quasi_static=False, estimate=None, criterion='speed'):
    """Run the loop; return ``(DiscoveryResult or None, JSON summary or skip reason)``."""
    if not supports_discovery(estimator):
        return None, {'skipped': f'effect discovery needs the refined method (the '
                                 f'{getattr(estimator, "name", "given")} method has no effect '
                                 'terms)'}
    try:
        found = DiscoveryLoop(records, torque_constant, vocabulary=vocabulary,
                              progress=progress, initial_state=initial_state,
                              quasi_static=quasi_static, criterion=criterion).run(estimate)
        _check_physical(found.estimate)
    except TimeBudgetExceeded:
        return None, {'skipped': f'the time budget ({progress.max_time_s:g} s) ran out '
                                 'before effect discovery had a result: the base model is '
                                 'reported'}
    except (DcMotorIdError, np.linalg.LinAlgError) as error:
        return None, {'skipped': f'effect discovery could not run on these data: {error}'}
    return found, found.summary()


def _part_metrics(simulated, measured, outputs, spread=None):
    """
    NRMSE and fit % per channel of one part.

    In percent of this part's own spread, or of ``spread`` (channel -> standard deviation,
    e.g. over the whole record) when given.
    """
    out: dict[str, float | None] = {}
    for channel in ('current', 'speed'):
        value = None
        if channel in outputs and measured[channel].shape[0] > 1:
            if spread is None:
                value = simulation_error_pct(simulated[channel], measured[channel])
            elif spread[channel] > 0:
                residual = np.asarray(simulated[channel]) - measured[channel]
                value = float(np.sqrt(np.mean(residual ** 2))) / spread[channel] * 100.0
                value = value if np.isfinite(value) else None
        out[f'{channel}_nrmse_pct'] = value
        out[f'{channel}_fit_pct'] = None if value is None else 100.0 - value
    return out


def _heldout_item(item, rec, index, found, outputs):
    """Fill a record's held-out figures: segment, errors, constant predictor; moves or not."""
    stop = found.final.stops[index]
    speed = np.asarray(rec.speed, dtype=float)
    held = speed[stop:]
    noise = max(noise_std(speed), 1e-12)
    moves = held.shape[0] > 5 and float(np.ptp(held)) > 10.0 * noise
    item['heldout_samples'] = int(len(rec) - stop)
    item['heldout_moves'] = bool(moves)
    time_s = np.asarray(rec.time_s, dtype=float)
    item['heldout_segments'] = [{'start_sample': int(stop), 'end_sample': int(len(rec)),
                                 'start_s': float(time_s[stop]), 'end_s': float(time_s[-1])}]
    if not moves:
        return False
    for label, fit in (('before', found.base), ('after', found.final)):
        # Each fit on its own records (a delay found shifts the final one's).
        start = fit.stops[index]
        spread = {c: float(np.std(getattr(fit.records[index], c))) for c in outputs}
        measured = {c: getattr(fit.records[index], c)[start:] for c in outputs}
        item[label]['heldout'] = _part_metrics(
            {c: fit.simulated[index][c][start:] for c in outputs}, measured, outputs, spread)
    item['heldout_constant'] = _part_metrics(
        {c: np.full(measured[c].shape, float(np.mean(getattr(found.final.records[index], c))))
         for c in outputs}, measured, outputs, spread)
    return True


def _worse_than_constant(items):
    """List the records whose held-out error exceeds a constant predictor's (its mean)."""
    worse = []
    for item in items:
        model, constant = item['after']['heldout'], item.get('heldout_constant')
        if not model or not constant:
            continue
        for key in ('current_nrmse_pct', 'speed_nrmse_pct'):
            if model.get(key) is not None and constant.get(key) is not None and \
                    model[key] > constant[key]:
                worse.append(f'{item["source"] or "record"} ({key.split("_")[0]} '
                             f'{model[key]:.3g} % against {constant[key]:.3g} %)')
    return worse


def _pooled(items):
    """Root mean square over records of each figure (records that have it)."""
    keys = {key for item in items for key in item}
    out: dict[str, float | None] = {}
    for key in sorted(keys):
        values = [item[key] for item in items if item.get(key) is not None]
        if not values:
            out[key] = None
        elif key.endswith('fit_pct'):
            out[key] = None
        else:
            out[key] = float(np.sqrt(np.mean(np.square(values))))
    for key in list(out):
        if key.endswith('fit_pct'):
            nrmse = out.get(key.replace('fit_pct', 'nrmse_pct'))
            out[key] = None if nrmse is None else 100.0 - nrmse
    return out


def record_errors(records: Sequence[Record], base: Estimate, final: Estimate,
                  found: DiscoveryResult | None, torque_constant: float | None = None,
                  terms: Sequence = (), quasi_static: bool = False) -> dict[str, Any]:
    """
    Per-record simulation errors, each normalised by its own record (the JSON ``errors``).

    Every figure is the NRMSE in percent of that part's own standard deviation and the
    MATLAB-style fit ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` = ``100 - NRMSE``, per
    channel.  ``whole_record``: the all-data fits simulated over each whole record (in-sample).
    ``heldout``: the training-part fits of the discovery loop on each record's held-out part
    (the end of the record carrying the last share of its excitation,
    :func:`~dcmotor_id.identification.discovery.excited_stop`), in percent of the *whole
    record's* spread (a steady tail's own spread is tiny); None for a record whose held-out
    part does not move.
    ``heldout_constant`` is the same figure for a constant predictor (the record's mean).

    Returns
    -------
    dict
        ``records`` (one ``{"source", "samples", "heldout_samples", "heldout_moves",
        "heldout_segments", "heldout_constant", "before": {"whole_record", "heldout"},
        "after": {...}}`` per record), ``before`` and ``after`` (root mean square over
        records), ``heldout_fraction``, ``heldout_choice``, ``heldout_normalisation``,
        ``worse_than_constant`` (records whose held-out error exceeds the constant's) and
        ``note``.

    """
    mechanical_only = torque_constant is not None
    outputs = output_channels(mechanical_only)
    prepared = found.records if found is not None else list(records)
    whole: dict[str, list] = {}
    for label, estimate, record_terms in (('before', base, ()), ('after', final, terms)):
        quasi = bool(estimate.info.get('quasi_static'))
        source = records if label == 'before' else prepared
        model = OutputErrorModel(source, torque_constant, record_terms, quasi)
        whole[label] = []
        # One record's simulation at a time, dropped once measured (memory).
        for index, state in enumerate(estimate.initial_states):
            with np.errstate(all='ignore'):
                simulated = model.simulate(estimate.parameters, index,
                                           np.array(state, dtype=float))
            whole[label].append(_part_metrics(
                simulated, {c: getattr(source[index], c) for c in outputs}, outputs))
            del simulated
    items = []
    notes = []
    for index, rec in enumerate(records):
        item: dict[str, Any] = {'source': rec.source, 'samples': len(rec)}
        for label in ('before', 'after'):
            item[label] = {'whole_record': whole[label][index], 'heldout': None}
        if found is not None and not _heldout_item(item, rec, index, found, outputs):
            notes.append(rec.source or f'record {index + 1}')
        items.append(item)
    summary = {label: {part: _pooled([item[label][part] for item in items
                                      if item[label][part] is not None])
                       for part in ('whole_record', 'heldout')} for label in ('before', 'after')}
    note = None
    if notes:
        note = ('held-out part without motion (standstill), not used to judge the fit: '
                + ', '.join(notes))
    worse = _worse_than_constant(items)
    return {'records': items, **summary,
            'heldout_fraction': None if found is None else found.holdout_fraction,
            'heldout_choice': None if found is None else HELDOUT_CHOICE,
            'heldout_normalisation': 'standard deviation of the whole record',
            'worse_than_constant': worse,
            'note': note}
