"""
The position error's model of a fit on the position, chosen against model-free evidence.

A fit that compares the position weights it first as the sensor's white noise
(:func:`~dcmotor_id.identification.criterion.position_error_model` ``white``): the position
sample by sample, which is what an open-loop validation of the model scores.  When the model
lacks a force (a friction that varies along a ball screw's travel), that fit can bend the
physical parameters to cancel the position's drift: a Coulomb friction pressed to zero, an
inertia far off.  The model-free regression on the data
(:func:`~dcmotor_id.identification.checks.start.regression_evidence`) sees that without a
model.  When the white fit's J, b or Mc lie more than :data:`AGREEMENT_FACTOR` from it, the
identification runs again with the ``adaptive`` error model (an AR(1) drift when the residual
misfits, :func:`~dcmotor_id.identification.criterion.position_ar`), and the result closer to
the evidence is kept.  JSON ``position_error`` says which and why.
"""

from __future__ import annotations

from contextvars import ContextVar
from dataclasses import replace
from typing import Any, Callable, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError, FitError, NotIdentifiableError
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.checks.start import FROM_RECORDS, known_evidence
from dcmotor_id.identification.criterion import position_error_model
from dcmotor_id.identification.multistart import once_per_identification

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.result import IdentificationResult

#: Largest ratio between a white fit's J, b or Mc and the model-free regression's before the
#: fit is taken to have bent them to a drift (the regression's own bias on a derived speed is
#: some ten per cent; a parameter pressed to a bound is far beyond it).
AGREEMENT_FACTOR = 1.5
#: Parameters compared with the regression.
COMPARED = ('J', 'b', 'Mc')
#: What the status line says of the runs after the first (the white one).
ADAPTIVE_RUN = 'second run, position error as a drift (AR(1))'
WHITE_RUN_RESUMED = 'white run resumed after its start check'
WHITE_RUN_AGAIN = 'white run again, to its end'


def disagreement(parameters: dict[str, float], evidence: dict[str, float] | None) -> float:
    """
    Largest ``|log(fitted / regression)|`` over J, b and Mc; 0 without evidence.

    A parameter at or below zero where the regression finds it positive is infinitely far;
    parameters the regression does not determine (not positive) are not compared.
    """
    if evidence is None:
        return 0.0
    worst = 0.0
    for name in COMPARED:
        seen, fitted = evidence.get(name, 0.0), parameters.get(name)
        if fitted is None or not seen > 0.0:
            continue
        worst = max(worst, abs(np.log(fitted / seen)) if fitted > 0.0 else np.inf)
    return float(worst)


class WhiteBaseDisagrees(Exception):
    """
    A white run left after its base fit: the base contradicts the regression.

    ``resume`` (when the run gave one) finishes the white run from where it was left, so
    that a white run needed after all does not fit its base and second start again.
    """

    def __init__(self, distance: float, parameters: dict[str, float],
                 resume: Callable[[], IdentificationResult] | None = None) -> None:
        super().__init__('the base fit on the white position error disagrees with the '
                         'model-free regression')
        self.distance = distance
        self.parameters = parameters
        self.resume = resume


# Whether the white run in progress is left as soon as its base fit disagrees (a context
# variable: the pipeline calls :func:`check_base` without knowing who runs it).
_CHECK_BASE: ContextVar[bool] = ContextVar('check_base', default=False)


def check_base(parameters: dict[str, float], records: Sequence[Record],
               torque_constant: float | None,
               resume: Callable[[], IdentificationResult] | None = None,
               evidence: dict[str, float] | None | str = FROM_RECORDS) -> None:
    """
    Leave a white run whose base fit (after the start check) contradicts the regression.

    Raises :class:`WhiteBaseDisagrees` inside :func:`with_chosen_error_model`'s first run
    only; elsewhere it does nothing.  The AR(1) run is then tried first, and the white run
    is finished only when that one disagrees too: by ``resume`` (the rest of the run from
    this point, its state kept) when given, else by running it again from the start.
    ``evidence``: the regression on ``records`` when the run has it
    (:func:`~dcmotor_id.identification.checks.start.known_evidence`).
    """
    if not _CHECK_BASE.get():
        return
    distance = disagreement(parameters, known_evidence(records, torque_constant, evidence))
    if distance > np.log(AGREEMENT_FACTOR):
        raise WhiteBaseDisagrees(distance, {name: float(parameters[name]) for name in COMPARED
                                            if name in parameters}, resume)


def with_chosen_error_model(run: Callable[[], IdentificationResult],
                            progress: Progress | None = None) -> IdentificationResult:
    """
    Run an identification on the position with the white error model, else the adaptive one.

    ``run`` runs the whole identification (under the error model in force).  The white run
    is left early when its base contradicts the regression (:func:`check_base`); the
    adaptive one runs when the white result disagrees with the regression by more than
    :data:`AGREEMENT_FACTOR`, or failed (a second run that fails or runs out of time leaves
    the white result).  Returns the result closer to the evidence, its ``position_error``
    filled in (and a warning when both disagree).  ``progress`` (the runs') names each run
    after the first on its status line (:meth:`~dcmotor_id.core.progress.Progress.set_run`).
    The runs fit the further starts of the base once
    (:func:`~dcmotor_id.identification.multistart.once_per_identification`).
    """
    runs = _Runs(run, progress)
    try:
        with once_per_identification():
            return _chosen(runs)
    finally:
        runs.name('')  # a later identification on the same Progress starts unnamed


def _chosen(runs: _Runs) -> IdentificationResult:
    """:func:`with_chosen_error_model`'s body."""
    white, left = _white_run(runs.run)
    if left is not None:
        return _adaptive_first(runs, left)
    if isinstance(white, DcMotorIdError):
        return replace(runs.adaptive(), position_error={'model': 'adaptive',
                                                        'white': f'failed: {white}'})
    evidence = _evidence(white)
    distance = disagreement(white.parameters, evidence)
    if distance <= np.log(AGREEMENT_FACTOR):
        return replace(white, position_error={
            'model': 'white', 'evidence': _compared(evidence),
            'agreement_factor': AGREEMENT_FACTOR, 'disagreement': _factors({'white': distance})})
    try:
        adaptive = runs.adaptive()
    except (FitError, NotIdentifiableError, TimeBudgetExceeded) as error:
        return replace(white, position_error={
            'model': 'white', 'evidence': _compared(evidence),
            'agreement_factor': AGREEMENT_FACTOR, 'disagreement': _factors({'white': distance}),
            'adaptive': f'failed: {error}'})
    return _closer(white, adaptive, evidence)


def _evidence(result: IdentificationResult) -> dict[str, float] | None:
    """Return the regression on a run's records: the run's own (``result.evidence``) if any."""
    return known_evidence(result.input_records, result.torque_constant,
                          FROM_RECORDS if result.evidence is None else result.evidence)


class _Runs:
    """The identification's runs after the first, each named on the status line."""

    def __init__(self, run: Callable[[], IdentificationResult],
                 progress: Progress | None) -> None:
        self.run, self.progress = run, progress

    def adaptive(self) -> IdentificationResult:
        """Run the identification again, the position error modelled as a drift (AR(1))."""
        self.name(ADAPTIVE_RUN)
        return self.run()

    def white(self, left: WhiteBaseDisagrees) -> tuple[
            IdentificationResult | DcMotorIdError, WhiteBaseDisagrees | None]:
        """Finish the white run that was left after its base (from there when it can)."""
        if left.resume is None:
            self.name(WHITE_RUN_AGAIN)
            return _white_run(self.run, check=False)
        self.name(WHITE_RUN_RESUMED)
        return _white_run(left.resume, check=False)

    def name(self, label: str) -> None:
        """Name the run that starts on the status line (empty: none)."""
        if self.progress is not None:
            self.progress.set_run(label)


def _white_run(run: Callable[[], IdentificationResult], check: bool = True) -> tuple[
        IdentificationResult | DcMotorIdError, WhiteBaseDisagrees | None]:
    """Run the white model, left early when its base disagrees; ``(result or error, left)``."""
    token = _CHECK_BASE.set(check)
    try:
        with position_error_model('white'):
            return run(), None
    except WhiteBaseDisagrees as left:
        return FitError('left after its base fit'), left
    except (FitError, NotIdentifiableError) as error:
        if 'time budget' in str(error):
            raise
        return error, None
    finally:
        _CHECK_BASE.reset(token)


def _adaptive_first(runs: _Runs, left: WhiteBaseDisagrees) -> IdentificationResult:
    """Run the adaptive model after a white base that disagrees; the full white run if needed."""
    left_note = ('left after its base fit (' + ', '.join(
        f'{name} {value:.4g}' for name, value in left.parameters.items())
        + f': {np.exp(left.distance):.3g}x from the regression)'
        if np.isfinite(left.distance) else 'left after its base fit (a parameter at zero)')
    try:
        adaptive = runs.adaptive()
    except (FitError, NotIdentifiableError, TimeBudgetExceeded):
        adaptive = None
    evidence = None
    if adaptive is not None:
        evidence = _evidence(adaptive)
        distance = disagreement(adaptive.parameters, evidence)
        if distance <= np.log(AGREEMENT_FACTOR):
            return replace(adaptive, position_error={
                'model': 'adaptive', 'evidence': _compared(evidence),
                'agreement_factor': AGREEMENT_FACTOR,
                'disagreement': _factors({'adaptive': distance}), 'white': left_note})
    white, _ = runs.white(left)
    if isinstance(white, DcMotorIdError):
        if adaptive is None:
            raise white
        return _closer(None, adaptive, evidence, f'failed: {white}')
    if adaptive is None:
        return replace(white, position_error={'model': 'white', 'adaptive': 'failed'})
    return _closer(white, adaptive, evidence)


def _closer(white: IdentificationResult | None, adaptive: IdentificationResult,
            evidence: dict[str, float] | None,
            white_failed: str | None = None) -> IdentificationResult:
    """
    Return the result closer to the regression, accounted for (a warning if both far).

    ``white`` None: its run failed (``white_failed`` says how); the adaptive result is kept.
    """
    distances = {'adaptive': disagreement(adaptive.parameters, evidence)}
    if white is not None:
        distances['white'] = disagreement(white.parameters, evidence)
    result: IdentificationResult = adaptive
    other, chosen = white, 'adaptive'
    if white is not None and distances['white'] <= distances['adaptive']:
        result, other, chosen = white, adaptive, 'white'
    account: dict[str, Any] = {'model': chosen, 'evidence': _compared(evidence),
                               'agreement_factor': AGREEMENT_FACTOR,
                               'disagreement': _factors(distances)}
    if other is not None:
        account['alternative'] = {name: float(value) for name, value in
                                  other.parameters.items() if name in COMPARED}
    if white_failed is not None:
        account['white'] = white_failed
    warnings = list(result.warnings)
    if distances[chosen] > np.log(AGREEMENT_FACTOR):
        warnings.append(_warning(evidence, result.parameters, distances))
    # The runs share one Progress: the later result's elapsed time is the whole of both.
    elapsed = max(item.elapsed_s for item in (white, adaptive) if item is not None)
    return replace(result, position_error=account, warnings=warnings, elapsed_s=elapsed)


def _compared(evidence: dict[str, float] | None) -> dict[str, float] | None:
    """Return the regression's values of the compared parameters (JSON)."""
    if evidence is None:
        return None
    return {name: float(evidence[name]) for name in COMPARED if name in evidence}


def _factors(distances: dict[str, float]) -> dict[str, float | None]:
    """Disagreements as factors (``exp``; None for a parameter at zero)."""
    return {name: float(np.exp(value)) if np.isfinite(value) else None
            for name, value in distances.items()}


def _warning(evidence: dict[str, float] | None, parameters: dict[str, float],
             distances: dict[str, float]) -> str:
    """Say that neither error model of the position agrees with the regression."""
    seen = evidence or {}
    listed = ', '.join(f'{name} {parameters[name]:.4g} (regression {seen[name]:.4g})'
                       for name in COMPARED if name in parameters and seen.get(name, 0.0) > 0)
    return ('the fit on the position disagrees with the model-free regression on the data '
            f'by more than {AGREEMENT_FACTOR:g}x with the position error modelled as white '
            'noise and as a drift (' + listed + '): the model lacks a force that the position '
            'integrates; compare with --criterion speed')
