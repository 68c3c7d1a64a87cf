"""
Effect discovery on the voltage-to-speed model (records of voltage and speed, no current).

The loop of :mod:`~dcmotor_id.identification.discovery.loop`, on the model the voltage-speed
path fits (:mod:`~dcmotor_id.identification.estimators.voltage_speed`: kS, kV, kA and, where
the data resolve it, the armature lag), over the effects of the vocabulary that act on the
shaft and so are voltages there (:meth:`~dcmotor_id.identification.effects.Effect.
in_voltage_speed`: a load torque, the friction's asymmetries, a late speed sensor).  The
model with effects is :class:`~dcmotor_id.identification.estimators.voltage_speed_effects.
EffectModel`; each coefficient is named as its effect's term (``load_torque.torque_Nm``) and
holds volts (``Ra T_L/CPhi``).

A round is the loop's (:func:`~dcmotor_id.identification.discovery.loop.one_round`) with
this model's steps (:data:`VOLTAGE_SPEED_ROUND`): every absent effect is screened
linearised on the training parts
(:func:`~dcmotor_id.identification.discovery.parts.excited_stop`; :func:`sensitivities`,
:func:`term_responses`), the ones the screen supports and the best few anyway are refitted
(:func:`refit`), scored on the held-out parts and judged by the loop's rule
(:func:`~dcmotor_id.identification.discovery.judging.decide`: the default rule's t test
on effective samples, the least gain, the BIC, the ties to the earlier effect); the loop
never ends worse than its base (:func:`~dcmotor_id.identification.discovery.judging.
never_worse`).  The effects found are refitted with the base on all of the data.  The
settings are a :class:`~dcmotor_id.identification.discovery.state.LoopState` of the
mechanical mode with a torque constant of 1: the voltage is the shaft's drive in volts,
the speed the one output.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Any, Callable, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.discovery.judging import never_worse
from dcmotor_id.identification.discovery.loop import RoundSteps, search_rounds
from dcmotor_id.identification.discovery.parts import excited_stop
from dcmotor_id.identification.discovery.refitting import cost
from dcmotor_id.identification.discovery.screening import (Screen, Sensitivities,
                                                           sensitivity_matrix, stack)
from dcmotor_id.identification.discovery.state import (CROSS_VALIDATED, DEFAULT_ACCEPTANCE,
                                                       LoopState)
from dcmotor_id.identification.discovery.structure import Candidate, Fit, Structure
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.estimators.jacobian import jacobian
from dcmotor_id.identification.estimators.voltage_speed import VoltageSpeedFit
from dcmotor_id.identification.estimators.voltage_speed_effects import EffectModel, fit_effects
from dcmotor_id.simulation import combine_contributions, MotorEffects

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import ExogenousTerm

#: The effects that act in the voltage-to-speed model, in the vocabulary's order (ties).
VOLTAGE_SPEED_VOCABULARY: tuple[type[Effect], ...] = tuple(
    cls for cls in VOCABULARY if cls.in_voltage_speed())
#: Bound on the function evaluations of a fit on the training parts.
PART_MAX_NFEV = 200
#: Names of the base parameters in a fit's values (log kA, log kV, kS, the lag, ``c``).
BASE_NAMES = ('kA', 'kV', 'kS', 'lag_share', 'cphi_share')
#: What every effect of this mode is, said with the result.
IN_VOLTS = ('the effects of the voltage-to-speed model are in volts (a torque T on the shaft '
            'as Ra T/CPhi, like kS = Ra Mc/CPhi): their split into a torque and Ra/CPhi needs '
            'the current')

#: Why there is no search on one voltage level in one direction (kS held at 0).
ONE_LEVEL = ('no effect search: one voltage level in one direction ties kS to kV (kS held at '
             "0), and a load or the friction's asymmetries would be as inseparable from them")


@dataclass
class VoltageSpeedDiscovery:
    """
    What the discovery found on voltage and speed.

    Attributes
    ----------
    structure : Structure
        The effects found (empty: none).
    fit : VoltageSpeedFit or None
        The base and the effects refitted on all of the (transformed) records; None without
        effects.
    records : list of Record
        The records as the final model sees them (a sensor delay shifts the speed).
    effects : list of Effect
        The effects found, their torque parameters in volts.
    summary : dict
        The JSON ``discovery`` block: hold-out share, least gain, reason, the rounds.
    out_of_time : bool
        Whether the time budget ran out (the best structure so far is kept).

    """

    structure: Structure
    fit: VoltageSpeedFit | None
    records: list
    effects: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    out_of_time: bool = False

    def effects_json(self) -> list[dict[str, Any]]:
        """Return the effects as the result lists them, the parameters named in volts."""
        return [effect.describe_voltage_speed() for effect in self.effects]


def coefficient_names(structure: Structure) -> list[str]:
    """Return the fit's names of a structure's coefficients (its effects' terms)."""
    return [cls.term_name(key) for cls, _ in structure.items if not cls.TRANSFORM
            for key in cls.VOLTAGE_SPEED_NAMES]


def effects_builder(structure: Structure) -> Callable[[np.ndarray], MotorEffects]:
    """Return the map from a structure's coefficients [V] to the simulation's effects."""
    names = coefficient_names(structure)
    shaft = [(cls, inner) for cls, inner in structure.items if not cls.TRANSFORM]

    def build(coefficients: np.ndarray) -> MotorEffects:
        values = {name: float(value) for name, value in zip(names, coefficients)}
        return combine_contributions([cls.from_fit(values, inner).motor_effects()
                                      for cls, inner in shaft])
    return build


def fit_parts(loop: LoopState, structure: Structure, theta: Sequence[float],
              start: dict[str, float], states: Sequence[Sequence[float]]) -> Fit | None:
    """
    Fit a structure on the training parts and simulate the whole records; None if it fails.

    ``theta`` holds the base parameters to start from (3, or 5 with the lag), ``start`` the
    coefficients (0 where missing), ``states`` every record's initial state.
    """
    records = structure.transformed(loop.records)
    stops = [excited_stop(rec, loop.holdout_fraction, loop.outputs) for rec in records]
    names = coefficient_names(structure)
    model = EffectModel(len(theta), effects_builder(structure))
    vector = np.array(list(theta) + [start.get(name, 0.0) for name in names])
    done = fit_effects(model, [rec.slice(0, stop) for rec, stop in zip(records, stops)],
                       vector, names, states, loop.progress, PART_MAX_NFEV)
    if done is None:
        return None
    fitted, x = done
    count = vector.size
    simulated = [{'speed': model(x[:count], rec, np.asarray(state))}
                 for rec, state in zip(records, fitted.states)]
    parameters = {**dict(zip(BASE_NAMES, (float(value) for value in x[:len(theta)]))),
                  **fitted.coefficients}
    estimate = Estimate('voltage_speed', parameters, dict(fitted.coefficient_stderr),
                        fitted.states, {'noise_std': {'speed': fitted.noise_std}})
    result = Fit(structure, estimate, records, stops, simulated, ())
    if loop.weights is None:
        loop = replace(loop, weights={'speed': max(fitted.noise_std, 1e-300)})
    result.train_cost = cost(loop, result, 'train')
    result.heldout_cost = cost(loop, result, 'heldout')
    result.n_train = int(sum(stops))
    return result


def base_theta(fit: Fit, size: int) -> list[float]:
    """Return a fit's base parameters (``theta``'s first ``size``)."""
    return [float(fit.values[name]) for name in BASE_NAMES[:size]]


def base_size(fit: Fit) -> int:
    """Return the number of a fit's base parameters: 3 (first order) or 5 (with the lag)."""
    return sum(name in fit.values for name in BASE_NAMES)


def parameter_vector(fit: Fit, structure: Structure) -> np.ndarray:
    """Return a fit's base parameters and ``structure``'s coefficients (0 where it has none)."""
    return np.array(base_theta(fit, base_size(fit)) + [
        float(fit.values.get(name, 0.0)) for name in coefficient_names(structure)])


def training_outputs(loop: LoopState, fit: Fit,
                     structure: Structure) -> Callable[[np.ndarray], np.ndarray]:
    """
    Return the map from ``structure``'s parameter vector to the stacked training speed.

    The fit's training parts (records, stops, initial states), weighted as the screen
    weighs them (:func:`~dcmotor_id.identification.discovery.screening.stack`).
    """
    model = EffectModel(base_size(fit), effects_builder(structure))
    train = [rec.slice(0, stop) for rec, stop in zip(fit.records, fit.stops)]
    states = [np.asarray(state, dtype=float) for state in fit.estimate.initial_states]

    def stacked(vector: np.ndarray) -> np.ndarray:
        with np.errstate(all='ignore'):  # a wild step may overflow; it is left out
            speeds = [{'speed': model(np.asarray(vector, dtype=float), rec, state)}
                      for rec, state in zip(train, states)]
        return stack(loop, speeds, fit.stops)
    return stacked


def sensitivities(loop: LoopState, fit: Fit) -> Sensitivities:
    """
    Return the weighted training residual and the sensitivities of the fit's parameters.

    The base parameters and the effects' coefficients, by forward differences through the
    model with effects; the nominal outputs are the fit's simulation (causal: its training
    part is the simulation of the training part).
    """
    nominal = fit.simulated
    simulated = stack(loop, nominal, fit.stops)
    residual = stack(loop, [{'speed': rec.speed} for rec in fit.records], fit.stops) - simulated
    matrix = sensitivity_matrix(training_outputs(loop, fit, fit.structure),
                                parameter_vector(fit, fit.structure), simulated)
    return residual, matrix, nominal


def term_responses(loop: LoopState, fit: Fit, cls: type[Effect], inner: dict,
                   nominal: list) -> tuple[Sequence[ExogenousTerm], np.ndarray]:
    """
    Return a candidate's terms and the training speed's sensitivities to its coefficients.

    The terms are the effect's own (names, start 0, typical magnitudes) with the voltage as
    the drive (torque constant 1: a torque is a voltage here) and ``kS``, ``kV`` as the
    friction; each coefficient's response is a secant of its typical magnitude through the
    model with effects, as the output-error screen's
    (:func:`~dcmotor_id.identification.discovery.screening.term_responses`).
    """
    values = fit.values
    drive = [rec.replace(current=rec.voltage) for rec in fit.records]
    terms = cls.terms(drive, inner, {'Mc': values['kS'], 'b': math.exp(values['kV'])}, 1.0)
    known = parameter_vector(fit, fit.structure)
    outputs = training_outputs(loop, fit, fit.structure.plus(cls, inner))
    return terms, jacobian(lambda coefficients: outputs(np.concatenate([known, coefficients])),
                           [term.initial for term in terms], [term.scale for term in terms],
                           central=False, f0=stack(loop, nominal, fit.stops))


def refit(loop: LoopState, current: Fit, candidate: Candidate) -> Candidate:
    """
    Refit the current structure with one more effect on the training parts; with its problem.

    The base starts from the current fit, the coefficients from the current ones and the new
    one from 0; a sensor delay takes the screen's samples.  The candidate comes back without
    a fit when the refit failed.
    """
    structure = current.structure.plus(candidate.effect, candidate.inner)
    fitted = fit_parts(loop, structure, base_theta(current, base_size(current)),
                       dict(current.values), current.estimate.initial_states)
    if fitted is None:
        return candidate
    values = fitted.values
    effect = structure.effects(values)[-1]
    # The fit holds log kV (kV > 0): the base's viscous term is kV itself.
    base = {'Mc': values['kS'], 'b': math.exp(values['kV'])}
    return replace(candidate, fit=fitted, problem=effect.problem(base, fitted.records))


def _in_volts(chosen: Candidate) -> dict[str, Any]:
    """Return a refitted candidate's effect as the result lists it (named in volts)."""
    return chosen.fitted.structure.effects(chosen.fitted.values)[-1].describe_voltage_speed()


def _no_analysis(loop: LoopState, fit: Fit) -> dict:
    """Return no residual analysis (the search runs until no candidate earns its place)."""
    return {}


#: A search round on the voltage-to-speed model: its screen, refit and names in volts.  Only
#: the candidates the screen supports are refitted (none anyway): its effects have no inner
#: parameters to grid and respond (nearly) linearly to their coefficients, so the screen's
#: share is close to a refit's training gain, while a refit through the event-driven kernel
#: costs a hundred simulations of a hundred times the linear model's.
VOLTAGE_SPEED_ROUND = RoundSteps(Screen(sensitivities, term_responses), refit, _no_analysis,
                                 _in_volts, 'discovery (voltage-speed)', (0, 0))


def discover_voltage_speed(records: Sequence[Record], fit: VoltageSpeedFit,
                           progress: Progress | None = None) -> VoltageSpeedDiscovery:
    """
    Search the effects of the voltage-to-speed model; refit the ones found on all the data.

    ``fit`` is the model without effects on all of the records (its order, first or
    second, is kept); the loop starts from it.  Past the time budget the best structure so
    far is kept (``out_of_time``).  No search when the fit held kS at 0 (one voltage level in
    one direction: :data:`ONE_LEVEL`).
    """
    if fit.friction_at_zero:
        return VoltageSpeedDiscovery(Structure(), None, list(records),
                                     summary={'reason': ONE_LEVEL})
    loop = LoopState(list(records), torque_constant=1.0, vocabulary=VOLTAGE_SPEED_VOCABULARY,
                     progress=progress)
    if loop.acceptance in CROSS_VALIDATED:
        # No fold refits of this model: its candidates are judged by the default rule.
        loop = replace(loop, acceptance=DEFAULT_ACCEPTANCE)
    try:
        if progress is not None:
            progress.set_stage('discovery (voltage-speed): base model on the training parts')
        base = fit_parts(loop, Structure(), fit.theta, {}, fit.states)
    except TimeBudgetExceeded:
        return VoltageSpeedDiscovery(Structure(), None, list(records), summary={
            'reason': 'the time budget ran out before the effect search'}, out_of_time=True)
    if base is None:
        return VoltageSpeedDiscovery(Structure(), None, list(records), summary={
            'reason': 'the base model did not fit the training parts: no effect search'})
    loop = replace(loop, weights={'speed': max(base.estimate.info['noise_std']['speed'],
                                               1e-300)})
    search = search_rounds(loop, base, {}, VOLTAGE_SPEED_ROUND)
    found, reason = never_worse(base, search.current, search.reason)
    summary = {'holdout_fraction': loop.holdout_fraction, 'min_gain_pct': 100 * loop.min_gain,
               'acceptance': loop.acceptance, 'reason': reason, 'steps': search.steps,
               'base_heldout_parameters': dict(base.values)}
    if not len(found.structure):
        return VoltageSpeedDiscovery(Structure(), None, list(records), [], summary,
                                     search.out_of_time)
    return _on_all_data(loop, fit, found, summary, search.out_of_time)


def _on_all_data(loop: LoopState, fit: VoltageSpeedFit, found: Fit, summary: dict,
                 out_of_time: bool) -> VoltageSpeedDiscovery:
    """Refit the effects found with the base on all of the records (the training fit if not)."""
    structure = found.structure
    records = structure.transformed(loop.records)
    names = coefficient_names(structure)
    model = EffectModel(len(fit.theta), effects_builder(structure))
    vector = np.array(list(fit.theta) + [found.values[name] for name in names])
    done = None
    try:
        if loop.progress is not None:
            loop.progress.set_stage('discovery (voltage-speed): final refit on all the data')
        done = fit_effects(model, records, vector, names, found.estimate.initial_states,
                           loop.progress)
    except TimeBudgetExceeded:
        out_of_time = True
    if done is None:  # the training-part fit is what there is
        summary['reason'] += '; the refit on all of the data failed: the training-part fit'
        return VoltageSpeedDiscovery(Structure(), None, list(loop.records), [], summary,
                                     out_of_time)
    final = done[0]
    return VoltageSpeedDiscovery(structure, final, records,
                                 structure.effects(final.coefficients), summary, out_of_time)
