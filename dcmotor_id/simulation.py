"""
Exact simulation of the DC motor with the voltage held over each sample (ZOH).

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

from numba import njit
import numpy as np

from dcmotor_id.model import state_matrix


@njit(cache=True)
def _flow_state(a, n, x0, x1, f0, f1, t, out):
    """
    Exact ``x(t)`` of ``dx/dt = A x + f`` (constant ``f``) from ``x(0)``; writes ``out``.

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
    """
    Bisection for the first instant in ``(0, upper]`` where the tracked quantity changes sign.

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
def _speed_slope(a, x0, x1, f1):
    """``dw/dt`` of the two-state system at state ``(x0, x1)`` with speed forcing ``f1``."""
    return a[1, 0] * x0 + a[1, 1] * x1 + f1


@njit(cache=True)
def _dip_time(a, x0, x1, f0, f1, upper, sign):
    """
    Instant at which a sliding speed touches zero inside ``(0, upper]`` and turns back.

    The speed of the two-state system can reach zero and return to its sign within one
    interval (it slows down, touches zero, and is driven back), so the same sign at both ends
    does not prove that no reversal or stick happened.  Between two turning points the speed is
    monotone; turning points of ``w`` are zeros of ``dw/dt``, at most one per chunk of length
    ``1.5 / omega`` (they are ``pi / omega`` apart when the modes oscillate, and there is at
    most one when they do not).  Returns the turning point ``t*`` (a minimum of ``sign * w``)
    with ``sign * w(t*) <= 0``, before which the speed crosses zero exactly once, or ``-1``.
    """
    out = np.empty(2)
    half = 0.5 * (a[0, 0] + a[1, 1])
    delta = half * half - (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
    chunks = 1
    if delta < 0.0:
        chunks = max(1, int(math.ceil(math.sqrt(-delta) * upper / 1.5)))
    start0 = x0
    start1 = x1
    t_start = 0.0
    for chunk in range(chunks):
        t_end = upper * (chunk + 1) / chunks
        _flow_state(a, 2, x0, x1, f0, f1, t_end, out)
        end0 = out[0]
        end1 = out[1]
        if sign * end1 <= 0.0:
            return t_end
        slope_start = sign * _speed_slope(a, start0, start1, f1)
        if slope_start < 0.0 and sign * _speed_slope(a, end0, end1, f1) > 0.0:
            low = t_start
            high = t_end
            for _ in range(200):
                middle = 0.5 * (low + high)
                if middle <= low or middle >= high:
                    break
                _flow_state(a, 2, x0, x1, f0, f1, middle, out)
                if sign * _speed_slope(a, out[0], out[1], f1) < 0.0:
                    low = middle
                else:
                    high = middle
            _flow_state(a, 2, x0, x1, f0, f1, high, out)
            if sign * out[1] <= 0.0:
                return high
        start0 = end0
        start1 = end1
        t_start = t_end
    return -1.0


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
            upper = remaining
            if w_end * sign > 0.0:
                # Same sign at the end: done, unless the speed touched zero on the way.  From
                # rest (just broken away or reversed) the speed leaves zero in the sign's
                # direction: the dip search would find its own start (round-off) and stall.
                upper = _dip_time(a, x0, x1, f0, f1, remaining, sign) \
                    if n == 2 and x1 != 0.0 else -1.0
                if upper < 0.0:
                    new[0] = out[0]
                    if n == 2:
                        new[1] = out[1]
                    return
            t_zero = remaining if w_end == 0.0 and upper == remaining else _root(
                a, n, x0, x1, f0, f1, upper, False, g, 0.0)
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
    # Modes oscillating fast against the sample period can turn the speed more than once per
    # sample: such systems always take the event path (see _dip_time).
    long_oscillation = False
    if n == 2:
        half = 0.5 * (a[0, 0] + a[1, 1])
        delta = half * half - (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
        long_oscillation = delta < 0.0 and math.sqrt(-delta) * dt > 1.5
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
                if n == 1:
                    states[k + 1, 0] = n1
                    continue
                # The speed keeps its sign at the end; it may still have touched zero inside
                # (slowing down, then driven back): only if it turned, i.e. its slope changed
                # from towards zero to away from it.
                turned = (sign * _speed_slope(a, states[k, 0], w, f1) < 0.0
                          and sign * _speed_slope(a, n0, n1, f1) > 0.0)
                if not (turned or long_oscillation):
                    states[k + 1, 0] = n0
                    states[k + 1, 1] = n1
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

    def simulate(self, forcing, x0, sample_period_s):
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


def simulate_mechanical(inertia, viscous, coulomb, torque, sample_period_s,
                        initial_speed=0.0, coulomb_neg=None):
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


@dataclass(frozen=True)
class MotorEffects:
    """
    True state-dependent effects to simulate (what :mod:`dcmotor_id.effects` describes).

    The vocabulary of :mod:`dcmotor_id.effects` turns each named effect into these fields;
    they add up.  Signs: torques are positive when they drive the shaft in the positive
    direction unless said otherwise, SI units.

    Attributes
    ----------
    load_torque_Nm : float
        Constant load torque ``T_L`` opposing positive rotation: ``J dw/dt = ... - T_L``.
    coulomb_delta_Nm : float
        Half-difference of the Coulomb friction: ``Mc + d`` for ``w > 0``, ``Mc - d`` for
        ``w < 0`` (also the break-away thresholds).
    viscous_delta_Nm_s : float
        Half-difference of the viscous friction: ``(b + d) w`` for ``w > 0``, ``(b - d) w``
        for ``w < 0``.
    stribeck_excess_Nm, stribeck_velocity_rad_s : float
        Friction magnitude ``Mc + excess exp(-(w / velocity)^2)``: static friction
        ``Mc + excess`` at rest.
    drag_Nm_s2 : float
        Quadratic drag, torque ``-c w |w|`` [N m s^2/rad^2].
    brush_drop_V : float
        Brush voltage drop ``-V_b sgn(i)`` in the armature circuit.
    resistance_rate_ohm_per_s : float
        ``Ra(t) = Ra + rate (t - t_0)``, ``t_0`` the record start.
    cogging_amplitude_Nm, cogging_cycles_per_rev, cogging_phase_rad : float
        Torque ripple ``A sin(N theta + phase)`` with shaft angle ``theta``.
    current_offset_A : float
        Offset of the current sensor: measured = true + offset.
    current_delay_samples, speed_delay_samples : int
        Whole-sample delay of a sensor: measured ``y[k] = y_true[k - d]``.

    """

    load_torque_Nm: float = 0.0
    coulomb_delta_Nm: float = 0.0
    viscous_delta_Nm_s: float = 0.0
    stribeck_excess_Nm: float = 0.0
    stribeck_velocity_rad_s: float = 1.0
    drag_Nm_s2: float = 0.0
    brush_drop_V: float = 0.0
    resistance_rate_ohm_per_s: float = 0.0
    cogging_amplitude_Nm: float = 0.0
    cogging_cycles_per_rev: float = 0.0
    cogging_phase_rad: float = 0.0
    current_offset_A: float = 0.0
    current_delay_samples: int = 0
    speed_delay_samples: int = 0

    def coefficients(self):
        """Pack the state-dependent fields for the kernel (float array)."""
        return np.array([self.load_torque_Nm, self.coulomb_delta_Nm, self.viscous_delta_Nm_s,
                         self.stribeck_excess_Nm, self.stribeck_velocity_rad_s,
                         self.drag_Nm_s2, self.brush_drop_V, self.resistance_rate_ohm_per_s,
                         self.cogging_amplitude_Nm, self.cogging_cycles_per_rev,
                         self.cogging_phase_rad], dtype=float)


def combine_effects(effects):
    """
    Return one :class:`MotorEffects` from ``None``, a MotorEffects or vocabulary effects.

    Vocabulary effects (:mod:`dcmotor_id.effects`) have ``motor_effects()`` returning a dict
    of :class:`MotorEffects` fields; additive fields add up, the others are set.
    """
    if effects is None:
        return MotorEffects()
    if isinstance(effects, MotorEffects):
        return effects
    total = {}
    replaced = {'stribeck_velocity_rad_s', 'cogging_cycles_per_rev', 'cogging_phase_rad'}
    for effect in effects:
        fields = effect if isinstance(effect, dict) else effect.motor_effects()
        for key, value in fields.items():
            if key in replaced or key not in total:
                total[key] = value
            else:
                total[key] += value
    return MotorEffects(**total)


@njit(cache=True)
def _speed_alone(a, w, g1, duration, friction_pos, friction_neg):
    """Speed after ``duration`` with no armature current (``i = 0``), stick-slip exact."""
    a1 = np.empty((1, 1))
    a1[0, 0] = a[1, 1]
    x = np.empty(2)
    x[0] = w
    x[1] = 0.0
    g = np.empty(2)
    g[0] = g1
    g[1] = 0.0
    out = np.empty(2)
    _event_step(a1, 1, x, g, duration, friction_pos, friction_neg, out)
    return out[0]


@njit(cache=True)
def _brush_step(a, x, u_la, g1, drop_la, duration, friction_pos, friction_neg, new):
    """
    One interval of the motor with a brush drop ``V_b`` (``drop_la = V_b / La``).

    The brushes drop ``V_b`` against the current and block it while ``|u - CPhi w| <= V_b``:
    the current is then held at zero and the shaft runs on alone.  Zero crossings of the
    current and the end of a blocked phase are located by bisection on the exact solution, so
    the only approximation left is the effect terms held over the sub-step.
    """
    state = np.empty(2)
    state[0] = x[0]
    state[1] = x[1]
    out = np.empty(2)
    g = np.empty(2)
    g[1] = g1
    remaining = duration
    for _ in range(6):
        if remaining <= 0.0:
            break
        i = state[0]
        w = state[1]
        net = u_la + a[0, 1] * w
        if i > 0.0:
            sign = 1
        elif i < 0.0:
            sign = -1
        elif net > drop_la:
            sign = 1
        elif net < -drop_la:
            sign = -1
        else:
            sign = 0
        if sign == 0:  # blocked: does it stay blocked to the end?
            w_end = _speed_alone(a, w, g1, remaining, friction_pos, friction_neg)
            if abs(u_la + a[0, 1] * w_end) <= drop_la:
                state[0] = 0.0
                state[1] = w_end
                break
            low = 0.0
            high = remaining
            for _ in range(100):
                middle = 0.5 * (low + high)
                if middle <= low or middle >= high:
                    break
                w_mid = _speed_alone(a, w, g1, middle, friction_pos, friction_neg)
                if abs(u_la + a[0, 1] * w_mid) <= drop_la:
                    low = middle
                else:
                    high = middle
            state[0] = 0.0
            state[1] = _speed_alone(a, w, g1, high, friction_pos, friction_neg)
            remaining -= high
            continue
        g[0] = u_la - sign * drop_la
        _event_step(a, 2, state, g, remaining, friction_pos, friction_neg, out)
        if out[0] * sign >= 0.0:
            state[0] = out[0]
            state[1] = out[1]
            break
        low = 0.0
        high = remaining
        for _ in range(100):
            middle = 0.5 * (low + high)
            if middle <= low or middle >= high:
                break
            _event_step(a, 2, state, g, middle, friction_pos, friction_neg, out)
            if out[0] * sign > 0.0:
                low = middle
            else:
                high = middle
        _event_step(a, 2, state, g, high, friction_pos, friction_neg, out)
        state[0] = 0.0
        state[1] = out[1]
        remaining -= high
    new[0] = state[0]
    new[1] = state[1]


@njit(cache=True)
def _effects_kernel(a0, n, forcing, coulomb, inertia, inductance, coefs, x_start, theta0, dt,
                    oversample, t_start):
    """
    Simulate with state-dependent effects frozen over sub-steps of ``dt / oversample``.

    Between sub-steps the linear part, the Coulomb friction, speed reversals and stick-slip are
    solved exactly by :func:`_event_step`; the effect torques and voltages (and ``Ra(t)``) are
    evaluated at the start of each sub-step and held over it (first order in the sub-step).
    Returns the states and the shaft angle at the sample instants.
    """
    n_samples = forcing.shape[0]
    load, c_delta, v_delta, s_excess, s_vel, drag, brush, ra_rate, cog_a, cog_n, cog_p = (
        coefs[0], coefs[1], coefs[2], coefs[3], coefs[4], coefs[5], coefs[6], coefs[7],
        coefs[8], coefs[9], coefs[10])
    states = np.empty((n_samples + 1, n))
    angles = np.empty(n_samples + 1)
    x = np.empty(2)
    new = np.empty(2)
    g = np.empty(2)
    a = a0.copy()
    for column in range(n):
        states[0, column] = x_start[column]
        x[column] = x_start[column]
    theta = theta0
    angles[0] = theta
    step = dt / oversample
    for k in range(n_samples):
        for sub in range(oversample):
            w = x[n - 1]
            time = t_start + k * dt + sub * step
            torque = -load - drag * w * abs(w) - v_delta * abs(w)
            if cog_a != 0.0:
                torque += cog_a * math.sin(cog_n * theta + cog_p)
            stribeck = 0.0
            if s_excess != 0.0:
                if s_vel != 0.0:
                    stribeck = s_excess * math.exp(-(w / s_vel) ** 2)
                elif w == 0.0:
                    stribeck = s_excess
            f_pos = max(coulomb + c_delta + stribeck, 0.0) / inertia
            f_neg = max(coulomb - c_delta + stribeck, 0.0) / inertia
            if n == 2:
                a[0, 0] = a0[0, 0] - ra_rate * time / inductance
                g[0] = forcing[k, 0]
                g[1] = forcing[k, 1] + torque / inertia
                if brush != 0.0:
                    _brush_step(a, x, g[0], g[1], brush / inductance, step, f_pos, f_neg, new)
                else:
                    _event_step(a, n, x, g, step, f_pos, f_neg, new)
            else:
                g[0] = forcing[k, 0] + torque / inertia
                g[1] = 0.0
                _event_step(a, n, x, g, step, f_pos, f_neg, new)
            theta += 0.5 * (w + new[n - 1]) * step
            for column in range(n):
                x[column] = new[column]
        for column in range(n):
            states[k + 1, column] = x[column]
        angles[k + 1] = theta
    return states, angles


def _delayed(values, samples):
    """``values`` seen by a sensor ``samples`` late (the first value held before the start)."""
    samples = int(samples)
    if samples <= 0:
        return values
    return np.concatenate([np.full(samples, values[0]), values[:-samples]])


def simulate_motor_effects(params, voltage, sample_period_s, effects, initial_state=(0.0, 0.0),
                           extra_voltage=None, extra_torque=None, oversample=10,
                           initial_angle_rad=0.0):
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
        The true effects (see :func:`combine_effects`).
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
    states, angles = _effects_kernel(
        np.ascontiguousarray(state_matrix(params)), 2, forcing, float(params.Mc),
        float(params.J), float(params.La), spec.coefficients(),
        np.asarray(initial_state, dtype=float), float(initial_angle_rad),
        float(sample_period_s), int(oversample), 0.0)
    current = _delayed(states[:-1, 0], spec.current_delay_samples) + spec.current_offset_A
    speed = _delayed(states[:-1, 1], spec.speed_delay_samples)
    return current, speed, angles[:-1].copy()


def simulate_mechanical_effects(inertia, viscous, coulomb, torque, sample_period_s, effects,
                                initial_speed=0.0, oversample=10, initial_angle_rad=0.0):
    """
    Simulate the shaft alone with true effects (mechanical-only counterpart).

    Electrical effects (brush drop, resistance drift, current offset and delay) do not apply
    here and are ignored.  Returns the measured speed and the true angle at the samples.
    """
    spec = combine_effects(effects)
    torque = np.asarray(torque, dtype=float)
    states, angles = _effects_kernel(
        np.array([[-viscous / inertia]]), 1, np.ascontiguousarray((torque / inertia)[:, None]),
        float(coulomb), float(inertia), 1.0, spec.coefficients(),
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
        True effects to simulate (:mod:`dcmotor_id.effects`); :meth:`step` then returns what
        the sensors measure (offset and delays applied).  Without effects the stepping is the
        exact one of :func:`simulate_motor`.
    oversample : int
        Sub-steps per sample for state-dependent effects.

    """

    def __init__(self, params, sample_period_s, initial_state=(0.0, 0.0), effects=None,
                 oversample=10):
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
            self._coefficients = spec.coefficients()
            self._a_matrix = np.ascontiguousarray(state_matrix(params))
            self._current_queue = [float(self.state[0])] * spec.current_delay_samples
            self._speed_queue = [float(self.state[1])] * spec.speed_delay_samples

    def step(self, voltage, extra_torque=0.0, extra_voltage=0.0):
        """Hold ``voltage`` [V] for one period; return the new ``(current, speed)``."""
        forcing = motor_forcing(self.params, [voltage], [extra_voltage], [extra_torque])
        if self.effects is None:
            self.state = self._system.simulate(forcing, self.state, self.sample_period_s)[-1]
            return float(self.state[0]), float(self.state[1])
        states, angles = _effects_kernel(
            self._a_matrix, 2, forcing, float(self.params.Mc), float(self.params.J),
            float(self.params.La), self._coefficients, self.state, self.angle_rad,
            self.sample_period_s, self.oversample, self.time_s)
        self.state = states[-1].copy()
        self.angle_rad = float(angles[-1])
        self.time_s += self.sample_period_s
        self._current_queue.append(float(self.state[0]))
        self._speed_queue.append(float(self.state[1]))
        current = self._current_queue.pop(0) + self.effects.current_offset_A
        speed = self._speed_queue.pop(0)
        return current, speed
