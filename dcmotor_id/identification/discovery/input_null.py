"""
An effect's coefficients against what the input current's noise makes of them (issue 29).

In the mechanical mode the measured current drives the model: its sensor noise is a torque
the shaft never felt, integrated twice into the position.  An output-error fit on the training
part bends its parameters to follow that drift, and a candidate effect's small term follows it
better (a load torque takes up the drift's slope): the held-out part, which inherits the
training fit, then shows a real gain, and a held-out test accepts an effect that is not there
(``bench/discovery_results.md``, rounds 7 and 8).

Rule ``input-noise-null`` (the default in rounds 8 and 9; since round 10 the default is the
same tests without the least gain, ``input-noise-null-any-gain``): the held-out test of
``innovation-t-alone``, and then the candidate's coefficients
must stand out of their null distribution under the noise of the input and of the outputs
(:func:`input_noise_doubt`).  The null is the fit's linear response to the noise: the
weighted training residual of the candidate's structure is whitened as its fit whitens it
(the position error's AR(1) coefficients), the fitted parameters' and the initial states'
sensitivities are its columns, and every one of :data:`DRAWS` draws of white noise of the
current's own level (:func:`~dcmotor_id.signals.filters.noise_std`, per record) is run through
the model at the fitted values, white noise of each output sensor's own level added
(:func:`sensor_levels`); least squares on the columns gives the coefficients that draw
produces.  The effect's coefficients are judged
by Hotelling's ``T^2`` against their draws (a zero mean: ``F`` with ``p`` and
``DRAWS - p + 1`` degrees of freedom) at the held-out test's size (:data:`ALPHA`).  Where
the current is not an input (the current-speed loop; the voltage-speed loop, whose input is
the voltage) or the effect is a data effect (a delay) the held-out test alone decides.  The
test's size on clean records: ``bench/bench_input_null_size.py``.
"""

from __future__ import annotations

from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.model import parameter_names
from dcmotor_id.identification.discovery.screening import train_model
from dcmotor_id.identification.error_model.criterion import noise_level, whiten
from dcmotor_id.identification.error_model.residuals import simulate_records
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.signals.filters import noise_std

if TYPE_CHECKING:
    from dcmotor_id.identification.discovery.state import LoopState
    from dcmotor_id.identification.discovery.structure import Candidate, Fit

#: Draws of the input's and the outputs' noise through the fit.
DRAWS = 200
#: Seed of the draws (the same record gets the same verdict).
SEED = 2029
#: Size of the test: the held-out test's
#: (:data:`~dcmotor_id.identification.discovery.judging.HELDOUT_ALPHA`).
ALPHA = 0.00135


def stacked_outputs(loop: LoopState, outputs: Sequence[dict], stops: Sequence[int],
                    rhos: Sequence[float], noise: tuple[np.random.Generator, dict] | None = None
                    ) -> np.ndarray:
    """
    Join the weighted, whitened training parts of every output channel of every record.

    Each channel is divided by its weight; the position is whitened by its record's AR(1)
    coefficient as the fit whitens it.  With ``noise`` (a generator and every channel's
    sensor noise level per record, :func:`sensor_levels`), white noise of that level is
    added before the whitening.
    """
    parts = []
    for channel in loop.outputs:
        for index, (out, stop) in enumerate(zip(outputs, stops)):
            part = np.asarray(out[channel][:stop], dtype=float)
            if noise is not None:
                part = part + noise[0].normal(0.0, noise[1][channel][index], part.shape[0])
            part = part / loop.fitted_weights[channel]
            rho = rhos[index] if channel == 'position' else 0.0
            parts.append(whiten(part, float(rho)))
    return np.concatenate(parts)


def sensor_levels(loop: LoopState, records: Sequence) -> dict[str, list[float]]:
    """
    Return every output channel's sensor noise per record: its own level, not the misfit's.

    :func:`~dcmotor_id.identification.error_model.criterion.noise_level` (at least the
    rounding of a quantised channel: an encoder's step over ``sqrt(12)``); the loop's weights
    are the base fit's residual levels, which hold the input's drift.
    """
    return {channel: [noise_level(getattr(rec, channel)) for rec in records]
            for channel in loop.outputs}


def fit_columns(loop: LoopState, fitted: Fit, model: OutputErrorModel, rhos: Sequence[float]
                ) -> tuple[np.ndarray, list[str], np.ndarray]:
    """
    Return the sensitivities of the stacked outputs, the parameters' names and the nominal.

    Forward differences at the fitted values: every fitted parameter (relative step 1e-6,
    1e-9 at zero) and every component of every record's initial state (step 1e-6 of its size,
    at least 1e-6): the fit frees them all, and the initial position and speed take up
    much of a drift.
    """
    values, states = dict(fitted.values), [list(s) for s in fitted.estimate.initial_states]
    names = list(model.base_names) + [term.name for term in fitted.terms]

    def run(moved: dict, moved_states: list) -> np.ndarray:
        with np.errstate(all='ignore'):
            return stacked_outputs(loop, simulate_records(model, moved, moved_states),
                                   fitted.stops, rhos)
    nominal = run(values, states)
    columns = []
    for name in names:
        step = 1e-6 * abs(values[name]) if values[name] != 0.0 else 1e-9
        columns.append((run({**values, name: values[name] + step}, states) - nominal) / step)
    for index, state in enumerate(states):
        for component, value in enumerate(state):
            step = 1e-6 * max(abs(value), 1.0)
            moved = [list(s) for s in states]
            moved[index][component] = value + step
            columns.append((run(values, moved) - nominal) / step)
    return np.column_stack(columns), names, nominal


def null_coefficients(loop: LoopState, fitted: Fit, prefix: str,
                      draws: int = DRAWS) -> np.ndarray | None:
    """
    Return the coefficients named ``prefix...`` of ``draws`` noise draws' fits (rows), or None.

    The fit's linear response (least squares on :func:`fit_columns`) to each draw: the
    current with white noise of each record's own level, run through the model at the fitted
    values, plus white noise of each output's level.  None when a column or a draw is not
    finite or the current has no noise to draw.
    """
    train, model = train_model(loop, fitted, fitted.terms)
    rhos = list(fitted.estimate.info.get('position_ar') or loop.position_ar
                or [0.0] * len(train))
    matrix, names, nominal = fit_columns(loop, fitted, model, rhos)
    indices = [index for index, name in enumerate(names) if name.startswith(prefix)]
    levels = [noise_std(np.asarray(rec.current, dtype=float)) for rec in train]
    if not (indices and np.all(np.isfinite(matrix)) and any(level > 0 for level in levels)):
        return None
    rng, sensors = np.random.default_rng(SEED), sensor_levels(loop, train)
    responses = np.empty((nominal.shape[0], draws))
    values, states = dict(fitted.values), fitted.estimate.initial_states
    for draw in range(draws):
        noisy = [rec.replace(current=np.asarray(rec.current, dtype=float)
                             + rng.normal(0.0, level, len(rec)))
                 for rec, level in zip(train, levels)]
        drawn = OutputErrorModel(noisy, loop.torque_constant, model.terms, loop.quasi_static,
                                 loop.criterion)
        with np.errstate(all='ignore'):
            simulated = simulate_records(drawn, values, states)
        responses[:, draw] = stacked_outputs(loop, simulated, fitted.stops, rhos,
                                             (rng, sensors)) - nominal
    if not np.all(np.isfinite(responses)):
        return None
    coefficients, *_ = np.linalg.lstsq(matrix, responses, rcond=None)
    return coefficients[indices].T


def input_noise_statistic(loop: LoopState, candidate: Candidate, alpha: float = ALPHA
                          ) -> tuple[float, float, int] | None:
    """
    Return Hotelling's ``T^2`` of a candidate's coefficients, the ``T^2`` needed, the draws.

    The effect's fitted coefficients against their draws under the noise
    (:func:`null_coefficients`, a zero mean): ``T^2 (m - p + 1) / (p m)`` follows ``F`` with
    ``p`` and ``m - p + 1`` degrees of freedom (``p`` coefficients, ``m`` draws); the ``T^2``
    needed is its upper ``alpha`` quantile (for one coefficient, ``|t|`` beyond the two-sided
    ``alpha``: the sign of a coefficient is free).  None outside the mechanical mode's
    output-error model (the current-speed loop; the voltage-speed loop, whose input is the
    voltage), for data effects and where the null cannot be drawn.
    """
    from scipy.stats import f as fisher

    fitted, prefix = candidate.fitted, f'{candidate.name}.'
    if not (loop.mechanical_only and set(parameter_names(True)) <= set(fitted.values)) \
            or candidate.effect.TRANSFORM:
        return None
    draws = null_coefficients(loop, fitted, prefix)
    if draws is None:
        return None
    observed = np.array([fitted.values[term.name] for term in fitted.terms
                         if term.name.startswith(prefix)])
    covariance = np.atleast_2d(draws.T @ draws / draws.shape[0])
    p, m = observed.shape[0], draws.shape[0]
    statistic = float(observed @ np.linalg.pinv(covariance) @ observed)
    required = float(fisher.ppf(1.0 - alpha, p, m - p + 1)) * p * m / (m - p + 1)
    return statistic, required, m


def input_noise_doubt(loop: LoopState, candidate: Candidate, alpha: float = ALPHA
                      ) -> str | None:
    """
    Why a candidate's coefficients do not stand out of the input's noise, or None.

    Its ``T^2`` (:func:`input_noise_statistic`) must reach the one needed at ``alpha``; None
    (no doubt) where the statistic is not computed.
    """
    found = input_noise_statistic(loop, candidate, alpha)
    if found is None or found[0] >= found[1]:
        return None
    statistic, required, draws = found
    return (f"its coefficients are within what the input current's noise makes of them "
            f'(T^2 = {statistic:.3g} against their fits to {draws} draws of that noise, '
            f'{required:.3g} needed)')
