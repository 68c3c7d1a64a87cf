"""
The discovery loop (:class:`DiscoveryLoop`): fit, analyse, screen, refit, judge, repeat.

Each step is a function of the frozen
:class:`~dcmotor_id.identification.discovery.state.LoopState` that returns what it found:
:func:`base_fit` the loop it taught and the base, :func:`one_round` a
:class:`~dcmotor_id.identification.discovery.structure.Round`, :func:`search_rounds` the
:class:`Search`, :func:`refit_all_data` the all-data fits.  What a round does on its model
(the screen's sensitivities, a candidate's refit, the residual analysis) is a
:class:`RoundSteps`: :data:`OUTPUT_ERROR` here, the voltage-to-speed model's in
:mod:`~dcmotor_id.identification.discovery.voltage_speed`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence, TYPE_CHECKING

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import parameter_names
from dcmotor_id.core.progress import TimeBudgetExceeded
from dcmotor_id.identification.discovery.analysis import (analyse, material, misfit, negligible,
                                                          stops_before_judging)
from dcmotor_id.identification.discovery.judging import decide, never_worse, round_report, score
from dcmotor_id.identification.discovery.refitting import (anchor_fit, base_unsound, fit_structure,
                                                           judging_reference, refit_all,
                                                           refit_candidate,
                                                           speed_base_on_the_position, taught)
from dcmotor_id.identification.discovery.result import DiscoveryResult
from dcmotor_id.identification.discovery.screening import (OUTPUT_ERROR_SCREEN, Screen,
                                                           screen_absent, SCREEN_SHARE, SCREEN_TOP,
                                                           SCREEN_TOP_MISFIT)
from dcmotor_id.identification.discovery.state import CROSS_VALIDATED, LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Fit, Round, Structure

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate


@dataclass(frozen=True)
class RoundSteps:
    """
    What a search round does on its model: screen, refit a candidate, analyse, name.

    Attributes
    ----------
    screen : Screen
        The screen's sensitivities and term responses
        (:class:`~dcmotor_id.identification.discovery.screening.Screen`).
    refit : callable
        ``(loop, current, candidate) -> candidate``: the candidate refitted on the training
        parts, with its problem (not yet scored); its ``fit`` None when the refit failed.
    analyse : callable
        ``(loop, fit) -> analysis``: the residual analysis after an effect is added (an
        empty one: the model has none, and the search runs until no candidate earns its
        place).
    describe : callable, optional
        ``candidate -> dict``: the added effect as the result names it (default
        :meth:`~dcmotor_id.identification.discovery.structure.Candidate.describe`).
    label : str
        The progress stage's name.
    refitted_anyway : tuple of int
        How many of the best screened candidates are refitted whatever their screen, when
        the model fits and when it misfits far above the noise
        (:func:`~dcmotor_id.identification.discovery.analysis.misfit`): the linearisation
        may miss a nonlinear effect.  The others are refitted when the screen explains
        :data:`~dcmotor_id.identification.discovery.screening.SCREEN_SHARE` of the least
        gain.

    """

    screen: Screen
    refit: Callable[[LoopState, Fit, Candidate], Candidate]
    analyse: Callable[[LoopState, Fit], dict]
    describe: Callable[[Candidate], dict] | None = None
    label: str = 'discovery'
    refitted_anyway: tuple[int, int] = (SCREEN_TOP, SCREEN_TOP_MISFIT)


#: The steps of the output-error model (current and speed, or the mechanical mode's speed).
OUTPUT_ERROR = RoundSteps(OUTPUT_ERROR_SCREEN, refit_candidate, analyse)


@dataclass
class Search:
    """Where the search stopped: the structure, the rounds' reports, its last analysis, why."""

    current: Fit
    analysis: dict
    steps: list = field(default_factory=list)
    reason: str = 'explained'
    out_of_time: bool = False


class DiscoveryLoop(LoopState):
    """
    Residual analysis and effect discovery on a set of prepared records.

    The parameters are those of :class:`~dcmotor_id.identification.discovery.state.LoopState`
    (records, torque constant, vocabulary, hold-out share, least gain, ...), frozen.  A round
    screens every absent effect (:mod:`~dcmotor_id.identification.discovery.screening`),
    refits the promising ones (:mod:`~dcmotor_id.identification.discovery.refitting`) and
    judges them on the held-out parts (:mod:`~dcmotor_id.identification.discovery.judging`).
    """

    def run(self, estimate: Estimate | None = None,
            structure: Structure | None = None) -> DiscoveryResult:
        """
        Run the loop, refit the base and final structures on all the data; return it.

        ``estimate``, the base model already fitted on all of the records (same model: mode,
        quasi-static armature), warm-starts the base fit on the training parts and is reused
        when no effect is added.  ``structure``: effects the base holds from the start (the
        model-free evidence's, :mod:`~dcmotor_id.identification.pipeline.second_start`), their
        coefficients started from ``estimate``'s values.
        """
        return run_loop(self, estimate, structure)


def run_loop(settings: LoopState, estimate: Estimate | None = None,
             structure: Structure | None = None) -> DiscoveryResult:
    """Run the loop from these settings (:meth:`DiscoveryLoop.run`); return what it found."""
    loop, base = base_fit(settings, estimate, structure or Structure())
    analysis_before = analyse(loop, base)
    search = search_rounds(loop, base, analysis_before)
    current, reason = search.current, search.reason
    if loop.acceptance not in CROSS_VALIDATED:
        # Under blocked cross-validation every effect passed its test against the structure
        # before it on every sample held out; the held-out end alone does not undo it.
        current, reason = never_worse(base, current, reason, judging_reference(base))
    records, terms, estimate, base_estimate, out_of_time = refit_all_data(
        loop, base, current, estimate, search.out_of_time)
    analysis = search.analysis
    return DiscoveryResult(
        holdout_fraction=loop.holdout_fraction, min_gain=loop.min_gain,
        outputs=loop.outputs, torque_constant=loop.torque_constant,
        source_records=list(loop.records), base=base, final=current, steps=search.steps,
        analysis_before=analysis_before, analysis_after=analysis, reason=reason,
        unexplained=material(loop, analysis), records=records, terms=terms,
        estimate=estimate, effects=current.structure.effects(estimate.parameters),
        base_estimate=base_estimate, error_before=base.errors(loop.error_channels),
        error_after=current.errors(loop.error_channels), out_of_time=out_of_time,
        quasi_static=loop.quasi_static, criterion=loop.criterion)


def base_fit(loop: LoopState, estimate: Estimate | None,
             structure: Structure) -> tuple[LoopState, Fit]:
    """
    Fit the base structure on the training parts (from ``estimate`` if given); the anchor.

    Returns the loop with what the base taught it
    (:func:`~dcmotor_id.identification.discovery.refitting.taught`, the pinned initial states,
    the anchor) and the base.  On the position, a base model fit that fails or lands far from
    the model-free evidence (:func:`~dcmotor_id.identification.discovery.refitting.base_unsound`)
    gives way to the base fitted on the speed (:func:`speed_base_on_the_position`); the
    candidates are then judged against that base refitted on the position as they are
    (:func:`~dcmotor_id.identification.discovery.refitting.null_refit`).
    """
    if loop.progress is not None:
        loop.progress.set_stage('discovery: base model on the training parts')
    on_the_position = loop.criterion != 'speed' and not len(structure)
    try:
        base = _fit_base(loop, estimate, structure)
    except DcMotorIdError:
        fallback = speed_base_on_the_position(loop) if on_the_position else None
        if fallback is None:
            raise
        return fallback
    loop = taught(loop, base)
    if on_the_position and base_unsound(loop, base):
        fallback = speed_base_on_the_position(loop)
        if fallback is not None:
            return fallback
    if base.estimate.info.get('initial_state') == 'measured':
        # The position criterion pinned the base's initial states (its fitted start moved
        # to absorb a misfit): the candidates start pinned too, without a second fit.
        loop = replace(loop, initial_state='measured')
    return replace(loop, anchor=anchor_fit(loop)), base


def _fit_base(loop: LoopState, estimate: Estimate | None, structure: Structure) -> Fit:
    """Fit the base structure on the training parts, from ``estimate`` if given."""
    if estimate is None:
        return fit_structure(loop, structure)
    start = {name: float(estimate.parameters[name])
             for name in parameter_names(loop.mechanical_only)
             if name in estimate.parameters}
    return fit_structure(loop, structure, start=start, initial=dict(estimate.parameters),
                         initial_states=estimate.initial_states)


def search_rounds(loop: LoopState, base: Fit, analysis: dict,
                  steps: RoundSteps = OUTPUT_ERROR) -> Search:
    """
    Add effects round by round until the residual is white or nothing helps.

    An empty ``analysis`` (a model without a residual analysis, ``steps.analyse``) never
    stops the search: it runs until no candidate earns its place or the most effects.
    """
    search = Search(base, analysis)
    try:
        while True:
            if stops_before_judging(loop, search.current, search.analysis):
                search.reason = 'the residual is white' if not negligible(
                    search.analysis) else 'the model reproduces the data exactly'
                break
            if len(search.current.structure) >= loop.max_effects:
                search.reason = f'stopped at {loop.max_effects} effects'
                break
            step = one_round(loop, search.current, search.analysis, steps)
            search.steps.append(step.report)
            if step.chosen is None:
                search.reason = 'no candidate lowers the held-out error enough'
                break
            search.current = step.chosen.fitted
            search.analysis = steps.analyse(loop, search.current)
    except TimeBudgetExceeded:
        search.out_of_time = True
        search.reason = 'the time budget ran out: the best structure so far is kept'
    return search


def refit_all_data(loop: LoopState, base: Fit, current: Fit, estimate: Estimate | None,
                   out_of_time: bool) -> tuple[list, tuple, Estimate, Estimate, bool]:
    """
    Refit the final and the base structure on all the data.

    Returns the final structure's records, terms and estimate, the base estimate and
    whether the time budget ran out (then the training-part fits are what there is).
    """
    try:
        if out_of_time:
            raise TimeBudgetExceeded('no time left for the all-data refit')
        if loop.progress is not None:
            loop.progress.set_stage('discovery: final refit on all the data')
        if len(current.structure) == 0 and estimate is not None:
            # The base model on all of the data is the one given: no refit.
            return list(loop.records), (), estimate, estimate, out_of_time
        records, terms, estimate = refit_all(loop, current)
        base_estimate = _base_on_all_data(loop, base) if current is not base else estimate
        return records, terms, estimate, base_estimate, out_of_time
    except TimeBudgetExceeded:
        # The training-part fits are what there is: report them, said so in the result.
        return (current.records, current.terms, current.estimate, base.estimate, True)


def _base_on_all_data(loop: LoopState, base: Fit) -> Estimate:
    """Refit the base structure on all the data; its training fit when it has none."""
    if 'base_from' in base.estimate.info:
        return base.estimate  # the speed fit: the base has no fit on the position
    try:
        return refit_all(loop, base)[2]
    except DcMotorIdError:
        # A base that lacks the effect found may have no fit on the whole position
        # (:func:`speed_base_on_the_position`): the comparison uses its training fit.
        return base.estimate


def one_round(loop: LoopState, current: Fit, analysis: dict,
              steps: RoundSteps = OUTPUT_ERROR) -> Round:
    """
    One search round: screen every absent effect, refit the promising, choose.

    The candidates are screened and refitted from ``current`` (by ``steps``) and judged
    against :func:`~dcmotor_id.identification.discovery.refitting.judging_reference`: the
    current structure refitted as they are when ``current`` is not a fit of the loop's
    criterion.
    """
    reference = judging_reference(current)
    scored = refit_promising(loop, current, screen_absent(loop, current, steps.screen),
                             reference, steps)
    order = {cls.name: position for position, cls in enumerate(loop.candidates)}
    refitted = sorted((candidate for candidate in scored if candidate.fit is not None),
                      key=lambda candidate: candidate.fitted.heldout_cost)
    screened_out = sorted((candidate for candidate in scored if candidate.fit is None),
                          key=lambda candidate: -candidate.screen_explained)
    chosen, equivalent, refitted = decide(loop, reference, refitted, order)
    results = refitted + screened_out
    report = round_report(loop, reference, analysis, results, chosen, equivalent)
    if reference is not current:
        report['judged_against'] = 'the base refitted as the candidates are (no effect)'
    if chosen is not None and steps.describe is not None:  # the model names its effects
        report['added'] = steps.describe(chosen)
        report['equivalent'] = [steps.describe(candidate) for candidate in equivalent]
    return Round(results, chosen, report)


def refit_promising(loop: LoopState, current: Fit, screened: list[Candidate],
                    reference: Fit | None = None,
                    steps: RoundSteps = OUTPUT_ERROR) -> list[Candidate]:
    """
    Refit and score the candidates the screen supports, and the best few anyway.

    The screen is a linearisation: a strongly nonlinear effect may look smaller than it
    is.  ``screened`` is in the order of the screen, best first; so is the list returned.
    Each refit (from ``current``, by ``steps.refit``) is scored against ``reference``
    (default ``current``).
    """
    threshold = SCREEN_SHARE * loop.min_gain
    top = steps.refitted_anyway[1] if misfit(loop, current) else steps.refitted_anyway[0]
    scored = []
    for rank, candidate in enumerate(screened):
        if rank < top or candidate.screen_explained >= threshold:
            if loop.progress is not None:
                loop.progress.set_stage(f'{steps.label}: candidate {candidate.name}')
            candidate = score(loop, reference or current,
                              steps.refit(loop, current, candidate))
        scored.append(candidate)
    return scored


def discover(records: Sequence[Record], torque_constant: float | None = None,
             **options: Any) -> DiscoveryResult:
    """Run the discovery loop on prepared records; return a :class:`DiscoveryResult`."""
    return DiscoveryLoop(records, torque_constant, **options).run()
