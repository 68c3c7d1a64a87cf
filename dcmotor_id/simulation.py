"""Exact simulation of the DC motor with the voltage held over each sample (ZOH).

Between speed reversals the motor is linear with piecewise-constant inputs, so each sample
step is solved exactly with the matrix exponential (no integration error).  Coulomb friction
makes the model hybrid: when the speed reaches zero inside a sample, the crossing instant is
found on the exact closed-form solution (bisection to machine precision), and the shaft either
reverses, when the driving torque exceeds the Coulomb torque, or sticks.  While stuck the speed
is exactly zero, the armature current follows ``La di/dt = u - Ra i``, and the shaft breaks away
at the instant the driving torque magnitude exceeds the Coulomb torque.

Accuracy: the only approximations are the floating-point evaluation of the exponentials and
the root finding; test_simulation.py checks the result against an adaptive Runge-Kutta
reference (DOP853, rtol 1e-12, restarted at each event) to a relative error below 1e-8.

The stepping runs in one numba-compiled kernel (compiled once, cached on disk): a sample
costs tens of nanoseconds, which is what makes output-error fitting fast.

All functions here take and return SI units and never modify their inputs.
"""

from dataclasses import dataclass

import math

import numpy as np
from numba import njit

from dcmotor_id.model import state_matrix

@njit(cache=True)
def _flow_state(a, n, x0, x1, f0, f1, t, out):
    """Exact ``x(t)`` of ``dx/dt = A x + f`` (constant ``f``) from ``x(0)``; writes ``out``.

    ``n == 1``: the first state alone with ``A = [[a[0, 0]]]``; ``n == 2``: both states
    (``A`` must be invertible, which the motor's always is: ``det A = (Ra b + CPhi^2)/(La J)``).
    """
    if n == 1:
        rate = -a[0, 0]
        rt = rate * t
        if abs(rt) > 1e-12:
            phi = -math.expm1(-rt) / rate
        else:
            phi = t * (1.0 - 0.5 * rt)
        out[0] = x0 * math.exp(-rt) + f0 * phi
        return
    det = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    ss0 = -(a[1, 1] * f0 - a[0, 1] * f1) / det
    ss1 = -(-a[1, 0] * f0 + a[0, 0] * f1) / det
    y0 = x0 - ss0
    y1 = x1 - ss1
    half = 0.5 * (a[0, 0] + a[1, 1])
    n00 = a[0, 0] - half
    n11 = a[1, 1] - half
    delta = half * half - det
    if delta > 0.0:
        q = math.sqrt(delta) * t
        c = math.cosh(q)
        s = math.sinh(q) / q * t if q > 1e-8 else t * (1.0 + q * q / 6.0)
    elif delta < 0.0:
        q = math.sqrt(-delta) * t
        c = math.cos(q)
        s = math.sin(q) / q * t if q > 1e-8 else t * (1.0 - q * q / 6.0)
    else:
        c = 1.0
        s = t
    growth = math.exp(half * t)
    out[0] = growth * (c * y0 + s * (n00 * y0 + a[0, 1] * y1)) + ss0
    out[1] = growth * (c * y1 + s * (a[1, 0] * y0 + n11 * y1)) + ss1


@njit(cache=True)
def _drive(a, n, x0, g):
    """``dw/dt`` at ``w = 0`` without the Coulomb term."""
    if n == 1:
        return g[0]
    return a[1, 0] * x0 + g[1]


@njit(cache=True)
def _slip_sign(drive, friction_pos, friction_neg):
    if drive > friction_pos:
        return 1
    if drive < -friction_neg:
        return -1
    return 0


@njit(cache=True)
def _root(a, n, x0, x1, f0, f1, upper, stick, g, limit):
    """Bisection for the first instant in ``(0, upper]`` where the tracked quantity changes sign.

    Slip (``stick`` False): the speed ``x[-1]``.  Stick: ``drive - limit``.
    """
    out = np.empty(2)
    low = 0.0
    high = upper
    if stick:
        value_low = _drive(a, n, x0, g) - limit
    else:
        value_low = x1 if n == 2 else x0
    for _ in range(200):
        middle = 0.5 * (low + high)
        if middle <= low or middle >= high:
            break
        if stick:
            _flow_state(a, 1, x0, 0.0, f0, 0.0, middle, out)
            value = _drive(a, n, out[0], g) - limit
        else:
            _flow_state(a, n, x0, x1, f0, f1, middle, out)
            value = out[n - 1]
        if (value > 0.0) == (value_low > 0.0) and value != 0.0:
            low = middle
        else:
            high = middle
    return high


@njit(cache=True)
def _event_step(a, n, x, g, duration, friction_pos, friction_neg, new):
    """Solve one sample interval exactly through speed reversals and stick-slip."""
    out = np.empty(2)
    x0 = x[0]
    x1 = x[1] if n == 2 else 0.0
    remaining = duration
    w = x1 if n == 2 else x0
    if w > 0.0:
        sign = 1
    elif w < 0.0:
        sign = -1
    else:
        sign = _slip_sign(_drive(a, n, x0, g), friction_pos, friction_neg)
    for _ in range(8):
        if sign != 0:
            f0 = g[0]
            f1 = g[1] if n == 2 else 0.0
            friction = friction_pos if sign > 0 else -friction_neg
            if n == 2:
                f1 -= friction
            else:
                f0 -= friction
            _flow_state(a, n, x0, x1, f0, f1, remaining, out)
            w_end = out[n - 1]
            if w_end * sign > 0.0:
                new[0] = out[0]
                if n == 2:
                    new[1] = out[1]
                return
            t_zero = remaining if w_end == 0.0 else _root(a, n, x0, x1, f0, f1, remaining,
                                                           False, g, 0.0)
            _flow_state(a, n, x0, x1, f0, f1, t_zero, out)
            if n == 2:
                x0 = out[0]
                x1 = 0.0
            else:
                x0 = 0.0
            remaining -= t_zero
            sign = _slip_sign(_drive(a, n, x0, g), friction_pos, friction_neg)
            if remaining <= 0.0:
                break
            continue
        # Stuck: the speed stays zero while the driving torque is within friction.
        if n == 1:
            break
        _flow_state(a, 1, x0, 0.0, g[0], 0.0, remaining, out)
        drive_end = _drive(a, n, out[0], g)
        sign = _slip_sign(drive_end, friction_pos, friction_neg)
        if sign == 0:
            x0 = out[0]
            break
        limit = friction_pos if sign > 0 else -friction_neg
        t_break = _root(a, n, x0, 0.0, g[0], 0.0, remaining, True, g, limit)
        _flow_state(a, 1, x0, 0.0, g[0], 0.0, t_break, out)
        x0 = out[0]
        x1 = 0.0
        remaining -= t_break
        if remaining <= 0.0:
            break
    new[0] = x0
    if n == 2:
        new[1] = x1


@njit(cache=True)
def _discretise(a, n, dt):
    """Exact ZOH discretisation: ``Ad = exp(A dt)`` and ``Gamma = int_0^dt exp(A s) ds``."""
    ad = np.zeros((n, n))
    gamma = np.zeros((n, n))
    out = np.empty(2)
    for column in range(n):
        unit0 = 1.0 if column == 0 else 0.0
        unit1 = 1.0 if column == 1 else 0.0
        _flow_state(a, n, unit0, unit1, 0.0, 0.0, dt, out)
        for row in range(n):
            ad[row, column] = out[row]
        _flow_state(a, n, 0.0, 0.0, unit0, unit1, dt, out)
        for row in range(n):
            gamma[row, column] = out[row]
    return ad, gamma


@njit(cache=True)
def _simulate_kernel(a, forcing, friction_pos, friction_neg, x_start, dt):
    n_samples, n = forcing.shape
    ad, gamma = _discretise(a, n, dt)
    stick = _discretise(a, 1, dt)
    stick_ad = stick[0][0, 0]
    stick_gamma = stick[1][0, 0]
    states = np.empty((n_samples + 1, n))
    for column in range(n):
        states[0, column] = x_start[column]
    new = np.empty(2)
    for k in range(n_samples):
        w = states[k, n - 1]
        if w > 0.0:
            sign = 1
        elif w < 0.0:
            sign = -1
        else:
            sign = _slip_sign(_drive(a, n, states[k, 0], forcing[k]), friction_pos,
                              friction_neg)
        if sign != 0:
            friction = friction_pos if sign > 0 else -friction_neg
            if n == 2:
                f0 = forcing[k, 0]
                f1 = forcing[k, 1] - friction
                n0 = ad[0, 0] * states[k, 0] + ad[0, 1] * w + gamma[0, 0] * f0 + gamma[0, 1] * f1
                n1 = ad[1, 0] * states[k, 0] + ad[1, 1] * w + gamma[1, 0] * f0 + gamma[1, 1] * f1
            else:
                n0 = 0.0
                n1 = ad[0, 0] * w + gamma[0, 0] * (forcing[k, 0] - friction)
            if n1 * sign > 0.0:
                if n == 2:
                    states[k + 1, 0] = n0
                    states[k + 1, 1] = n1
                else:
                    states[k + 1, 0] = n1
                continue
        elif n == 2:
            i_end = stick_ad * states[k, 0] + stick_gamma * forcing[k, 0]
            if _slip_sign(_drive(a, n, i_end, forcing[k]), friction_pos, friction_neg) == 0:
                states[k + 1, 0] = i_end
                states[k + 1, 1] = 0.0
                continue
        else:
            states[k + 1, 0] = 0.0
            continue
        _event_step(a, n, states[k], forcing[k], dt, friction_pos, friction_neg, new)
        for column in range(n):
            states[k + 1, column] = new[column]
    return states


@dataclass(frozen=True)
class HybridSystem:
    """A linear system whose last state is a shaft speed with Coulomb friction.

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

    def simulate(self, forcing, x0, sample_period_s):
        """Simulate; return the states at the sample instants, shape ``(N + 1, n)``.

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
        return _simulate_kernel(a_matrix, forcing, float(self.friction_pos),
                                float(self.friction_neg), np.asarray(x0, dtype=float),
                                float(sample_period_s))


def motor_system(params):
    """Return the :class:`HybridSystem` of the full motor (state ``[i, w]``)."""
    friction = params.Mc / params.J
    return HybridSystem(state_matrix(params), friction, friction)


def motor_forcing(params, voltage, extra_voltage=None, extra_torque=None):
    """Build the forcing ``g = [u / La, tau / J]`` of the full motor, shape ``(N, 2)``."""
    voltage = np.asarray(voltage, dtype=float)
    forcing = np.zeros((voltage.shape[0], 2))
    forcing[:, 0] = voltage / params.La
    if extra_voltage is not None:
        forcing[:, 0] += np.asarray(extra_voltage, dtype=float) / params.La
    if extra_torque is not None:
        forcing[:, 1] = np.asarray(extra_torque, dtype=float) / params.J
    return forcing


def simulate_motor(params, voltage, sample_period_s, initial_state=(0.0, 0.0),
                   extra_voltage=None, extra_torque=None):
    """Simulate the motor exactly for a voltage held over each sample.

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


def simulate_mechanical(inertia, viscous, coulomb, torque, sample_period_s,
                        initial_speed=0.0, coulomb_neg=None):
    """Simulate the shaft alone, ``J dw/dt = torque - b w - Mc sgn(w)``, exactly.

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


class MotorStepper:
    """Advance the motor one sample at a time (for a real-time simulated drive).

    Parameters
    ----------
    params : MotorParameters
        The motor.
    sample_period_s : float
        The step [s].
    initial_state : tuple of float
        ``(i0, w0)``.

    """

    def __init__(self, params, sample_period_s, initial_state=(0.0, 0.0)):
        self.params = params
        self.sample_period_s = float(sample_period_s)
        self._system = motor_system(params)
        self.state = np.array(initial_state, dtype=float)

    def step(self, voltage, extra_torque=0.0, extra_voltage=0.0):
        """Hold ``voltage`` [V] for one period; return the new ``(current, speed)``."""
        forcing = motor_forcing(self.params, [voltage], [extra_voltage], [extra_torque])
        self.state = self._system.simulate(forcing, self.state, self.sample_period_s)[-1]
        return float(self.state[0]), float(self.state[1])
