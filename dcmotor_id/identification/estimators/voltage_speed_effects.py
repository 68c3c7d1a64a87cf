"""
The voltage-to-speed model with effects on the shaft, in volts.

Without the current, a torque on the shaft enters the voltage-to-speed model as a voltage:
the shaft equation times ``Ra/CPhi`` reads ``kA dw/dt = u - kV w - kS sgn w - Ra T/CPhi``,
so a load torque ``T_L`` is the voltage ``Ra T_L/CPhi``, a Coulomb asymmetry ``d`` the
voltage ``Ra d/CPhi``, a viscous asymmetry ``d`` the gain ``Ra d/CPhi`` [V s/rad]; the split
into the torque and ``Ra/CPhi`` needs the current, as kS's does.

The effects arrive as a :class:`~dcmotor_id.simulation.MotorEffects` whose shaft fields
(:data:`SHAFT_FIELDS`) hold those voltages.  :class:`EffectModel` simulates the speed of the
first-order model (the shaft in volts, ``J = kA``: the voltages act as they are) or of the
second-order one (the exact motor of
:func:`~dcmotor_id.identification.estimators.voltage_speed.motor_of` at ``Ra`` = 1 Ohm, where a
voltage ``v`` on the shaft is the torque ``CPhi v``), exactly: the effects kernel of
:func:`~dcmotor_id.simulation.simulate_motor_effects`, sub-stepped only for a state-dependent
term.  :func:`fit_effects` fits it as the model without effects is fitted (output error on
the speed, one initial state per record).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Callable, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.estimators.voltage_speed import (_fit, channels, motor_of,
                                                                summary, theta_of,
                                                                VoltageSpeedFit)
from dcmotor_id.simulation import (MotorEffects, simulate_mechanical,
                                   simulate_mechanical_effects, simulate_motor,
                                   simulate_motor_effects)

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: The fields of :class:`~dcmotor_id.simulation.MotorEffects` that act on the shaft: in the
#: voltage-to-speed model their values are in volts (V, V s/rad).
SHAFT_FIELDS = ('load_torque_Nm', 'coulomb_delta_Nm', 'viscous_delta_Nm_s')
#: Shaft fields that depend on the state within a sample: simulated with sub-steps.
STATE_DEPENDENT = ('viscous_delta_Nm_s',)
#: No effect: the simulation of the model without effects.
NO_EFFECTS = MotorEffects()
#: Sub-steps per sample for a state-dependent term (as ``validate`` simulates it).
OVERSAMPLE = 10
#: Bounds of the base parameters (first, second order) as the fit without effects has them.
BOUNDS = {3: ([-np.inf, -np.inf, 0.0], [np.inf, np.inf, np.inf]),
          5: ([-np.inf, -np.inf, 0.0, -15.0, 1e-3], [np.inf, np.inf, np.inf, 0.0, 1.0])}


def on_the_motor(effects: MotorEffects, cphi: float) -> MotorEffects:
    """Return the effects with their shaft voltages as torques of a motor at 1 Ohm."""
    return effects._replace(**{name: getattr(effects, name) * cphi for name in SHAFT_FIELDS})


def oversample(effects: MotorEffects) -> int:
    """Return the sub-steps per sample the effects need (1 without a state-dependent term)."""
    return OVERSAMPLE if any(getattr(effects, name) for name in STATE_DEPENDENT) else 1


def simulate_with_effects(theta: np.ndarray, effects: MotorEffects, voltage: np.ndarray,
                          sample_period_s: float,
                          initial: Sequence[float] | np.ndarray) -> np.ndarray:
    """
    Return the speed of the voltage-to-speed model with effects (shaft fields in volts).

    ``theta`` holds 3 parameters (log kA, log kV, kS: the first-order model) or 5 (with the
    armature lag, :func:`~dcmotor_id.identification.estimators.voltage_speed.motor_of`);
    ``initial`` the speed (and the current at 1 Ohm).
    """
    if effects == NO_EFFECTS or effects == NO_EFFECTS._replace(
            load_torque_Nm=effects.load_torque_Nm):  # the linear simulation: faster
        return _with_load(theta, effects.load_torque_Nm, voltage, sample_period_s, initial)
    steps = oversample(effects)
    if theta.size == 3:
        speed, _ = simulate_mechanical_effects(
            math.exp(theta[0]), math.exp(theta[1]), float(theta[2]), voltage, sample_period_s,
            effects, float(initial[0]), oversample=steps)
        return speed
    motor = motor_of(theta)
    _, speed, _ = simulate_motor_effects(motor, voltage, sample_period_s,
                                         on_the_motor(effects, motor.CPhi),
                                         (float(initial[1]), float(initial[0])),
                                         oversample=steps)
    return speed


def _with_load(theta: np.ndarray, load: float, voltage: np.ndarray, sample_period_s: float,
               initial: Sequence[float] | np.ndarray) -> np.ndarray:
    """Return the speed with a constant load [V] alone (the simulation without effects)."""
    if theta.size == 3:
        return simulate_mechanical(math.exp(theta[0]), math.exp(theta[1]), float(theta[2]),
                                   voltage - load, sample_period_s, float(initial[0]))
    motor = motor_of(theta)
    torque = None if load == 0.0 else np.full(voltage.shape, -load * motor.CPhi)
    return simulate_motor(motor, voltage, sample_period_s, (float(initial[1]), float(initial[0])),
                          extra_torque=torque)[1]


def simulate_speed_effects(values: Mapping[str, float], voltage: np.ndarray,
                           sample_period_s: float, initial_speed: float,
                           lag: tuple[float, float] | None, effects: MotorEffects,
                           initial_drop: float | None = None) -> np.ndarray:
    """
    Return the speed [rad/s] of a reported model with effects (shaft fields in volts).

    The arguments of :func:`~dcmotor_id.identification.estimators.voltage_speed.
    simulate_speed` (kS, kV, kA, the lag as reported, the initial state), and the effects.
    """
    theta = theta_of(values, lag)
    voltage = np.asarray(voltage, dtype=float)
    initial = [initial_speed]
    if theta.size == 5:
        initial.append(initial_drop if initial_drop is not None else (  # at Ra = 1 Ohm
            float(voltage[0]) - motor_of(theta).CPhi * initial_speed if voltage.size else 0.0))
    return simulate_with_effects(theta, effects, voltage, sample_period_s, initial)


@dataclass(frozen=True)
class EffectModel:
    """
    The voltage-to-speed model of ``size`` base parameters with effect coefficients after them.

    Attributes
    ----------
    size : int
        3 (first order) or 5 (with the armature lag).
    effects : callable
        The effect coefficients (the parameter vector after the base) to a
        :class:`~dcmotor_id.simulation.MotorEffects` with its shaft fields in volts.

    """

    size: int
    effects: Callable[[np.ndarray], MotorEffects]

    @property
    def states(self) -> int:
        """Return the initial states per record: the speed, and with the lag the current."""
        return 1 if self.size == 3 else 2

    def __call__(self, theta: np.ndarray, record: Record, initial: np.ndarray) -> np.ndarray:
        """Return the speed of a record under the parameters ``theta``."""
        return simulate_with_effects(theta[:self.size], self.effects(theta[self.size:]),
                                     channels(record)[0], record.sample_period_s, initial)


def fit_effects(model: EffectModel, records: Sequence[Record], theta: np.ndarray,
                names: Sequence[str], initial: Sequence[Sequence[float]],
                progress: Progress | None = None, max_nfev: int = 400
                ) -> tuple[VoltageSpeedFit, np.ndarray] | None:
    """
    Fit the model with effects from ``theta`` (base then coefficients, named ``names``).

    Returns the fit (its ``coefficients`` in volts, with standard errors as the base's) and
    the whole fitted vector (parameters then initial states); None when it did not converge
    to finite values.
    """
    lower, upper = BOUNDS[model.size]
    extra = [-np.inf] * len(names), [np.inf] * len(names)
    with np.errstate(all='ignore'):  # a wild step may overflow; it is an infinite cost
        try:
            result = _fit(model, records, theta, (lower + extra[0], upper + extra[1]),
                          progress, initial, max_nfev)
        except ValueError:
            # scipy's trust region refuses a residual or Jacobian that overflowed (its SVD
            # checks for infs and NaNs): this candidate has no fit, as when it diverges.
            return None
    if not (np.all(np.isfinite(result.x)) and np.all(np.isfinite(result.fun))):
        return None
    return summary(result, model, records, {}, float('nan'), names=names), result.x
