"""
From prepared records to the identification result (the CLI's and the node's common path).

:func:`identify` checks its arguments, runs the pipeline within a time budget and, when the
fit on the position fails under ``--criterion auto``, runs it again on the speed.  The
pipeline (``_identify``) is a list of stages, one function each, reading and setting one
state (``_Run``), top to bottom; the details of each live in a module of their own:

1. prepare: held samples restored, coarse channels named, data that do not move refused
   (:mod:`~dcmotor_id.identification.prepare`, which also makes records ready:
   :func:`~dcmotor_id.identification.prepare.prepare_records`); a drive at an amplifier's
   current limit takes its own path (:mod:`~dcmotor_id.identification.current_limited`);
2. base fit: the estimator named by ``--method`` on all data, non-physical values refused
   (:mod:`~dcmotor_id.identification.fitting`);
3. armature: La below what the data resolve makes the quasi-static armature the model
   (:mod:`~dcmotor_id.identification.quasi_static`);
4. start check: the base against model-free evidence, a second start when doubted
   (:mod:`~dcmotor_id.identification.second_start`);
5. discovery: the effect discovery loop (:mod:`~dcmotor_id.identification.discovery`);
6. final start check: where discovery led, checked the same way;
7. final fit: refused when it does not reproduce the data;
8. uncertainty: data-based standard errors
   (:mod:`~dcmotor_id.identification.estimators.uncertainty`), La by its upper bound;
9. identifiability: what the data do not determine
   (:mod:`~dcmotor_id.identification.checks.identifiability`: one direction only, bounds, loose
   parameters), plausibility and units;
10. warnings: correlations, initial states, misfit, how far the effects moved the base;
11. held-out errors: per record, whole and held out (:mod:`~dcmotor_id.identification.heldout`);
12. result: an :class:`~dcmotor_id.identification.result.IdentificationResult`, whose
    :meth:`~dcmotor_id.identification.result.IdentificationResult.as_dict` is the JSON layout
    of the CLI contract.

The names of those modules that callers import from here stay importable from here
(``__all__``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.blas import single_threaded
from dcmotor_id.core.errors import FitError, InputDataError, NotIdentifiableError
from dcmotor_id.core.model import (DERIVED_NAMES, MECHANICAL_NAMES, PARAMETER_NAMES,
                                   POSITIVE_NAMES, UNITS)
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.formats.held import restore_held
from dcmotor_id.formats.quality import coarse_speed
from dcmotor_id.identification.checks.identifiability import (at_bound, correlated_pairs,
                                                              Excitation, initial_state_warnings,
                                                              limited_samples, loose,
                                                              misfit_warning,
                                                              ONE_DIRECTION_CONFOUNDED,
                                                              one_direction_note, useful)
from dcmotor_id.identification.checks.plausibility import check_plausibility
from dcmotor_id.identification.checks.start import regression_evidence
from dcmotor_id.identification.checks.units import sign_problem, unit_warnings
from dcmotor_id.identification.criterion import resolve_criterion, with_position_states
from dcmotor_id.identification.current_limited import (electrical_part, JACKKNIFE_GROUPS,
                                                       with_electrical_part)
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.estimators.uncertainty import (between_record_warnings,
                                                              with_robust_stderr)
from dcmotor_id.identification.fitting import (check_physical, record_names, run_discovery,
                                               simulation_errors, supports_discovery)
from dcmotor_id.identification.floor import (floor_fallback, regression_floor,
                                             trimmed_records, with_floor)
from dcmotor_id.identification.heldout import HELDOUT_CHOICE, heldout_warnings, record_errors
from dcmotor_id.identification.multistart import ambiguity_warning, several_starts, with_starts
from dcmotor_id.identification.position_error import check_base, with_chosen_error_model
from dcmotor_id.identification.prepare import (check_excitation, common_period, one_level_reason,
                                               PERIOD_RTOL, prepare_records, SETTLE_SAMPLES,
                                               single_current_level)
from dcmotor_id.identification.quasi_static import (la_reason, la_unresolved, quasi_static_refit,
                                                    with_la_bound)
from dcmotor_id.identification.residuals import output_channels, simulate_records
from dcmotor_id.identification.result import IdentificationResult
from dcmotor_id.identification.second_start import check_start, start_warning
from dcmotor_id.identification.segments import split_tests
from dcmotor_id.identification.validate import operating_range

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate
    from dcmotor_id.identification.residuals import ChannelErrors

__all__ = ['check_excitation', 'common_period', 'DEFAULT_MAX_TIME_S', 'HELDOUT_CHOICE',
           'HOPELESS_DISCOVERY_S', 'HOPELESS_NRMSE_PCT', 'IdentificationResult', 'identify',
           'INITIAL_STATES', 'JACKKNIFE_GROUPS', 'METHODS', 'NO_FIT_NRMSE_PCT',
           'one_level_reason', 'PERIOD_RTOL', 'prepare_records', 'record_errors',
           'SETTLE_SAMPLES', 'simulation_errors', 'single_current_level', 'supports_discovery']

#: Estimators by the name the CLI's ``--method`` takes.
METHODS = {'refined': RefinedEstimator, 'paper': PaperEstimator}
#: Simulation error (percent of std) above which the model is said not to fit at all.
NO_FIT_NRMSE_PCT = 60.0
#: Simulation error of the base model above which effect discovery is not tried (percent).
HOPELESS_NRMSE_PCT = 100.0
#: Time given to effect discovery when the base model is off by more than NO_FIT_NRMSE_PCT
#: [s of CPU time, as the budget: :func:`dcmotor_id.core.progress.budget_clock`].
HOPELESS_DISCOVERY_S = 3.0
#: Default time budget [s] (``--max-time``).
DEFAULT_MAX_TIME_S = 120.0
#: Choices of ``--initial-state``.
INITIAL_STATES = ('estimate', 'measured')


@single_threaded
def identify(records: Sequence[Record], method: str = 'refined',
             torque_constant: float | None = None, discover: bool = True,
             estimator: Any = None, vocabulary: Sequence[type[Effect]] | None = None, *,
             max_time_s: float | None = DEFAULT_MAX_TIME_S, progress: Progress | None = None,
             initial_state: str = 'estimate', criterion: str = 'auto',
             structure_bootstrap: int = 0) -> IdentificationResult:
    """
    Identify the motor from prepared records.

    Parameters
    ----------
    records : list of Record
        From :func:`~dcmotor_id.identification.prepare.prepare_records`.
    method : str
        ``refined`` (default) or ``paper``.
    torque_constant : float, optional
        Mechanical-only mode with this torque constant [N m/A].
    discover : bool
        Run the discovery loop (:mod:`~dcmotor_id.identification.discovery`) after an
        estimator that :func:`supports_discovery`.
    estimator : object, optional
        An estimator instance instead of the one named by ``method``.
    vocabulary : sequence of Effect classes, optional
        Candidates of the loop (default :data:`dcmotor_id.identification.effects.VOCABULARY`).
    max_time_s : float or None
        Time budget [s], then the best result so far with a warning (or ``progress``'s).
    progress : Progress, optional
        Progress report and deadline (:mod:`dcmotor_id.core.progress`).
    initial_state : str
        ``estimate`` (each record's initial state is fitted) or ``measured`` (first samples).
    criterion : str
        ``auto`` (default), ``speed``, ``position`` or ``both``: the channels the fit compares
        (:func:`~dcmotor_id.identification.criterion.resolve_criterion`; JSON ``criterion``).
    structure_bootstrap : int
        Noise resamples rerunning discovery so that ``stderr`` covers the structure choice
        (:mod:`~dcmotor_id.identification.structure_uncertainty`); 0 (default): not run.

    Returns
    -------
    IdentificationResult
        Its ``as_dict()`` is the JSON result (every key is described by the class).

    Raises
    ------
    NotIdentifiableError
        Nothing useful can be identified (no motion, steady state, every key parameter loose).
    FitError
        The model does not reproduce the data, or no fit finished within the time budget.

    """
    _check_choices(method, initial_state)
    if structure_bootstrap:
        from dcmotor_id.identification.structure_uncertainty import bootstrapped
        return bootstrapped(identify, records, structure_bootstrap, method=method,
                            torque_constant=torque_constant, discover=discover,
                            estimator=estimator, vocabulary=vocabulary, max_time_s=max_time_s,
                            progress=progress, initial_state=initial_state, criterion=criterion)
    progress = progress if progress is not None else Progress(max_time_s)
    return _identify_with_floor(criterion, (records, method, torque_constant, discover,
                                            estimator, vocabulary, progress, initial_state))


# --- regression floor (issue 29; identification/floor.py): port as one stage -------------
def _identify_with_floor(criterion, arguments):
    """
    Run :func:`_identify_checked` above the model-free regression's answer.

    The regression (:func:`~dcmotor_id.identification.floor.regression_floor`) is computed
    first; a command that did not reach the motor at a record's start is cut; a failed fit
    falls back to the regression, and a fit that predicts the held-out part worse gives way
    to it (:func:`~dcmotor_id.identification.floor.with_floor`).
    """
    records, torque_constant, progress = arguments[0], arguments[2], arguments[6]
    tests = split_tests(records)  # idle or braked stretches between tests (segments.py)
    records = list(tests.records)
    floor = regression_floor(records, torque_constant) if arguments[4] is None else None
    records, left_out = trimmed_records(records, floor)
    left_out = ([tests.note] if tests.note else []) + left_out
    try:
        result = _identify_checked(criterion, (records, *arguments[1:]))
    except FitError as error:
        fallback = floor_fallback(floor, records, torque_constant, error, criterion,
                                  progress.elapsed())
        if fallback is None:
            raise
        result = fallback
    result = with_floor(result, floor, records)
    return replace(result, warnings=left_out + result.warnings) if left_out else result
# --- end of the regression floor ---------------------------------------------------------


def _identify_checked(criterion, arguments):
    """Run :func:`_identify_on`; a refusal names a channel that looks reversed, if one does."""
    try:
        return _identify_on(criterion, arguments)
    except FitError as error:
        records, torque_constant = arguments[0], arguments[2]
        found = None if 'time budget' in str(error) else sign_problem(records, torque_constant)
        if found is None:
            raise
        raise FitError(f'{str(error).rstrip(".")}. {found[0].upper()}{found[1:]}') from None


def _identify_on(criterion, arguments):
    """
    Run the pipeline on the resolved criterion; ``auto`` falls back to the speed.

    On the position, the position error's model is chosen against model-free evidence
    (:mod:`~dcmotor_id.identification.position_error`).
    """
    records, method, estimator = arguments[0], arguments[1], arguments[4]
    resolved = _criterion_of(records, criterion, method, estimator)
    try:
        if resolved == 'speed' or method != 'refined' or estimator is not None:
            return _identify(*arguments, resolved)
        return with_chosen_error_model(lambda: _identify(*arguments, resolved), arguments[6])
    except (FitError, NotIdentifiableError) as error:
        if criterion != 'auto' or resolved == 'speed' or 'time budget' in str(error):
            raise
        return _on_the_speed(arguments, error)


def _check_choices(method: str, initial_state: str) -> None:
    """Refuse an unknown method or initial-state choice, naming the choices."""
    if method not in METHODS:
        raise InputDataError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    if initial_state not in INITIAL_STATES:
        raise InputDataError(f'initial state must be one of {", ".join(INITIAL_STATES)}, not '
                             f'{initial_state!r}')


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


def _on_the_speed(arguments, error):
    """Identify on the speed after the fit on the position failed (``--criterion auto``)."""
    # The position integrates every force the model lacks over the whole record: a base
    # model that cannot follow it (a load the loop did not find) is refused there, and
    # ``auto`` falls back to the speed, as before the position criterion.
    result = _identify(*arguments, 'speed')
    reason = str(error).split('. Check')[0].split('. Use')[0]
    result.warnings.insert(0, f'the fit on the position failed ({reason}): the integral '
                              'of a force the model lacks drifts over the record (the loop '
                              'looks for it unless --no-discover); the result is the fit '
                              'on the speed (--criterion speed)')
    return result


def _identify(records, method, torque_constant, discover, estimator, vocabulary, progress,
              initial_state, criterion):
    """
    Identify with a resolved criterion (:func:`identify`'s body): the stages in order.

    Each stage reads and sets the fields of one :class:`_Run`; a stage may refuse the data
    (raise), and a drive at an amplifier's current limit takes its own path.
    """
    run = _prepare(records, method, torque_constant, discover, estimator, vocabulary,
                   progress, initial_state, criterion)
    limited = _current_limit(run)
    if limited is not None:
        return replace(_identify_current_limited(run.records, limited, discover, run.vocabulary,
                                                 progress, initial_state), criterion='speed')
    _base_fit(run)
    _armature(run)
    _check_base_start(run)
    if run.criterion != 'speed':
        check_base(run.estimate.parameters, run.records, run.torque_constant,
                   resume=lambda: _after_the_start_check(run), evidence=run.evidence)
    return _after_the_start_check(run)


def _after_the_start_check(run: _Run) -> IdentificationResult:
    """Stages 5-12 of :func:`_identify` (a white run left after its base resumes here)."""
    _discovery(run)
    _check_final_start(run)
    _final_fit(run)
    _uncertainty(run)
    _identifiability(run)
    _fit_warnings(run)
    _heldout(run)
    return _result(run)


@dataclass
class _Run:
    """
    One identification as it passes through the stages of :func:`_identify`.

    The inputs (the records as the first stage leaves them), then what the stages find, in
    the order they set it.  ``estimate`` is the base fit on all data (replaced by the
    quasi-static refit or the second start), ``final`` the reported one.
    """

    # The inputs.
    records: list[Record]
    method: str
    torque_constant: float | None
    discover: bool
    estimator: Any
    vocabulary: list[type[Effect]]
    progress: Progress
    initial_state: str
    criterion: str
    # What the user must know (every stage may add), and what the data do not determine.
    warnings: list[str]
    not_identifiable: dict[str, str] = field(default_factory=dict)
    # What the stages find, in order.
    excitation: Excitation = field(init=False)
    estimate: Estimate = field(init=False)
    errors: ChannelErrors = field(init=False)
    quasi: bool = False  # the quasi-static armature (La -> 0) is the model
    full_la: tuple[float, float, float] | None = None  # La, its stderr, Ra of the full fit
    found: DiscoveryResult | None = None
    discovery_info: dict[str, Any] | None = None
    start_check: dict[str, Any] | None = None
    starts: dict[str, Any] | None = None  # the further starts of the base fit
    final: Estimate = field(init=False)
    terms: Sequence = ()
    fitted_records: list[Record] = field(init=False)
    names: tuple[str, ...] = ()
    parameters: dict[str, float] = field(default_factory=dict)
    stderr: dict[str, float] = field(default_factory=dict)
    stderr_model: dict[str, float] = field(default_factory=dict)
    upper_bounds: dict[str, float] = field(default_factory=dict)
    combined: dict[str, Any] = field(default_factory=dict)
    bound: dict[str, str] = field(default_factory=dict)
    errors_detail: dict[str, Any] = field(default_factory=dict)

    @property
    def mechanical_only(self) -> bool:
        """Whether the torque constant is given (J, b and Mc only)."""
        return self.torque_constant is not None

    @cached_property
    def evidence(self) -> dict[str, float] | None:
        """Return the model-free regression on the records (computed once, for every check)."""
        return regression_evidence(self.records, self.torque_constant)

    @property
    def checkable(self) -> bool:
        """Whether the fit is checked against model-free evidence (free initial states)."""
        return self.initial_state == 'estimate' and isinstance(self.estimator, RefinedEstimator)


def _prepare(records, method, torque_constant, discover, estimator, vocabulary, progress,
             initial_state, criterion) -> _Run:
    """Stage 1: restore held samples, name coarse channels, refuse data without excitation."""
    # Sensors refreshing slower than the log: fit on their real updates (said in a warning).
    restored, warnings = restore_held(list(records))
    warnings += [text for text in map(coarse_speed, restored) if text]
    run = _Run(restored, method, torque_constant, discover, estimator, [], progress,
               initial_state, criterion, warnings)
    run.excitation = check_excitation(restored, run.mechanical_only)
    run.vocabulary = list(vocabulary or VOCABULARY)
    return run


def _current_limit(run: _Run) -> list[np.ndarray] | None:
    """Return the samples at an amplifier's current limit (refined method, full mode), or None."""
    if run.mechanical_only or run.estimator is not None or run.method != 'refined':
        return None
    return limited_samples(run.records)


def _identify_current_limited(records, limited, discover, vocabulary, progress, initial_state):
    """
    Identify a drive whose amplifier limits the current (the model has no limit).

    The electrical part off the limit
    (:func:`~dcmotor_id.identification.current_limited.electrical_part`), then the mechanical
    part as in the mechanical-only mode with the measured current and that CPhi as the torque
    constant, completed by
    :func:`~dcmotor_id.identification.current_limited.with_electrical_part`.
    """
    values, robust = electrical_part(records, limited)
    mechanical = identify(records, torque_constant=values['CPhi'], discover=discover,
                          vocabulary=vocabulary, progress=progress,
                          initial_state=initial_state)
    return with_electrical_part(mechanical, values, robust, records, progress)


def _base_fit(run: _Run) -> None:
    """Stage 2: the base model (no effects) fitted on all data, and its simulation errors."""
    if run.excitation.one_direction:
        run.vocabulary = [cls for cls in run.vocabulary
                          if cls.name not in ONE_DIRECTION_CONFOUNDED]
    run.estimator = run.estimator or _make_estimator(run.method, run.initial_state,
                                                     run.progress, run.criterion)
    run.progress.set_stage('base fit', record_names(run.records))
    try:
        estimate = run.estimator.fit(run.records, torque_constant=run.torque_constant)
    except FitError as error:
        level = single_current_level(run.records) if run.mechanical_only else None
        if level is not None:
            raise NotIdentifiableError(one_level_reason(level, str(error))) from None
        estimate = _speed_base(run, error)
    except TimeBudgetExceeded:
        raise FitError(f'no fit finished within the time budget ({run.progress.max_time_s:g} '
                       's): give more time with --max-time, or shorten or decimate the records'
                       ) from None
    check_physical(estimate)
    run.estimate = estimate
    run.errors = simulation_errors(estimate, run.records, run.torque_constant)


def _make_estimator(method, initial_state, progress, criterion='speed'):
    """Return the estimator named by ``method`` (the refined one with its options)."""
    if method == 'refined':
        return RefinedEstimator(initial_state=initial_state, progress=progress,
                                criterion=criterion)
    return METHODS[method]()


def _speed_base(run: _Run, error: FitError) -> Estimate:
    """
    Fit the base model on the speed when it has no fit on the position (else raise ``error``).

    A model that lacks the very effect the loop is there to find (a force offset on an axis
    driven both ways) may have no fit on the position: its integral drifts and the fit runs
    to an infinite inertia.  Its speed fit is the base the loop starts from
    (:func:`~dcmotor_id.identification.criterion.with_position_states`).
    """
    if run.criterion == 'speed' or not isinstance(run.estimator, RefinedEstimator):
        raise error
    speed = _make_estimator(run.method, run.initial_state, run.progress)
    estimate = with_position_states(speed.fit(run.records, torque_constant=run.torque_constant),
                                    run.records)
    reason = str(error).split(': the motor model')[0]
    run.warnings.append(f'the base model (no effects) has no fit on the position ({reason}): '
                        'the effect search started from its fit on the speed')
    return estimate


def _armature(run: _Run) -> None:
    """
    Stage 3: La first (:mod:`~dcmotor_id.identification.quasi_static`).

    When the data cannot resolve La, the quasi-static armature is the model of everything
    that follows (discovery included).
    """
    if run.mechanical_only or not isinstance(run.estimator, RefinedEstimator):
        return
    dt = run.records[0].sample_period_s
    robust = with_robust_stderr(run.estimate)
    run.full_la = (robust.parameters['La'], robust.stderr['La'], robust.parameters['Ra'])
    if not la_unresolved(*run.full_la, dt):
        return
    refit = quasi_static_refit(run.estimate, run.records, run.errors, run.initial_state,
                               run.progress, run.criterion)
    if refit is None:
        run.not_identifiable['La'] = la_reason(*run.full_la, dt, None)
    else:
        run.estimate, run.quasi = refit, True
        run.errors = simulation_errors(refit, run.records, None, quasi_static=True)


def _check_base_start(run: _Run) -> None:
    """
    Stage 4: the base checked against model-free evidence before the loop.

    A base fit that misfits far above the noise or lies far from the evidence is fitted again
    from further starts, the best kept
    (:func:`~dcmotor_id.identification.multistart.several_starts`).  A base in a wrong
    basin misleads the effect screen; when the second start explains the data better it is
    the base, and it ran its own discovery
    (:func:`~dcmotor_id.identification.second_start.check_start`).
    """
    if not run.checkable:
        return
    run.estimate, run.starts = several_starts(run.records, run.torque_constant, run.quasi,
                                              run.progress, run.estimate, run.criterion,
                                              run.evidence)
    if run.starts is not None and run.starts['chosen'] != 'default':
        run.errors = simulation_errors(run.estimate, run.records, run.torque_constant,
                                       quasi_static=run.quasi)
    run.found, run.estimate, run.discovery_info, check = check_start(
        run.records, run.torque_constant, run.quasi, run.discover, run.vocabulary,
        run.progress, run.estimate, None, None, run.criterion, run.evidence)
    if check['chosen'] == 'first start':
        run.start_check = None if not check['doubts'] else check
    else:
        run.start_check = check
        run.errors = simulation_errors(run.estimate, run.records, run.torque_constant,
                                       quasi_static=run.quasi)
        run.warnings += _discovery_time_warnings(run.found, run.discovery_info, run.progress)


def _discovery(run: _Run) -> None:
    """Stage 5: effect discovery from the base, within the time budget, unless hopeless."""
    base_worst = max([value for value in run.errors.values() if value is not None] or [np.inf])
    if run.criterion != 'speed':
        # The base model's position may be far off for lack of the very effect (a load) the
        # loop is there to find: the loop gets its full time, the final model is checked.
        base_worst = min(base_worst, NO_FIT_NRMSE_PCT)
    if run.start_check is not None and run.start_check['chosen'] != 'first start':
        return  # the second start ran its own discovery
    if run.discover and not base_worst <= HOPELESS_NRMSE_PCT:
        # Worse than the signals' mean: a sign or unit error, which no effect explains (and
        # every candidate fit would diverge slowly); refused later without the loop.
        run.discovery_info = {'skipped': f'the base model does not fit ({base_worst:.3g} % '
                                         'simulation error)'}
    elif run.discover:
        progress = run.progress
        deadline = progress.deadline
        if base_worst > NO_FIT_NRMSE_PCT:
            # A base model this far off is rarely rescued by one effect: a short look only, so
            # that a record that cannot be fitted is refused in seconds.
            progress.deadline = min(deadline if deadline is not None else np.inf,
                                    progress.now() + HOPELESS_DISCOVERY_S)
        try:
            run.found, run.discovery_info = run_discovery(
                run.records, run.torque_constant, run.estimator, run.vocabulary, progress,
                run.initial_state, run.quasi, run.estimate, run.criterion)
        finally:
            progress.deadline = deadline
        run.warnings += _discovery_time_warnings(run.found, run.discovery_info, progress)


def _discovery_time_warnings(found, discovery_info, progress):
    """Say when the time budget ran out during discovery, or before it had a result."""
    if found is not None and found.out_of_time:
        return [f'the time budget ({progress.max_time_s:g} s) ran out during effect discovery: '
                'the result is the best structure so far'
                + (' fitted on the training parts only (first '
                   f'{100 * (1 - found.holdout_fraction):.0f} % of the motion)'
                   if found.estimate is found.final.estimate else '')
                + '; give more time with --max-time']
    if found is None and discovery_info and 'time budget' in discovery_info.get('skipped', ''):
        return [discovery_info['skipped']]
    return []


def _check_final_start(run: _Run) -> None:
    """Stage 6: when the base looked sound, check where discovery led; say what was found."""
    if run.checkable and run.start_check is None:
        found = run.found
        run.found, run.estimate, run.discovery_info, run.start_check = check_start(
            run.records, run.torque_constant, run.quasi, run.discover, run.vocabulary,
            run.progress, run.estimate, run.found, run.discovery_info, run.criterion,
            run.evidence)
        if run.found is not found:  # the second start's own loop
            run.warnings += _discovery_time_warnings(run.found, run.discovery_info,
                                                     run.progress)
    run.start_check = with_starts(run.start_check, run.starts)
    for warning in (start_warning(run.start_check), ambiguity_warning(run.starts)):
        if warning is not None:
            run.warnings.append(warning)


def _final_fit(run: _Run) -> None:
    """Stage 7: the final fit (the loop's, else the base); refused when it does not fit."""
    run.final, run.terms, run.fitted_records = run.estimate, (), list(run.records)
    if run.found is not None:
        run.final, run.terms, run.fitted_records = (run.found.estimate, run.found.terms,
                                                    run.found.records)
    in_sample = simulation_errors(run.final, run.fitted_records, run.torque_constant,
                                  run.terms, run.quasi)
    worst = max(value for value in in_sample.values() if value is not None) \
        if any(value is not None for value in in_sample.values()) else float('inf')
    if not np.isfinite(worst) or worst > NO_FIT_NRMSE_PCT:
        raise FitError(
            f'the identified model does not reproduce the data (simulation error {worst:.3g} % '
            'of the signal spread). Check that the columns are what their names say (units, '
            'signs) and that the data come from a DC motor drive.')


def _uncertainty(run: _Run) -> None:
    """Stage 8: data-based standard errors; La by its upper bound under the quasi-static model."""
    final = with_robust_stderr(run.final)
    stderr_model = dict(final.info.get('stderr_model', final.stderr))
    if run.quasi and run.full_la is not None:
        dt = run.records[0].sample_period_s
        final, run.upper_bounds = with_la_bound(final, *run.full_la, dt)
        stderr_model = dict(final.info['stderr_model'])
        run.not_identifiable['La'] = la_reason(*run.full_la, dt, run.upper_bounds['La'])
    run.final = final
    run.names = MECHANICAL_NAMES if run.mechanical_only else PARAMETER_NAMES + DERIVED_NAMES
    run.parameters = {name: float(final.parameters[name]) for name in run.names}
    run.stderr = {name: float(final.stderr.get(name, np.nan)) for name in run.names}
    run.stderr_model = {name: float(stderr_model.get(name, np.nan)) for name in run.names}
    for name in run.upper_bounds:
        run.stderr[name] = run.stderr_model[name] = float('nan')


def _identifiability(run: _Run) -> None:
    """
    Stage 9: what the data do not determine, and the answer against the data's own scales.

    One direction only, parameters at a bound, loose ones; plausibility and unit warnings;
    refused when nothing useful is left.
    """
    final, not_identifiable = run.final, run.not_identifiable
    run.bound = at_bound(final, run.fitted_records, run.torque_constant)
    if run.excitation.one_direction:
        note = one_direction_note(run.excitation, run.parameters['Mc'])
        not_identifiable['Mc'] = note
        not_identifiable['load_torque'] = note
        run.combined['friction_torque_Nm'] = {
            'value': run.parameters['Mc'], 'stderr': run.stderr['Mc'],
            'direction': run.excitation.direction, 'of': ['Mc', 'load_torque']}
        run.bound.pop('Mc', None)
    for name, reason in run.bound.items():
        not_identifiable[name] = reason
        run.stderr[name] = float('nan')
    checked = [name for name in run.names if name not in not_identifiable and name not in
               run.upper_bounds and name not in ('Ka',)]
    not_identifiable.update(loose(final, [name for name in checked if name in POSITIVE_NAMES
                                          or name == 'Ta']))
    # Orders of magnitude against the data's own scales: refused there, else warnings (the
    # parameters already said to be at a bound are not repeated).
    run.warnings += [text for text in check_plausibility(final.parameters, final.stderr,
                                                         run.records, run.torque_constant)
                     if not any(text.startswith(f'{name} = ') for name in not_identifiable)]
    run.warnings += unit_warnings(final.parameters, run.records, run.mechanical_only)
    if not useful(list(run.parameters), not_identifiable, run.mechanical_only):
        raise NotIdentifiableError(
            'nothing useful is identifiable from these data: '
            + '; '.join(f'{name}: {reason}' for name, reason in not_identifiable.items())
            + '. Use a richer excitation (faster changes for La, larger speed changes for J) '
            'or a longer record.')


def _fit_warnings(run: _Run) -> None:
    """Stage 10: the final fit's warnings, and how far the effects moved the base."""
    outputs = output_channels(run.mechanical_only)
    run.warnings += _result_warnings(run.final, run.fitted_records, run.terms, outputs,
                                     run.torque_constant, run.quasi,
                                     list(run.bound) + list(run.upper_bounds), run.initial_state)
    if run.found is not None and run.found.effects:
        shift = _structure_shift(run.found.base_estimate, run.parameters, run.stderr)
        if shift:
            run.warnings.append(shift)
    run.warnings += between_record_warnings(run.final.info.get('between_records'))


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
    misfit = misfit_warning(estimate, records, outputs, rms, torque_constant)
    if misfit:
        warnings.append(misfit)
    return warnings


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


def _heldout(run: _Run) -> None:
    """
    Stage 11: the per-record errors, on the whole records and held out, and their warnings.

    Both come from :mod:`~dcmotor_id.identification.heldout`.
    """
    run.errors_detail = record_errors(run.records, run.estimate, run.final, run.found,
                                      run.torque_constant, run.terms, run.quasi)
    run.warnings += heldout_warnings(run.errors_detail)


def _result(run: _Run) -> IdentificationResult:
    """Stage 12: the result (the JSON contract's values and the objects behind them)."""
    found, final, records = run.found, run.final, run.records
    return IdentificationResult(
        parameters=run.parameters,
        stderr=run.stderr,
        method=final.method,
        effects=found.effects_json() if found is not None else [],
        error_before=found.error_before if found is not None else run.errors,
        error_after=found.error_after if found is not None else dict(run.errors),
        unexplained=bool(found.unexplained) if found is not None else False,
        mode='mechanical' if run.mechanical_only else 'full',
        torque_constant=run.torque_constant,
        initial_states=[list(state) for state in final.initial_states],
        noise_std=final.info.get('noise_std', {}),
        sample_period_s=records[0].sample_period_s,
        n_samples=int(sum(len(rec) for rec in records)),
        sources=[rec.source for rec in records],
        units={name: UNITS[name] for name in run.names},
        discover=bool(run.discover),
        discovery=run.discovery_info,
        stderr_model=run.stderr_model,
        uncertainty_method=final.info.get('uncertainty_method',
                                          f"the {final.method} estimator's own"),
        not_identifiable=run.not_identifiable,
        warnings=run.warnings,
        errors=run.errors_detail,
        combined=run.combined,
        upper_bounds=run.upper_bounds,
        initial_state=run.initial_state,
        elapsed_s=run.progress.elapsed(),
        start_check=run.start_check,
        operating_range=operating_range(records),
        estimate=final,
        input_records=list(records),
        discovery_result=found,
        criterion=run.criterion,
        between_records=final.info.get('between_records'),
        evidence=run.evidence if run.criterion != 'speed' else None,  # the position error's
    )
