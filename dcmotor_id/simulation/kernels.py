"""
The numba kernels of the exact hybrid ZOH simulation (compiled once, cached on disk).

Between speed reversals the motor is linear with piecewise-constant inputs, so each sample
step is solved exactly with the closed-form matrix exponential of a 2x2 (or 1x1) system.
Coulomb friction makes the model hybrid: when the speed reaches zero inside a sample, the
crossing instant is found on the exact solution (bisection to machine precision), and the shaft
either reverses, when the driving torque exceeds the Coulomb torque, or sticks.  While stuck the
speed is exactly zero, the armature current follows ``La di/dt = u - Ra i``, and the shaft
breaks away at the instant the driving torque magnitude exceeds the Coulomb torque.

The entry points are :func:`simulate_kernel` (linear part and Coulomb friction, exact),
:func:`effects_kernel` (plus the state-dependent effects of a
:class:`~dcmotor_id.simulation.coefficients.MotorEffects`, read by field name, held over
sub-steps) and :func:`discretise` (the exact ZOH matrices).  A sample costs tens of
nanoseconds, which is what makes output-error fitting fast.  Arrays only: the motor-level
functions in :mod:`dcmotor_id.simulation.motor` build them.  :func:`sosfilt_kernel` is the
recursion of the zero-phase filter of :mod:`dcmotor_id.signals.filters`.  The callers take the
kernels
through :func:`dcmotor_id.simulation.compiled.kernel` (ahead-of-time machine code when the
set-up built it).
"""

import math

from numba import njit
import numpy as np

#: Most chunks of ``1.5 / omega`` one sample interval is searched in for a speed turn.  Modes
#: oscillating faster (more than a few hundred turns per sample) belong to absurd trial
#: parameters of a wandering fit (issue 21: ``Ra = 0, CPhi = 4.6e23`` took hours): the kernels
#: return non-finite results for them at once, which the fits reject as a failed step.
MAX_TURN_CHUNKS = 512


@njit(cache=True)
def too_fast(a, n, dt):
    """Whether ``A``'s modes oscillate more than :data:`MAX_TURN_CHUNKS` times per ``dt``."""
    if n != 2:
        return False
    half = 0.5 * (a[0, 0] + a[1, 1])
    delta = half * half - (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
    return delta < 0.0 and math.sqrt(-delta) * dt > 1.5 * MAX_TURN_CHUNKS


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
def _initial_sign(a, n, x0, x1, g, friction_pos, friction_neg):
    """
    Return the direction of sliding at the start of an interval from ``(x0, x1)`` (or ``x0``).

    The sign of the speed, else (at rest) the direction the driving torque breaks away to, or
    ``0`` when it stays within friction (stuck).
    """
    w = x1 if n == 2 else x0
    if w > 0.0:
        return 1
    if w < 0.0:
        return -1
    return _slip_sign(_drive(a, n, x0, g), friction_pos, friction_neg)


@njit(cache=True)
def _forcing(g, n, sign, friction_pos, friction_neg):
    """Return the forcing ``(f0, f1)`` while sliding with ``sign`` (Coulomb term on ``w``)."""
    f0 = g[0]
    f1 = g[1] if n == 2 else 0.0
    friction = friction_pos if sign > 0 else -friction_neg
    if n == 2:
        f1 -= friction
    else:
        f0 -= friction
    return f0, f1


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
        # Bounded: beyond MAX_TURN_CHUNKS the kernels refuse the parameters (too_fast).
        count = math.sqrt(-delta) * upper / 1.5
        chunks = MAX_TURN_CHUNKS if count > MAX_TURN_CHUNKS else max(1, int(math.ceil(count)))
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
def _stuck_time(a, n, x0, g, duration, friction_pos, friction_neg, out):
    """
    Return how long a stuck shaft (current ``x0``) stays stuck within ``duration``.

    Returns ``(sign, time)``: ``(0, duration)`` when the driving torque stays within friction
    to the end, else the direction and the instant of the break-away.  ``out[0]`` gets the
    current at ``time``.
    """
    _flow_state(a, 1, x0, 0.0, g[0], 0.0, duration, out)
    sign = _slip_sign(_drive(a, n, out[0], g), friction_pos, friction_neg)
    if sign == 0:
        return 0, duration
    limit = friction_pos if sign > 0 else -friction_neg
    t_break = _root(a, n, x0, 0.0, g[0], 0.0, duration, True, g, limit)
    _flow_state(a, 1, x0, 0.0, g[0], 0.0, t_break, out)
    return sign, t_break


@njit(cache=True)
def _event_step(a, n, x, g, duration, friction_pos, friction_neg, new):
    """Solve one sample interval exactly through speed reversals and stick-slip."""
    out = np.empty(2)
    x0 = x[0]
    x1 = x[1] if n == 2 else 0.0
    remaining = duration
    sign = _initial_sign(a, n, x0, x1, g, friction_pos, friction_neg)
    for _ in range(8):
        if sign != 0:
            f0, f1 = _forcing(g, n, sign, friction_pos, friction_neg)
            # Written out here and in _event_step_sens: as a helper, this hot part cost
            # effects_kernel 10-20 % (measured).
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
        sign, t_stuck = _stuck_time(a, n, x0, g, remaining, friction_pos, friction_neg, out)
        x0 = out[0]
        if sign == 0:
            break
        x1 = 0.0
        remaining -= t_stuck
        if remaining <= 0.0:
            break
    new[0] = x0
    if n == 2:
        new[1] = x1


@njit(cache=True)
def discretise(a, n, dt):
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
def simulate_kernel(a, forcing, friction_pos, friction_neg, x_start, dt):
    n_samples, n = forcing.shape
    ad, gamma = discretise(a, n, dt)
    stick = discretise(a, 1, dt)
    stick_ad = stick[0][0, 0]
    stick_gamma = stick[1][0, 0]
    states = np.empty((n_samples + 1, n))
    for column in range(n):
        states[0, column] = x_start[column]
    if too_fast(a, n, dt):
        states[1:, :] = np.nan
        return states
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
def _slide_step(w, drive, decay, gain, friction_pos, friction_neg, new):
    """
    One sub-step of the shaft alone that keeps sliding one way; False when it does not.

    ``decay`` and ``gain`` are ``exp(A h)`` and ``int_0^h exp(A s) ds`` of the sub-step:
    :func:`_event_step`'s first sliding phase, which ends the sub-step when the speed keeps
    its sign.  Otherwise (at rest, stuck, or reaching zero) the caller takes the event path.
    """
    if w > 0.0:
        sign = 1
    elif w < 0.0:
        sign = -1
    else:
        sign = _slip_sign(drive, friction_pos, friction_neg)
    if sign == 0:
        return False
    friction = friction_pos if sign > 0 else -friction_neg
    w_end = w * decay + (drive - friction) * gain
    if w_end * sign > 0.0:
        new[0] = w_end
        return True
    return False


@njit(cache=True)
def effects_kernel(a0, n, forcing, coulomb, inertia, inductance, effects, x_start, theta0, dt,
                   oversample, t_start):
    """
    Simulate with state-dependent effects frozen over sub-steps of ``dt / oversample``.

    Between sub-steps the linear part, the Coulomb friction, speed reversals and stick-slip are
    solved exactly by :func:`_event_step`; the effect torques and voltages (and ``Ra(t)``) are
    evaluated at the start of each sub-step and held over it (first order in the sub-step).
    ``effects`` is a :class:`~dcmotor_id.simulation.coefficients.MotorEffects` (its sensor
    fields are applied by the caller).  Returns the states and the shaft angle at the sample
    instants.
    """
    n_samples = forcing.shape[0]
    load = effects.load_torque_Nm
    c_delta = effects.coulomb_delta_Nm
    v_delta = effects.viscous_delta_Nm_s
    s_excess = effects.stribeck_excess_Nm
    s_vel = effects.stribeck_velocity_rad_s
    drag = effects.drag_Nm_s2
    brush = effects.brush_drop_V
    ra_rate = effects.resistance_rate_ohm_per_s
    cog_a = effects.cogging_amplitude_Nm
    cog_n = effects.cogging_cycles_per_rev
    cog_p = effects.cogging_phase_rad
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
    if too_fast(a0, n, step):
        states[1:, :] = np.nan
        angles[1:] = np.nan
        return states, angles
    # The shaft alone (n == 1) has a constant A: a sub-step that slides without reaching zero
    # is _flow_state's solution with these factors, computed once (the same operations, so the
    # same values); other sub-steps take _event_step.
    rate = -a0[0, 0]
    rt = rate * step
    decay = math.exp(-rt)
    gain = -math.expm1(-rt) / rate if abs(rt) > 1e-12 else step * (1.0 - 0.5 * rt)
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
                if not _slide_step(x[0], g[0], decay, gain, f_pos, f_neg, new):
                    _event_step(a, n, x, g, step, f_pos, f_neg, new)
            theta += 0.5 * (w + new[n - 1]) * step
            for column in range(n):
                x[column] = new[column]
        for column in range(n):
            states[k + 1, column] = x[column]
        angles[k + 1] = theta
    return states, angles


@njit(cache=True)
def sosfilt_kernel(sos, values, state):  # pragma: no cover - compiled
    """Run second-order sections over ``values`` in place from ``state`` (transposed form II)."""
    for n in range(values.shape[0]):
        current = values[n]
        for s in range(sos.shape[0]):
            new = sos[s, 0] * current + state[s, 0]
            state[s, 0] = sos[s, 1] * current - sos[s, 4] * new + state[s, 1]
            state[s, 1] = sos[s, 2] * current - sos[s, 5] * new
            current = new
        values[n] = current
