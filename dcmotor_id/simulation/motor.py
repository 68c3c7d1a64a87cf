"""
Motor-level simulation: the exact ZOH hybrid solution of the motor or the shaft, with effects.

Between speed reversals the motor is linear with the voltage held over each sample, so each
sample step is solved exactly (:mod:`dcmotor_id.simulation.kernels`); Coulomb friction
(reversals, stick-slip) is located on the exact solution.  The state-dependent effects of a
:class:`~dcmotor_id.simulation.coefficients.MotorEffects` are held over sub-steps.

Accuracy: the only approximations are the floating-point evaluation of the exponentials and
the root finding; test_simulation.py checks the result against an adaptive Runge-Kutta
reference (DOP853, rtol 1e-12, restarted at each event) to a relative error below 1e-8.

All functions here take and return SI units and never modify their inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.core.model import MotorParameters, state_matrix
from dcmotor_id.simulation.coefficients import combine_effects, EffectsLike
from dcmotor_id.simulation.compiled import kernel


@dataclass(frozen=True)
class HybridSystem:
    """
    A linear system whose last state is a shaft speed with Coulomb friction.

    ``dx/dt = A x + g(t) - e_n F sgn(w)`` with ``w = x[-1]``, ``g`` held constant over each
    sample, friction magnitude ``F = friction_pos`` for ``w > 0`` and ``friction_neg`` for
    ``w < 0`` (in units of ``dw/dt``, i.e. torque / inertia).  At ``w = 0`` the shaft sticks
    while ``-friction_neg <= drive <= friction_pos``, where ``drive`` is ``dw/dt`` without the
    Coulomb term.

    Attributes
    ----------
    a_matrix : numpy.ndarray
        ``A``, 1x1 (speed only) or 2x2 (current, speed; invertible).
    friction_pos, friction_neg : float
        Coulomb friction magnitudes for positive and negative speed, >= 0.

    """

    a_matrix: np.ndarray
    friction_pos: float
    friction_neg: float

    def simulate(self, forcing: ArrayLike, x0: ArrayLike,
                 sample_period_s: float) -> np.ndarray:
        """
        Simulate; return the states at the sample instants, shape ``(N + 1, n)``.

        Parameters
        ----------
        forcing : numpy.ndarray
            ``g`` at each sample, shape ``(N, n)``; held over ``[t_k, t_k + dt)``.
        x0 : array_like
            Initial state.
        sample_period_s : float
            Sample period ``dt`` [s].

        """
        forcing = np.ascontiguousarray(forcing, dtype=float)
        a_matrix = np.ascontiguousarray(self.a_matrix, dtype=float)
        return kernel('simulate_kernel')(a_matrix, forcing, float(self.friction_pos),
                                         float(self.friction_neg),
                                         np.ascontiguousarray(x0, dtype=float),
                                         float(sample_period_s))


def motor_system(params: MotorParameters) -> HybridSystem:
    """Return the :class:`HybridSystem` of the full motor (state ``[i, w]``)."""
    friction = params.Mc / params.J
    return HybridSystem(state_matrix(params), friction, friction)


def motor_forcing(params: MotorParameters, voltage: ArrayLike,
                  extra_voltage: ArrayLike | None = None,
                  extra_torque: ArrayLike | None = None) -> np.ndarray:
    """Build the forcing ``g = [u / La, tau / J]`` of the full motor, shape ``(N, 2)``."""
    voltage = np.asarray(voltage, dtype=float)
    forcing = np.zeros((voltage.shape[0], 2))
    forcing[:, 0] = voltage / params.La
    if extra_voltage is not None:
        forcing[:, 0] += np.asarray(extra_voltage, dtype=float) / params.La
    if extra_torque is not None:
        forcing[:, 1] = np.asarray(extra_torque, dtype=float) / params.J
    return forcing


def simulate_motor(params: MotorParameters, voltage: ArrayLike, sample_period_s: float,
                   initial_state: Sequence[float] | np.ndarray = (0.0, 0.0),
                   extra_voltage: ArrayLike | None = None,
                   extra_torque: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
    """
    Simulate the motor exactly for a voltage held over each sample.

    Parameters
    ----------
    params : MotorParameters
        The motor.
    voltage : array_like
        Armature voltage ``u[k]`` [V], held over ``[t_k, t_k + dt)``.
    sample_period_s : float
        Sample period ``dt`` [s].
    initial_state : tuple of float
        ``(i0 [A], w0 [rad/s])`` at ``t_0``.
    extra_voltage, extra_torque : array_like, optional
        Further voltage added to ``u`` [V] and torque on the shaft [N m], per sample.

    Returns
    -------
    current, speed : numpy.ndarray
        ``i[k]`` and ``w[k]`` at the sample instants, same length as ``voltage``.

    """
    forcing = motor_forcing(params, voltage, extra_voltage, extra_torque)
    states = motor_system(params).simulate(forcing, initial_state, sample_period_s)
    return states[:-1, 0].copy(), states[:-1, 1].copy()


def held_input(samples: ArrayLike) -> np.ndarray:
    """
    Return the mechanical-only model's input held over each sample: the mean of its two ends.

    The sampled current of the mechanical-only model (``--torque-constant``) varies within a
    sample; the torque held over ``[t_k, t_k+1)`` is the trapezoidal mean
    ``(i[k] + i[k+1]) / 2`` (the last sample held as it is).  The fit, the validation and the
    simulated records of the benchmarks take this one definition, so that a record simulated
    with the true parameters is the fit's model exactly.

    Parameters
    ----------
    samples : array_like
        The input at the sample instants (a current [A] or a torque [N m]).

    Returns
    -------
    numpy.ndarray
        The value held over each sample, same length.

    """
    samples = np.asarray(samples, dtype=float)
    return np.append(0.5 * (samples[:-1] + samples[1:]), samples[-1:])


def simulate_mechanical(inertia: float, viscous: float, coulomb: float, torque: ArrayLike,
                        sample_period_s: float, initial_speed: float = 0.0,
                        coulomb_neg: float | None = None) -> np.ndarray:
    """
    Simulate the shaft alone, ``J dw/dt = torque - b w - Mc sgn(w)``, exactly.

    Parameters
    ----------
    inertia, viscous, coulomb : float
        ``J`` [kg m^2], ``b`` [N m s/rad], ``Mc`` [N m] (for positive speed).
    torque : array_like
        Applied torque per sample [N m], held over each sample.
    sample_period_s : float
        Sample period [s].
    initial_speed : float
        Speed at ``t_0`` [rad/s].
    coulomb_neg : float, optional
        Coulomb friction for negative speed when it differs [N m].

    Returns
    -------
    numpy.ndarray
        Speed at the sample instants [rad/s].

    """
    torque = np.asarray(torque, dtype=float)
    neg = coulomb if coulomb_neg is None else coulomb_neg
    system = HybridSystem(np.array([[-viscous / inertia]]), coulomb / inertia, neg / inertia)
    states = system.simulate((torque / inertia)[:, None], [initial_speed], sample_period_s)
    return states[:-1, 0].copy()


def _delayed(values: np.ndarray, samples: int) -> np.ndarray:
    """``values`` seen by a sensor ``samples`` late (the first value held before the start)."""
    samples = int(samples)
    if samples <= 0:
        return values
    return np.concatenate([np.full(samples, values[0]), values[:-samples]])


def simulate_motor_effects(params: MotorParameters, voltage: ArrayLike, sample_period_s: float,
                           effects: EffectsLike,
                           initial_state: Sequence[float] | np.ndarray = (0.0, 0.0),
                           extra_voltage: ArrayLike | None = None,
                           extra_torque: ArrayLike | None = None, oversample: int = 10,
                           initial_angle_rad: float = 0.0
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Simulate the motor with true state-dependent effects; return what sensors measure.

    The linear part and the Coulomb friction (reversals, stick-slip) are solved exactly as in
    :func:`simulate_motor`; effect terms that depend on the state are held over sub-steps of
    ``sample_period_s / oversample``.  With no effects the result equals
    :func:`simulate_motor` to round-off.

    Parameters
    ----------
    params : MotorParameters
        The motor.
    voltage : array_like
        Armature voltage per sample [V], held over each sample.
    sample_period_s : float
        Sample period [s].
    effects : MotorEffects or sequence of vocabulary effects
        The true effects (see
        :func:`~dcmotor_id.simulation.coefficients.combine_effects`).
    initial_state : tuple of float
        ``(i0, w0)``.
    extra_voltage, extra_torque : array_like, optional
        Further voltage [V] and torque [N m] per sample.
    oversample : int
        Sub-steps per sample for the state-dependent terms.
    initial_angle_rad : float
        Shaft angle at ``t_0`` (cogging).

    Returns
    -------
    current, speed, angle : numpy.ndarray
        Measured current [A] and speed [rad/s] (with sensor offset and delays applied) and the
        true shaft angle [rad] at the sample instants.

    """
    spec = combine_effects(effects)
    forcing = motor_forcing(params, voltage, extra_voltage, extra_torque)
    states, angles = kernel('effects_kernel')(
        np.ascontiguousarray(state_matrix(params)), 2, forcing, float(params.Mc),
        float(params.J), float(params.La), spec,
        np.asarray(initial_state, dtype=float), float(initial_angle_rad),
        float(sample_period_s), int(oversample), 0.0)
    current = _delayed(states[:-1, 0], spec.current_delay_samples) + spec.current_offset_A
    speed = _delayed(states[:-1, 1], spec.speed_delay_samples)
    return current, speed, angles[:-1].copy()


def simulate_mechanical_effects(inertia: float, viscous: float, coulomb: float,
                                torque: ArrayLike, sample_period_s: float, effects: EffectsLike,
                                initial_speed: float = 0.0, oversample: int = 10,
                                initial_angle_rad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """
    Simulate the shaft alone with true effects (mechanical-only counterpart).

    Electrical effects (brush drop, resistance drift, current offset and delay) do not apply
    here and are ignored.  Returns the measured speed and the true angle at the samples.
    """
    spec = combine_effects(effects)
    torque = np.asarray(torque, dtype=float)
    states, angles = kernel('effects_kernel')(
        np.array([[-viscous / inertia]]), 1, np.ascontiguousarray((torque / inertia)[:, None]),
        float(coulomb), float(inertia), 1.0, spec,
        np.array([initial_speed], dtype=float), float(initial_angle_rad),
        float(sample_period_s), int(oversample), 0.0)
    return _delayed(states[:-1, 0], spec.speed_delay_samples), angles[:-1].copy()


class MotorStepper:
    """
    Advance the motor one sample at a time (for a real-time simulated drive).

    Parameters
    ----------
    params : MotorParameters
        The motor.
    sample_period_s : float
        The step [s].
    initial_state : tuple of float
        ``(i0, w0)``.
    effects : MotorEffects or sequence of vocabulary effects, optional
        True effects to simulate (:mod:`dcmotor_id.identification.effects`); :meth:`step` then
        returns what
        the sensors measure (offset and delays applied).  Without effects the stepping is the
        exact one of :func:`simulate_motor`.
    oversample : int
        Sub-steps per sample for state-dependent effects.

    """

    def __init__(self, params: MotorParameters, sample_period_s: float,
                 initial_state: Sequence[float] | np.ndarray = (0.0, 0.0),
                 effects: EffectsLike = None,
                 oversample: int = 10) -> None:
        self.params = params
        self.sample_period_s = float(sample_period_s)
        self._system = motor_system(params)
        self.state = np.array(initial_state, dtype=float)
        self.effects = None if effects is None else combine_effects(effects)
        self.oversample = int(oversample)
        self.angle_rad = 0.0
        self.time_s = 0.0
        if self.effects is not None:
            spec = self.effects
            self._a_matrix = np.ascontiguousarray(state_matrix(params))
            self._current_queue = [float(self.state[0])] * spec.current_delay_samples
            self._speed_queue = [float(self.state[1])] * spec.speed_delay_samples

    def step(self, voltage: float, extra_torque: float = 0.0,
             extra_voltage: float = 0.0) -> tuple[float, float]:
        """Hold ``voltage`` [V] for one period; return the new ``(current, speed)``."""
        forcing = motor_forcing(self.params, [voltage], [extra_voltage], [extra_torque])
        if self.effects is None:
            self.state = self._system.simulate(forcing, self.state, self.sample_period_s)[-1]
            return float(self.state[0]), float(self.state[1])
        states, angles = kernel('effects_kernel')(
            self._a_matrix, 2, forcing, float(self.params.Mc), float(self.params.J),
            float(self.params.La), self.effects, self.state, self.angle_rad,
            self.sample_period_s, self.oversample, self.time_s)
        self.state = states[-1].copy()
        self.angle_rad = float(angles[-1])
        self.time_s += self.sample_period_s
        self._current_queue.append(float(self.state[0]))
        self._speed_queue.append(float(self.state[1]))
        current = self._current_queue.pop(0) + self.effects.current_offset_A
        speed = self._speed_queue.pop(0)
        return current, speed


def zoh_matrices(a_matrix: ArrayLike, sample_period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Exact ZOH discretisation of ``dx/dt = A x + g`` (``g`` held over the sample).

    Parameters
    ----------
    a_matrix : array_like
        ``A``, 1x1 or 2x2 (invertible), as :func:`~dcmotor_id.core.model.state_matrix` returns.
    sample_period_s : float
        Sample period ``dt`` [s].

    Returns
    -------
    ad, gamma : numpy.ndarray
        ``Ad = exp(A dt)`` and ``Gamma = int_0^dt exp(A s) ds``, so that
        ``x[k+1] = Ad x[k] + Gamma g[k]`` between speed reversals; the same closed form the
        simulation kernels use.

    """
    a_matrix = np.ascontiguousarray(np.atleast_2d(np.asarray(a_matrix, dtype=float)))
    return kernel('discretise')(a_matrix, a_matrix.shape[0], float(sample_period_s))
