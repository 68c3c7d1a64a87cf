"""The discovery loop (:class:`DiscoveryLoop`): fit, analyse, screen, refit, judge, repeat."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence, TYPE_CHECKING

from dcmotor_id.core.model import parameter_names
from dcmotor_id.core.progress import TimeBudgetExceeded

from dcmotor_id.identification.discovery.analysis import (analyse, explained, material, misfit,
                                                          negligible)
from dcmotor_id.identification.discovery.judging import (candidate_report, choose, never_worse,
                                                         score, unearned)
from dcmotor_id.identification.discovery.refitting import (anchor_fit, fit_structure, refit_all,
                                                           refit_candidate)
from dcmotor_id.identification.discovery.result import DiscoveryResult
from dcmotor_id.identification.discovery.screening import (base_sensitivities, projector,
                                                           screen_candidate, SCREEN_SHARE,
                                                           SCREEN_TOP, SCREEN_TOP_MISFIT)
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Fit, Round, Structure

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate


class DiscoveryLoop(LoopState):
    """
    Residual analysis and effect discovery on a set of prepared records.

    The parameters are those of :class:`~dcmotor_id.identification.discovery.state.LoopState`
    (records, torque constant, vocabulary, hold-out share, least gain, ...).  A round
    screens every absent effect (:mod:`~dcmotor_id.identification.discovery.screening`),
    refits the promising ones (:mod:`~dcmotor_id.identification.discovery.refitting`) and
    judges them on the held-out parts (:mod:`~dcmotor_id.identification.discovery.judging`).
    """

    def run(self, estimate: Estimate | None = None) -> DiscoveryResult:
        """
        Run the loop, refit the base and final structures on all the data; return it.

        ``estimate``, the base model already fitted on all of the records (same model: mode,
        quasi-static armature), warm-starts the base fit on the training parts and is reused
        when no effect is added.
        """
        if self.progress is not None:
            self.progress.set_stage('discovery: base model on the training parts')
        if estimate is None:
            base = fit_structure(self, Structure())
        else:
            start = {name: float(estimate.parameters[name])
                     for name in parameter_names(self.mechanical_only)
                     if name in estimate.parameters}
            base = fit_structure(self, Structure(), start=start,
                                 initial_states=estimate.initial_states)
        current = base
        if base.estimate.info.get('initial_state') == 'measured':
            # The position criterion pinned the base's initial states (its fitted start moved
            # to absorb a misfit): the candidates start pinned too, without a second fit.
            self.initial_state = 'measured'
        self.anchor = anchor_fit(self)
        steps = []
        analysis_before = analyse(self, base)
        analysis = analysis_before
        reason = 'explained'
        out_of_time = False
        try:
            while True:
                if explained(self, analysis):
                    reason = 'the residual is white' if not negligible(analysis) else \
                        'the model reproduces the data exactly'
                    break
                if len(current.structure) >= self.max_effects:
                    reason = f'stopped at {self.max_effects} effects'
                    break
                step = self._round(current, analysis)
                steps.append(step.report)
                if step.chosen is None:
                    reason = 'no candidate lowers the held-out error enough'
                    break
                current = step.chosen.fitted
                analysis = analyse(self, current)
        except TimeBudgetExceeded:
            out_of_time = True
            reason = 'the time budget ran out: the best structure so far is kept'
        current, reason = never_worse(base, current, reason)
        try:
            if out_of_time:
                raise TimeBudgetExceeded('no time left for the all-data refit')
            if self.progress is not None:
                self.progress.set_stage('discovery: final refit on all the data')
            if len(current.structure) == 0 and estimate is not None:
                # The base model on all of the data is the one given: no refit.
                records, terms, base_estimate = list(self.records), (), estimate
            else:
                records, terms, estimate = refit_all(self, current)
                base_estimate = refit_all(self, base)[2] if len(current.structure) else estimate
        except TimeBudgetExceeded:
            # The training-part fits are what there is: report them, said so in the result.
            out_of_time = True
            records, terms = current.records, current.terms
            estimate, base_estimate = current.estimate, base.estimate
        return DiscoveryResult(
            holdout_fraction=self.holdout_fraction, min_gain=self.min_gain,
            outputs=self.outputs, torque_constant=self.torque_constant,
            source_records=list(self.records), base=base, final=current, steps=steps,
            analysis_before=analysis_before, analysis_after=analysis, reason=reason,
            unexplained=material(self, analysis), records=records, terms=terms,
            estimate=estimate, effects=current.structure.effects(estimate.parameters),
            base_estimate=base_estimate, error_before=base.errors(self.error_channels),
            error_after=current.errors(self.error_channels), out_of_time=out_of_time,
            quasi_static=self.quasi_static, criterion=self.criterion)

    def _round(self, current: Fit, analysis: dict) -> Round:
        """One search round: screen every absent effect, refit the promising, choose."""
        residual, matrix, nominal = base_sensitivities(self, current)
        q = projector(matrix)
        present = set(current.structure.names())
        screened = []
        for cls in self.candidates:
            if cls.name in present:
                continue
            candidate = screen_candidate(self, current, cls, residual, q, nominal)
            if candidate is not None:
                screened.append(candidate)
        # Refit the candidates the linearised screen supports, and the best few anyway (the
        # screen is a linearisation: a strongly nonlinear effect may look smaller than it is).
        screened.sort(key=lambda candidate: -candidate.screen_explained)
        threshold = SCREEN_SHARE * self.min_gain
        top = SCREEN_TOP_MISFIT if misfit(self, current) else SCREEN_TOP
        scored = []
        for rank, candidate in enumerate(screened):
            if rank < top or candidate.screen_explained >= threshold:
                if self.progress is not None:
                    self.progress.set_stage(f'discovery: candidate {candidate.name}')
                candidate = score(self, current, refit_candidate(self, current, candidate))
            scored.append(candidate)
        order = {cls.name: position for position, cls in enumerate(self.candidates)}
        refitted = sorted((candidate for candidate in scored if candidate.fit is not None),
                          key=lambda candidate: candidate.fitted.heldout_cost)
        screened_out = sorted((candidate for candidate in scored if candidate.fit is None),
                              key=lambda candidate: -candidate.screen_explained)
        chosen = None
        equivalent: list[Candidate] = []
        while chosen is None:
            admissible = [candidate for candidate in refitted if not candidate.problem]
            chosen, equivalent = choose(self, current, admissible, order)
            if chosen is None:
                break
            doubt = unearned(self, current, chosen)
            if doubt:
                # Rejected, and the next best is considered in its place.
                refitted = [replace(candidate, problem=doubt) if candidate is chosen
                            else candidate for candidate in refitted]
                chosen = None
        results = refitted + screened_out
        report: dict[str, Any] = {
            'error_before': current.errors(self.error_channels),
            'candidates': [candidate_report(candidate, analysis)
                           for candidate in results],
            'added': None,
        }
        if chosen is not None:
            report['added'] = chosen.describe()
            report['error_after'] = chosen.fitted.errors(self.error_channels)
            report['gain_pct'] = chosen.gain * 100.0
            report['equivalent'] = [candidate.describe() for candidate in equivalent]
        return Round(results, chosen, report)


def discover(records: Sequence[Record], torque_constant: float | None = None,
             **options: Any) -> DiscoveryResult:
    """Run the discovery loop on prepared records; return a :class:`DiscoveryResult`."""
    return DiscoveryLoop(records, torque_constant, **options).run()
