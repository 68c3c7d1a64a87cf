"""
The position error's model of a fit on the position, chosen against model-free evidence.

A fit that compares the position weights it first as the sensor's white noise
(:func:`~dcmotor_id.identification.error_model.criterion.position_ar` with the ``white`` model):
the position
sample by sample, which is what an open-loop validation of the model scores.  When the model
lacks a force (a friction that varies along a ball screw's travel), that fit can bend the
physical parameters to cancel the position's drift: a Coulomb friction pressed to zero, an
inertia far off.  The model-free regression on the data
(:func:`~dcmotor_id.identification.checks.start.regression_evidence`) sees that without a
model.  When the white fit's J, b or Mc lie more than :data:`AGREEMENT_FACTOR` from it, the
identification runs again with the ``adaptive`` error model (an AR(1) drift when the residual
misfits, :func:`~dcmotor_id.identification.error_model.criterion.position_ar`), and the result
closer to
the evidence is kept.  JSON ``position_error`` says which and why.

This module holds the decisions (functions of the runs' results); the pipeline runs the
identification's stages under each model and follows them
(:mod:`~dcmotor_id.identification.identify`).  The white run is left after its base fit
when that already contradicts the regression (:func:`white_base_far`): the adaptive run comes
first, and the white run is finished from its state only when the adaptive one disagrees too.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.identification.checks.start import FROM_RECORDS, known_evidence
from dcmotor_id.identification.result import IdentificationResult

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

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


@dataclass(frozen=True)
class WhiteBaseFar:
    """
    A white run's base fit (after the start check) that contradicts the regression.

    ``distance``: :func:`disagreement` (log of the factor); ``parameters``: its J, b and Mc.
    The pipeline then runs the adaptive model first, and finishes the white run from its
    state only when the adaptive one disagrees too (:func:`adaptive_agreeing`,
    :func:`after_a_far_white_base`).
    """

    distance: float
    parameters: dict[str, float]

    def note(self) -> str:
        """Return what the JSON says of the white run left after its base fit."""
        if not np.isfinite(self.distance):
            return 'left after its base fit (a parameter at zero)'
        return ('left after its base fit (' + ', '.join(
            f'{name} {value:.4g}' for name, value in self.parameters.items())
            + f': {np.exp(self.distance):.3g}x from the regression)')


def white_base_far(parameters: dict[str, float], records: Sequence[Record],
                   torque_constant: float | None,
                   evidence: dict[str, float] | None | str = FROM_RECORDS) -> WhiteBaseFar | None:
    """
    Return how far a white run's base fit lies from the regression when beyond agreement.

    None when within :data:`AGREEMENT_FACTOR` (the white run goes on).  ``evidence``: the
    regression on ``records`` when the run has it
    (:func:`~dcmotor_id.identification.checks.start.known_evidence`).
    """
    distance = disagreement(parameters, known_evidence(records, torque_constant, evidence))
    if distance <= np.log(AGREEMENT_FACTOR):
        return None
    return WhiteBaseFar(distance, {name: float(parameters[name]) for name in COMPARED
                                   if name in parameters})


def white_if_agreeing(white: IdentificationResult) -> IdentificationResult | None:
    """Return the white result with its account when it agrees with the regression, else None."""
    return _if_agreeing(white, 'white')


def adaptive_after_white_failed(adaptive: IdentificationResult,
                                failed: DcMotorIdError) -> IdentificationResult:
    """Return the adaptive result after the white run failed (``failed``), accounted for."""
    return replace(adaptive, position_error={'model': 'adaptive', 'white': f'failed: {failed}'})


def after_a_far_white(white: IdentificationResult,
                      adaptive: IdentificationResult | DcMotorIdError) -> IdentificationResult:
    """
    Return the result closer to the regression after a white result that disagrees.

    ``adaptive``: the adaptive run's result, or how it failed (the white result is kept).
    """
    evidence = _evidence(white)
    if isinstance(adaptive, IdentificationResult):
        return _closer(white, adaptive, evidence)
    return replace(white, position_error={
        'model': 'white', 'evidence': _compared(evidence),
        'agreement_factor': AGREEMENT_FACTOR,
        'disagreement': _factors({'white': disagreement(white.parameters, evidence)}),
        'adaptive': f'failed: {adaptive}'})


def adaptive_agreeing(adaptive: IdentificationResult | None,
                      left: WhiteBaseFar) -> IdentificationResult | None:
    """
    Return the adaptive result, accounted for, when it agrees with the regression, else None.

    ``adaptive``: the adaptive run that came first after the white base ``left`` (None: it
    failed).
    """
    return None if adaptive is None else _if_agreeing(adaptive, 'adaptive', white=left.note())


def after_a_far_white_base(adaptive: IdentificationResult | None,
                           white: IdentificationResult | DcMotorIdError) -> IdentificationResult:
    """
    Return the result closer to the regression once the white run was finished after all.

    ``adaptive``: the adaptive run's result (None: it failed); ``white``: the white run's,
    finished from its start check, or how it failed (raised when both failed).
    """
    evidence = None if adaptive is None else _evidence(adaptive)
    if isinstance(white, DcMotorIdError):
        if adaptive is None:
            raise white
        return _closer(None, adaptive, evidence, f'failed: {white}')
    if adaptive is None:
        return replace(white, position_error={'model': 'white', 'adaptive': 'failed'})
    return _closer(white, adaptive, evidence)


def _if_agreeing(result: IdentificationResult, model: str, **more: Any
                 ) -> IdentificationResult | None:
    """
    Return a result of the position error ``model`` with its account when it agrees, else None.

    Agreeing: within :data:`AGREEMENT_FACTOR` of the regression on its records.  ``more``:
    further entries of the account (after the agreement's).
    """
    evidence = _evidence(result)
    distance = disagreement(result.parameters, evidence)
    if distance > np.log(AGREEMENT_FACTOR):
        return None
    return replace(result, position_error={
        'model': model, 'evidence': _compared(evidence), 'agreement_factor': AGREEMENT_FACTOR,
        'disagreement': _factors({model: distance}), **more})


def _evidence(result: IdentificationResult) -> dict[str, float] | None:
    """Return the regression on a run's records: the run's own (``result.evidence``) if any."""
    return known_evidence(result.input_records, result.torque_constant,
                          FROM_RECORDS if result.evidence is None else result.evidence)


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
