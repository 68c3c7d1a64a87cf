"""
From prepared records to the identification result (the CLI's and the node's common path).

:func:`identify` checks its arguments and runs the pipeline
(:mod:`~dcmotor_id.identification.pipeline`) within a time budget.  One run is a list of
stages, one module each, every stage a function from the run's frozen state
(:mod:`~dcmotor_id.identification.pipeline.state`: the inputs, the fit, the answer) to a new
one, in this order (:mod:`~dcmotor_id.identification.pipeline.run`):

1. prepare: held samples restored, coarse channels named, data that do not move refused
   (:mod:`~dcmotor_id.identification.pipeline.prepare`; records are made ready before, by
   :func:`~dcmotor_id.identification.prepare.prepare_records`); a drive at an amplifier's
   current limit takes its own path (:mod:`~dcmotor_id.identification.pipeline.current_limited`);
2. base fit: the estimator named by ``--method`` on all data, non-physical values refused
   (:mod:`~dcmotor_id.identification.pipeline.base_fit`);
3. armature: La below what the data resolve makes the quasi-static armature the model
   (:mod:`~dcmotor_id.identification.pipeline.armature`);
4. start check: the base against model-free evidence, further starts and a second start when
   doubted (:mod:`~dcmotor_id.identification.pipeline.start_check`);
5. discovery: the effect discovery loop (:mod:`~dcmotor_id.identification.pipeline.discovery`);
6. final start check: where discovery led, checked the same way;
7. final fit: refused when it does not reproduce the data
   (:mod:`~dcmotor_id.identification.pipeline.final_fit`);
8. uncertainty: data-based standard errors, La by its upper bound (same module);
9. identifiability: what the data do not determine, plausibility and units
   (:mod:`~dcmotor_id.identification.pipeline.identifiability`);
10. warnings: correlations, initial states, misfit, how far the effects moved the base
    (:mod:`~dcmotor_id.identification.pipeline.fit_warnings`);
11. held-out errors: per record, whole and held out
    (:mod:`~dcmotor_id.identification.pipeline.heldout`);
12. result: an :class:`~dcmotor_id.identification.result.IdentificationResult`, whose
    :meth:`~dcmotor_id.identification.result.IdentificationResult.as_dict` is the JSON layout
    of the CLI contract (:mod:`~dcmotor_id.identification.pipeline.result`).

Around the run stands the floor (:mod:`~dcmotor_id.identification.pipeline.floor`): before
it, the records are split into their tests
(:mod:`~dcmotor_id.identification.pipeline.segments`), the model-free regression of both
equations is computed and a command that did not reach the motor at a record's start is cut;
after it, a failed fit falls back to the regression, and a fit that predicts the held-out part
worse than the regression gives way to it, with a warning that says why.

Records of voltage and speed without a current take their own path
(:mod:`~dcmotor_id.identification.pipeline.voltage_speed`): the voltage-to-speed model
``kS, kV, kA`` in WPILib's convention, Ra, CPhi, J, b, Mc not separable.

On the position the run is made with the position error as white noise and, when that
disagrees with model-free evidence, as a drift (AR(1)); the closer result is kept
(:mod:`~dcmotor_id.identification.pipeline.position_error`).  When the fit on the position
fails under ``--criterion auto``, the pipeline runs again on the speed.

The names callers import from here stay importable from here (``__all__``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence, TYPE_CHECKING

from dcmotor_id.core.blas import single_threaded
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.estimators.base import Estimator
from dcmotor_id.identification.estimators.voltage_speed import one_magnitude
from dcmotor_id.identification.pipeline.base_fit import METHODS
from dcmotor_id.identification.pipeline.current_limited import JACKKNIFE_GROUPS
from dcmotor_id.identification.pipeline.discovery import (HOPELESS_DISCOVERY_S,
                                                          HOPELESS_NRMSE_PCT,
                                                          supports_discovery)
from dcmotor_id.identification.pipeline.fit_outcome import NO_FIT_NRMSE_PCT, simulation_errors
from dcmotor_id.identification.pipeline.floor import identify_above_floor
from dcmotor_id.identification.pipeline.heldout import HELDOUT_CHOICE, record_errors
from dcmotor_id.identification.pipeline.segments import split_tests
from dcmotor_id.identification.pipeline.state import Request
from dcmotor_id.identification.pipeline.voltage_speed import identify_voltage_speed
from dcmotor_id.identification.prepare import (check_excitation, common_period,
                                               is_voltage_speed, one_level_reason, PERIOD_RTOL,
                                               prepare_records, SETTLE_SAMPLES,
                                               single_current_level)
from dcmotor_id.identification.result import IdentificationResult
from dcmotor_id.identification.structure_uncertainty import bootstrapped

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect

__all__ = ['check_excitation', 'common_period', 'DEFAULT_MAX_TIME_S', 'HELDOUT_CHOICE',
           'HOPELESS_DISCOVERY_S', 'HOPELESS_NRMSE_PCT', 'IdentificationResult', 'identify',
           'INITIAL_STATES', 'JACKKNIFE_GROUPS', 'METHODS', 'NO_FIT_NRMSE_PCT',
           'one_level_reason', 'PERIOD_RTOL', 'prepare_records', 'record_errors',
           'SETTLE_SAMPLES', 'simulation_errors', 'single_current_level', 'supports_discovery']

#: Default time budget [s] (``--max-time``).
DEFAULT_MAX_TIME_S = 120.0
#: Choices of ``--initial-state``.
INITIAL_STATES = ('estimate', 'measured')


@single_threaded
def identify(records: Sequence[Record], method: str = 'refined',
             torque_constant: float | None = None, discover: bool = True,
             estimator: Estimator | None = None,
             vocabulary: Sequence[type[Effect]] | None = None, *,
             max_time_s: float | None = DEFAULT_MAX_TIME_S, progress: Progress | None = None,
             initial_state: str = 'estimate', criterion: str = 'auto',
             structure_bootstrap: int = 0) -> IdentificationResult:
    """
    Identify the motor from prepared records.

    Parameters
    ----------
    records : list of Record
        From :func:`~dcmotor_id.identification.prepare.prepare_records` (here if speed lacks).
    method : str
        ``refined`` (default) or ``paper``.
    torque_constant : float, optional
        Mechanical-only mode with this torque constant [N m/A]; without both: ``kS, kV, kA``.
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
        ``auto`` (default), ``speed``, ``position`` or ``both``: the channels compared, JSON
        ``criterion`` (:func:`~dcmotor_id.identification.error_model.criterion.resolve_criterion`).
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
    records = _checked(records, torque_constant, method, initial_state)
    budget = progress if progress is not None else Progress(max_time_s)
    request = Request(records, method, torque_constant, discover, estimator, vocabulary,
                      budget, initial_state)
    result = _run(request, criterion, max_time_s, progress, structure_bootstrap)
    return _with_notes(records, result)


def _run(request: Request, criterion: str, max_time_s: float | None,
         progress: Progress | None, structure_bootstrap: int) -> IdentificationResult:
    """Run the voltage-speed tests, the structure bootstrap or the pipeline above the floor."""
    if is_voltage_speed(request.records, request.torque_constant):  # no current: kS, kV, kA
        return _voltage_speed_tests(request.records, request.discover, request.progress,
                                    structure_bootstrap)
    if structure_bootstrap:
        return _bootstrapped(request, criterion, max_time_s, progress, structure_bootstrap)
    return identify_above_floor(criterion, request)


def _with_notes(records: Sequence[Record], result: IdentificationResult) -> IdentificationResult:
    """Return the result with what the preparation changed in the records said first."""
    notes = [note for rec in records for note in rec.notes if note not in result.warnings]
    return replace(result, warnings=notes + list(result.warnings)) if notes else result


def _voltage_speed_tests(records: Sequence[Record], discover: bool, budget: Progress,
                         structure_bootstrap: int) -> IdentificationResult:
    """Identify kS, kV, kA from the tests a segment column marks (the records as they are else)."""
    tests = split_tests(records)
    result = identify_voltage_speed(list(tests.records), discover, budget, structure_bootstrap)
    said = [text for text in (tests.note, one_magnitude(tests.records)) if text]
    return replace(result, warnings=said + result.warnings) if said else result


def _bootstrapped(request: Request, criterion: str, max_time_s: float | None,
                  progress: Progress | None, resamples: int) -> IdentificationResult:
    """Run :func:`identify` under the structure bootstrap with the request's arguments."""
    return bootstrapped(identify, request.records, resamples, method=request.method,
                        torque_constant=request.torque_constant, discover=request.discover,
                        estimator=request.estimator, vocabulary=request.vocabulary,
                        max_time_s=max_time_s, progress=progress,
                        initial_state=request.initial_state, criterion=criterion)


def _checked(records: Sequence[Record], torque_constant: float | None, method: str,
             initial_state: str) -> Sequence[Record]:
    """
    Return the records, prepared if any lacks a speed; refuse an unknown method or start.

    A position-only record as read gets its speed from
    :func:`~dcmotor_id.identification.prepare.prepare_records` (the documented first step).
    """
    if method not in METHODS:
        raise InputDataError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    if initial_state not in INITIAL_STATES:
        raise InputDataError(f'initial state must be one of {", ".join(INITIAL_STATES)}, not '
                             f'{initial_state!r}')
    if any(rec.speed is None for rec in records):
        return prepare_records(records, torque_constant)
    return records
