"""
The linearised screen: which candidate explains the residual, with which inner parameters.

The residual of the training parts is regressed on the sensitivities of the fitted parameters
and of each candidate's terms (finite differences through the model); a sensor delay on the
time derivative of the simulated channel.  The model's part is a :class:`Screen`: how its
fitted parameters and a candidate's coefficients move the simulated outputs
(:data:`OUTPUT_ERROR_SCREEN`, the output-error model of the current-speed loop; the
voltage-to-speed model has its own in
:mod:`~dcmotor_id.identification.discovery.voltage_speed`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Fit, slice_terms
from dcmotor_id.identification.effects import SensorDelay
from dcmotor_id.identification.error_model.residuals import simulate_records
from dcmotor_id.identification.estimators.jacobian import jacobian
from dcmotor_id.identification.estimators.refined import OutputErrorModel

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import ExogenousTerm


#: Share of ``min_gain`` the linearised screen must explain for a candidate to be refitted.
SCREEN_SHARE = 0.5
#: Candidates refitted whatever their screen, best screen first.
SCREEN_TOP = 2
#: Candidates refitted whatever their screen when the model misfits far above the noise (the
#: linearised screen then ranks, it does not gate: a decisive nonlinear effect can screen low).
SCREEN_TOP_MISFIT = 4

#: The weighted training residual, the fitted parameters' sensitivities and the nominal outputs.
Sensitivities = tuple[np.ndarray, np.ndarray, list]


@dataclass(frozen=True)
class Screen:
    """
    How a model's training outputs respond: the screen's model-specific part.

    Attributes
    ----------
    sensitivities : callable
        ``(loop, fit) -> (residual, matrix, nominal)``: the weighted training residual, the
        sensitivities of the fit's parameters (columns) and the simulated outputs per record
        (:func:`base_sensitivities`).
    responses : callable
        ``(loop, fit, effect class, inner, nominal) -> (terms, columns)``: a candidate's terms
        (their names, start values and typical magnitudes) and the sensitivities of the
        training outputs to their coefficients (:func:`term_responses`).

    """

    sensitivities: Callable[[LoopState, Fit], Sensitivities]
    responses: Callable[[LoopState, Fit, type[Effect], dict, list],
                        tuple[Sequence[ExogenousTerm], np.ndarray]]


def train_model(loop: LoopState, fitted: Fit,
                terms: tuple[ExogenousTerm, ...]) -> tuple[list[Record], OutputErrorModel]:
    """Return the training parts of a fit's records and the output-error model on them."""
    train = [rec.slice(0, stop) for rec, stop in zip(fitted.records, fitted.stops)]
    return train, OutputErrorModel(train, loop.torque_constant,
                                   slice_terms(terms, fitted.stops), loop.quasi_static,
                                   loop.criterion)


def stack(loop: LoopState, outputs_per_record: Sequence[dict],
          stops: Sequence[int]) -> np.ndarray:
    """Join the weighted training parts of every output channel of every record."""
    parts = []
    for channel in loop.outputs:
        for out, stop in zip(outputs_per_record, stops):
            parts.append(np.asarray(out[channel][:stop]) / loop.fitted_weights[channel])
    return np.concatenate(parts)


def base_sensitivities(loop: LoopState, fitted: Fit) -> Sensitivities:
    """Weighted residual and sensitivities of the fitted parameters (training part)."""
    train, model = train_model(loop, fitted, fitted.terms)
    values = dict(fitted.values)
    states = fitted.estimate.initial_states
    nominal = simulate_records(model, values, states)
    measured = [{channel: getattr(rec, channel) for channel in loop.outputs}
                for rec in train]
    residual = stack(loop, measured, fitted.stops) - stack(loop, nominal, fitted.stops)
    names = list(model.base_names) + [term.name for term in fitted.terms]
    point = np.array([values[name] for name in names], dtype=float)

    def stacked(vector):
        moved = {**values, **dict(zip(names, vector))}
        with np.errstate(all='ignore'):
            return stack(loop, simulate_records(model, moved, states), fitted.stops)
    # Initial-state sensitivities are left out: they decay within a few time constants.
    return residual, sensitivity_matrix(stacked, point, stack(loop, nominal, fitted.stops)), \
        nominal


def sensitivity_matrix(stacked: Callable[[np.ndarray], np.ndarray], point: np.ndarray,
                       nominal: np.ndarray) -> np.ndarray:
    """
    Forward-difference sensitivities of stacked outputs to the parameters at ``point``.

    Relative steps of 1e-6 (1e-9 at zero); columns that are not finite are left out.
    """
    if not point.size:
        return np.zeros((nominal.shape[0], 0))
    steps = np.where(point != 0.0, 1e-6 * np.abs(point), 1e-9)
    matrix = jacobian(stacked, point, steps, central=False, f0=nominal)
    return matrix[:, np.all(np.isfinite(matrix), axis=0)]


def term_responses(loop: LoopState, fitted: Fit, cls: type[Effect], inner: dict,
                   nominal: list) -> tuple[Sequence[ExogenousTerm], np.ndarray]:
    """
    Return a candidate's terms and the training outputs' sensitivities to its coefficients.

    Finite differences through the model from the candidate's start values, with the
    coefficient's typical magnitude as the (secant) step, so stick-slip events do not make
    the difference noisy; for a linear term this is its exact linear response.
    """
    terms = cls.terms(fitted.records, inner, fitted.values, loop.torque_constant)
    _, model = train_model(loop, fitted, fitted.terms + tuple(terms))
    start = dict(fitted.values)
    start.update({term.name: term.initial for term in terms})
    names = [term.name for term in terms]

    def stacked(vector):
        moved = {**start, **dict(zip(names, vector))}
        return stack(loop, simulate_records(model, moved, fitted.estimate.initial_states),
                     fitted.stops)
    return terms, jacobian(stacked, [term.initial for term in terms],
                           [term.scale for term in terms], central=False,
                           f0=stack(loop, nominal, fitted.stops))


#: The screen of the output-error model (current and speed, or the speed of the mechanical mode).
OUTPUT_ERROR_SCREEN = Screen(base_sensitivities, term_responses)


def projector(matrix: np.ndarray) -> np.ndarray | None:
    """Orthonormal basis of the columns of a sensitivity matrix (pivoted QR), or None."""
    if matrix.shape[1] == 0:
        return None
    from scipy.linalg import qr  # lazily: only a search round needs it (import time)
    q, r, _ = qr(matrix, mode='economic', pivoting=True)
    keep = np.abs(np.diag(r)) > 1e-10 * max(abs(r[0, 0]), 1e-300)
    return q[:, keep]


def explained_by(q: np.ndarray | None, residual: np.ndarray,
                 columns: np.ndarray) -> tuple[float, np.ndarray]:
    """Residual sum of squares explained by ``columns`` beyond the base sensitivities."""
    if q is not None:
        residual = residual - q @ (q.T @ residual)
        columns = columns - q @ (q.T @ columns)
    coefficients, *_ = np.linalg.lstsq(columns, residual, rcond=None)
    fitted = columns @ coefficients
    return float(fitted @ fitted), coefficients


def screen(loop: LoopState, fitted: Fit, cls: type[Effect], residual: np.ndarray,
           q: np.ndarray | None, nominal: list,
           model: Screen = OUTPUT_ERROR_SCREEN) -> tuple[float, dict, dict] | None:
    """Best inner parameters of a candidate by the linearised fit; with start values."""
    best = None
    for inner in cls.inner_grid(fitted.records, fitted.values, loop.torque_constant):
        terms, columns = model.responses(loop, fitted, cls, inner, nominal)
        if not np.all(np.isfinite(columns)) or np.allclose(columns, 0.0):
            continue
        gained, coefficients = explained_by(q, residual, columns)
        if best is None or gained > best[0]:
            # A coefficient without effect at the start (the Stribeck velocity while the
            # excess is zero) keeps its start value.
            norms = np.linalg.norm(columns, axis=0)
            moved = norms > 1e-9 * np.max(norms)
            best = (gained, inner, {
                term.name: float(term.initial + (c if active else 0.0))
                for term, c, active in zip(terms, coefficients, moved)})
    return best


def delay_estimate(loop: LoopState, fitted: Fit, channel: str, residual: np.ndarray,
                   q: np.ndarray | None, nominal: list) -> tuple[float, float]:
    """Linearised delay of one channel's sensor [samples] (positive: the sensor is late)."""
    outs = []
    for out, rec, stop in zip(nominal, fitted.records, fitted.stops):
        sens = {name: np.zeros(stop) for name in loop.outputs}
        sens[channel] = -np.gradient(out[channel][:stop])
        outs.append(sens)
    column = stack(loop, outs, fitted.stops)[:, None]
    gained, coefficients = explained_by(q, residual, column)
    return gained, float(coefficients[0])


def screen_candidate(loop: LoopState, current: Fit, cls: type[Effect], residual: np.ndarray,
                     q: np.ndarray | None, nominal: list,
                     model: Screen = OUTPUT_ERROR_SCREEN) -> Candidate | None:
    """
    Linearised screen of one candidate: its inner parameters, start and explained share.

    Returns the :class:`Candidate` (not refitted) or None when the candidate has nothing
    to offer (no grid point, or a delay that rounds to zero samples).
    """
    total = max(float(residual @ residual), 1e-300)
    if cls.TRANSFORM:
        best = None
        for channel in SensorDelay.channels(loop.mechanical_only):
            gained, estimate = delay_estimate(loop, current, channel, residual, q, nominal)
            samples = int(np.round(estimate))
            if samples != 0 and (best is None or gained / total > best.screen_explained):
                best = Candidate(cls, {'channel': channel, 'samples': samples}, {},
                                 gained / total)
        return best
    found = screen(loop, current, cls, residual, q, nominal, model)
    if found is None:
        return None
    gained, inner, start_terms = found
    return Candidate(cls, inner, start_terms, gained / total)


def screen_absent(loop: LoopState, current: Fit,
                  model: Screen = OUTPUT_ERROR_SCREEN) -> list[Candidate]:
    """
    Screen every effect of the vocabulary not yet in the structure; best screen first.

    The residual and the sensitivities of the fitted parameters (training parts) are computed
    once, by the model's :class:`Screen`; each candidate is screened against them
    (:func:`screen_candidate`).
    """
    residual, matrix, nominal = model.sensitivities(loop, current)
    q = projector(matrix)
    present = set(current.structure.names())
    screened = []
    for cls in loop.candidates:
        if cls.name in present:
            continue
        candidate = screen_candidate(loop, current, cls, residual, q, nominal, model)
        if candidate is not None:
            screened.append(candidate)
    screened.sort(key=lambda candidate: -candidate.screen_explained)
    return screened
