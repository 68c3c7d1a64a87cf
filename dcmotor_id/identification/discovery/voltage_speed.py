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

Every round refits each absent effect on the training parts
(:func:`~dcmotor_id.identification.discovery.parts.excited_stop`), scores it on the held-out
parts and judges it by the loop's rule
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
from typing import Any, Callable, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.discovery.judging import decide, never_worse, round_report, score
from dcmotor_id.identification.discovery.parts import excited_stop
from dcmotor_id.identification.discovery.refitting import cost
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Fit, Structure
from dcmotor_id.identification.effects import SensorDelay, VOCABULARY
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.estimators.voltage_speed import VoltageSpeedFit
from dcmotor_id.identification.estimators.voltage_speed_effects import EffectModel, fit_effects
from dcmotor_id.simulation import combine_contributions, MotorEffects

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect

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


def delay_inner(current: Fit) -> dict[str, Any] | None:
    """
    Return the speed sensor's delay the current fit's training residual points to, or None.

    A sensor ``d`` samples late reads ``w[k - d] ~ w[k] - d (w[k] - w[k-1])``: the residual's
    projection on the simulated speed's increments gives ``d``, rounded (None below half a
    sample).
    """
    along = total = 0.0
    for rec, sim, stop in zip(current.records, current.simulated, current.stops):
        slope = np.gradient(sim['speed'][:stop])
        along += float((sim['speed'][:stop] - rec.speed[:stop]) @ slope)
        total += float(slope @ slope)
    samples = int(round(along / total)) if total > 0 else 0
    return {'channel': 'speed', 'samples': samples} if samples else None


def candidate(loop: LoopState, current: Fit, cls: type[Effect], size: int) -> Candidate:
    """Refit the current structure with one more effect; the candidate with its problem."""
    inner = delay_inner(current) if cls is SensorDelay else {}
    if inner is None:
        return Candidate(cls, {}, {}, 0.0)
    structure = current.structure.plus(cls, inner)
    states = current.estimate.initial_states
    fitted = fit_parts(loop, structure, base_theta(current, size), dict(current.values), states)
    if fitted is None:
        return Candidate(cls, inner, {}, 0.0)
    values = fitted.values
    effect = structure.effects(values)[-1]
    problem = effect.problem({'Mc': values['kS'], 'b': values['kV']}, fitted.records)
    return score(loop, current, Candidate(cls, inner, {}, 0.0, fit=fitted, problem=problem))


def one_round(loop: LoopState, current: Fit, size: int) -> tuple[Candidate | None, dict]:
    """Refit every absent effect, judge them; return the chosen one (or None) and the report."""
    order = {cls.name: position for position, cls in enumerate(VOLTAGE_SPEED_VOCABULARY)}
    present = set(current.structure.names())
    tried = []
    for cls in VOLTAGE_SPEED_VOCABULARY:
        if cls.name not in present:
            if loop.progress is not None:
                loop.progress.set_stage(f'discovery (voltage-speed): candidate {cls.name}')
            tried.append(candidate(loop, current, cls, size))
    refitted = sorted((item for item in tried if item.fit is not None),
                      key=lambda item: item.fitted.heldout_cost)
    chosen, equivalent, refitted = decide(loop, current, refitted, order)
    results = refitted + [item for item in tried if item.fit is None]
    report = round_report(loop, current, {}, results, chosen, equivalent)
    if chosen is not None:  # named in volts, as the result lists them
        report['added'] = _in_volts(chosen)
        report['equivalent'] = [_in_volts(item) for item in equivalent]
    return chosen, report


def _in_volts(chosen: Candidate) -> dict[str, Any]:
    """Return a refitted candidate's effect as the result lists it (named in volts)."""
    return chosen.fitted.structure.effects(chosen.fitted.values)[-1].describe_voltage_speed()


def search(loop: LoopState, base: Fit, size: int) -> tuple[Fit, list[dict], str, bool]:
    """Add effects round by round until none earns its place; the fit, rounds, reason."""
    current, steps = base, []
    try:
        while len(current.structure) < loop.max_effects:
            chosen, report = one_round(loop, current, size)
            steps.append(report)
            if chosen is None:
                return current, steps, 'no candidate lowers the held-out error enough', False
            current = chosen.fitted
        return current, steps, f'stopped at {loop.max_effects} effects', False
    except TimeBudgetExceeded:
        return current, steps, 'the time budget ran out: the best structure so far is kept', True


def discover_voltage_speed(records: Sequence[Record], fit: VoltageSpeedFit,
                           progress: Progress | None = None) -> VoltageSpeedDiscovery:
    """
    Search the effects of the voltage-to-speed model; refit the ones found on all the data.

    ``fit`` is the model without effects on all of the records (its order, first or
    second, is kept); the loop starts from it.  Past the time budget the best structure so
    far is kept (``out_of_time``).
    """
    loop = LoopState(list(records), torque_constant=1.0, vocabulary=VOLTAGE_SPEED_VOCABULARY,
                     progress=progress)
    size = len(fit.theta)
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
    found, steps, reason, out_of_time = search(loop, base, size)
    found, reason = never_worse(base, found, reason)
    summary = {'holdout_fraction': loop.holdout_fraction, 'min_gain_pct': 100 * loop.min_gain,
               'acceptance': loop.acceptance, 'reason': reason, 'steps': steps,
               'base_heldout_parameters': dict(base.values)}
    if not len(found.structure):
        return VoltageSpeedDiscovery(Structure(), None, list(records), [], summary, out_of_time)
    return _on_all_data(loop, fit, found, summary, out_of_time)


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
