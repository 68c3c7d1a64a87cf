"""
Output sensitivities of the exact hybrid simulation, and the normal equations they give.

The kernel :func:`normal_kernel` runs the same exact hybrid ZOH solution as
:func:`~dcmotor_id.simulation.kernels.simulate_kernel` (the states are bit-identical) and
propagates beside the state ``x = [i, w]`` (or ``[w]``) its sensitivity ``S = dx/dp`` to every
column ``p`` (the physical parameters, the coefficients of linear terms, the asymmetric Coulomb
friction and the initial state).  Between events the augmented linear system

    d/dt [x; S_j] = [[A, 0], [dA/dp_j, A]] [x; S_j] + [f; df/dp_j]

is solved exactly by its ZOH solution (Van Loan's block exponential; once per run for a whole
sample, per sub-interval at the rare events).  At an event the sensitivity jumps by the
saltation rule ``S+ = S- + (f- - f+) dtau/dp`` with ``dtau/dp = -S-_w / wdot-`` (the event is
``w = 0``):

* speed reversal (``w`` crosses zero, Coulomb term flips): ``S+_w = S-_w wdot+ / wdot-``,
  the current's sensitivity is continuous;
* slip to stick: ``S+_w = 0`` (the speed is identically zero while stuck);
* stick to slip (break-away when the driving torque reaches the friction level): the vector
  field is continuous there (the speed leaves zero with zero slope), no jump.

The kernel never stores the ``2N x p`` Jacobian: it accumulates the normal equations
``J^T J``, ``J^T r``, the cost, per-channel residual sums of squares and the score sums
``J^T r`` over blocks of samples (for a robust covariance), with rows weighted by the inverse
noise level of each channel.  Optionally it stores the trajectory of ``x`` and ``S`` (tests,
short records).
"""

import math

from numba import njit
import numpy as np

from dcmotor_id.simulation.kernels import (_dip_time, _drive, _event_step, _flow_state, _forcing,
                                           _initial_sign, _root, _slip_sign, _speed_slope,
                                           _stuck_time, discretise, too_fast)


@njit(cache=True)
def _mul_add(out, a, b, factor):
    """``out += factor * a @ b`` for small square matrices."""
    size = a.shape[0]
    for i in range(size):
        for k in range(size):
            aik = a[i, k] * factor
            if aik != 0.0:
                for j in range(size):
                    out[i, j] += aik * b[k, j]


@njit(cache=True)
def flow_matrices(a, da, n, tau):
    """
    ZOH matrices of the state and its sensitivities over ``tau``.

    Returns ``ad = exp(A tau)``, ``gd = int_0^tau exp(A s) ds`` and, per column ``j``,
    ``dad[j]``, ``dgd[j]``: their derivatives in the direction ``da[j] = dA/dp_j`` (the blocks
    of the exponential of ``[[A, 0, I], [dA, A, 0], [0, 0, 0]] tau``).  Scaling and squaring
    with a Taylor series differentiated term by term: ``d(A^k) = A d(A^(k-1)) + dA A^(k-1)``
    and, per squaring, ``E(2t) = E^2``, ``G(2t) = G + E G`` and their product rules.  The
    scaled ``A t`` has norm <= 0.5, so 14 terms are exact to round-off; written here because
    numba has no ``expm`` (let alone its Frechet derivative), and a general block exponential
    costs a hundred times more.
    """
    m = da.shape[0]
    norm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(a[i, j])
        norm = max(norm, row * tau)
    squarings = 0
    if norm > 0.5:
        squarings = int(math.ceil(math.log(norm / 0.5) / math.log(2.0)))
    t = tau * 0.5 ** squarings
    at = a * t
    ad = np.eye(n)
    gd = np.eye(n) * t
    power = np.eye(n)
    dad = np.zeros((m, n, n))
    dgd = np.zeros((m, n, n))
    dpower = np.zeros((m, n, n))
    active = np.zeros(m, dtype=np.bool_)
    for j in range(m):
        for r in range(n):
            for c in range(n):
                if da[j, r, c] != 0.0:
                    active[j] = True
    new_power = np.empty((n, n))
    new_dpower = np.empty((n, n))
    for order in range(1, 15):
        for j in range(m):
            if not active[j]:
                continue
            new_dpower[:, :] = 0.0
            _mul_add(new_dpower, dpower[j], at, 1.0 / order)
            _mul_add(new_dpower, power, da[j], t / order)
            for r in range(n):
                for c in range(n):
                    dpower[j, r, c] = new_dpower[r, c]
                    dad[j, r, c] += new_dpower[r, c]
                    dgd[j, r, c] += t * new_dpower[r, c] / (order + 1)
        new_power[:, :] = 0.0
        _mul_add(new_power, power, at, 1.0 / order)
        for r in range(n):
            for c in range(n):
                power[r, c] = new_power[r, c]
                ad[r, c] += new_power[r, c]
                gd[r, c] += t * new_power[r, c] / (order + 1)
    e2 = np.empty((n, n))
    g2 = np.empty((n, n))
    d2 = np.empty((n, n))
    h2 = np.empty((n, n))
    for _ in range(squarings):
        for j in range(m):
            if not active[j]:
                continue
            d2[:, :] = 0.0
            _mul_add(d2, dad[j], ad, 1.0)
            _mul_add(d2, ad, dad[j], 1.0)
            h2[:, :] = dgd[j]
            _mul_add(h2, dad[j], gd, 1.0)
            _mul_add(h2, ad, dgd[j], 1.0)
            dad[j] = d2
            dgd[j] = h2
        e2[:, :] = 0.0
        _mul_add(e2, ad, ad, 1.0)
        g2[:, :] = gd
        _mul_add(g2, ad, gd, 1.0)
        ad[:, :] = e2
        gd[:, :] = g2
    return ad, gd, dad, dgd


@njit(cache=True)
def _propagate(n, ad, gd, dad, dgd, x, f, s, df, out):
    """``S(tau) = Ad S + dAd x + dGd f + Gd df`` for every column (``out`` may not be ``s``)."""
    m = s.shape[1]
    for j in range(m):
        for r in range(n):
            value = 0.0
            for c in range(n):
                value += (ad[r, c] * s[c, j] + dad[j, r, c] * x[c] + dgd[j, r, c] * f[c]
                          + gd[r, c] * df[c, j])
            # A decaying sensitivity (of an initial state) would end as a subnormal number
            # that rounds to itself: every operation on it costs a hundred cycles.
            out[r, j] = value if abs(value) > 1e-100 else 0.0


@njit(cache=True)
def _flow_sens(a, da, n, x, f, s, df, tau, out):
    """Propagate the sensitivities over a sub-interval of length ``tau`` (events only)."""
    ad, gd, dad, dgd = flow_matrices(a, da, n, tau)
    _propagate(n, ad, gd, dad, dgd, x, f, s, df, out)


@njit(cache=True)
def _stuck_sens(a, da, x0, g0, s, dg, tau):
    """Stuck shaft: propagate the current's sensitivity over ``tau`` (speed's stays zero)."""
    m = s.shape[1]
    a1 = np.empty((1, 1))
    a1[0, 0] = a[0, 0]
    da1 = np.empty((m, 1, 1))
    for j in range(m):
        da1[j, 0, 0] = da[j, 0, 0]
    x = np.empty(1)
    x[0] = x0
    f = np.empty(1)
    f[0] = g0
    s1 = np.empty((1, m))
    df1 = np.empty((1, m))
    for j in range(m):
        s1[0, j] = s[0, j]
        df1[0, j] = dg[0, j]
    out = np.empty((1, m))
    _flow_sens(a1, da1, 1, x, f, s1, df1, tau, out)
    for j in range(m):
        s[0, j] = out[0, j]
        s[1, j] = 0.0


@njit(cache=True)
def _slip_forcing_derivative(n, dg, sign, dfric_pos, dfric_neg, df):
    """``df/dp`` while sliding with ``sign``: the forcing's and the friction level's."""
    m = dg.shape[1]
    for j in range(m):
        for r in range(n):
            df[r, j] = dg[r, j]
        if sign > 0:
            df[n - 1, j] -= dfric_pos[j]
        else:
            df[n - 1, j] += dfric_neg[j]


@njit(cache=True)
def _event_step_sens(a, da, n, x, s, g, dg, duration, friction_pos, friction_neg, dfric_pos,
                     dfric_neg, new, new_s):
    """
    One sample interval through reversals and stick-slip, with the sensitivities.

    The state follows exactly the steps of :func:`~dcmotor_id.simulation.kernels._event_step`
    (same calls, same numbers); the sensitivities follow each sub-interval and jump at each
    event (module docstring).
    """
    m = s.shape[1]
    out = np.empty(2)
    sc = np.empty((n, m))
    tmp = np.empty((n, m))
    df = np.empty((n, m))
    for r in range(n):
        for j in range(m):
            sc[r, j] = s[r, j]
    xs = np.empty(n)
    fv = np.empty(n)
    x0 = x[0]
    x1 = x[1] if n == 2 else 0.0
    remaining = duration
    sign = _initial_sign(a, n, x0, x1, g, friction_pos, friction_neg)
    for _ in range(8):
        if sign != 0:
            f0, f1 = _forcing(g, n, sign, friction_pos, friction_neg)
            fv[0] = f0
            if n == 2:
                fv[1] = f1
            xs[0] = x0
            if n == 2:
                xs[1] = x1
            _slip_forcing_derivative(n, dg, sign, dfric_pos, dfric_neg, df)
            _flow_state(a, n, x0, x1, f0, f1, remaining, out)
            w_end = out[n - 1]
            upper = remaining
            if w_end * sign > 0.0:
                upper = _dip_time(a, x0, x1, f0, f1, remaining, sign) \
                    if n == 2 and x1 != 0.0 else -1.0
                if upper < 0.0:
                    new[0] = out[0]
                    if n == 2:
                        new[1] = out[1]
                    _flow_sens(a, da, n, xs, fv, sc, df, remaining, new_s)
                    return
            t_zero = remaining if w_end == 0.0 and upper == remaining else _root(
                a, n, x0, x1, f0, f1, upper, False, g, 0.0)
            _flow_state(a, n, x0, x1, f0, f1, t_zero, out)
            _flow_sens(a, da, n, xs, fv, sc, df, t_zero, tmp)
            for r in range(n):
                for j in range(m):
                    sc[r, j] = tmp[r, j]
            if n == 2:
                x0 = out[0]
                x1 = 0.0
                slope_before = a[1, 0] * x0 + f1
            else:
                x0 = 0.0
                slope_before = f0
            remaining -= t_zero
            drive = _drive(a, n, x0, g)
            sign = _slip_sign(drive, friction_pos, friction_neg)
            # Saltation at w = 0: stick zeroes the speed's sensitivity, a reversal scales it
            # by the ratio of the speed's slopes after and before.
            if sign == 0:
                for j in range(m):
                    sc[n - 1, j] = 0.0
            elif slope_before != 0.0:
                slope_after = drive - (friction_pos if sign > 0 else -friction_neg)
                ratio = slope_after / slope_before
                for j in range(m):
                    sc[n - 1, j] *= ratio
            if remaining <= 0.0:
                break
            continue
        # Stuck: the speed stays zero while the driving torque is within friction.
        if n == 1:
            for j in range(m):
                sc[0, j] = 0.0
            break
        sign, t_stuck = _stuck_time(a, n, x0, g, remaining, friction_pos, friction_neg, out)
        _stuck_sens(a, da, x0, g[0], sc, dg, t_stuck)
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
    for r in range(n):
        for j in range(m):
            new_s[r, j] = sc[r, j]


@njit(cache=True)
def normal_kernel(a, da, forcing, gscale, regs, reg_col, reg_row, reg_factor, oregs, oreg_col,
                  oreg_chan, oreg_value, friction_pos, friction_neg, dfric_pos, dfric_neg,
                  x_start, s_start, dt, meas0, meas1, inv_sigma, with_sens, block_edges,
                  trajectory, store):
    """
    Simulate with sensitivities and accumulate the weighted normal equations.

    Parameters (arrays; :mod:`dcmotor_id.identification.estimators.normal_equations` builds them)
    ----------
    a, da : ``A`` (n x n) and ``dA/dp_j`` (m x n x n).
    forcing : ``g[k]`` (N x n), held over each sample.
    gscale : ``dg[k]/dp_j = gscale[j] * g[k]`` (m x n), plus the regressor parts
        ``reg_factor[q] * regs[q, k]`` on row ``reg_row[q]`` of column ``reg_col[q]``.
    oregs, oreg_col, oreg_chan, oreg_value : output terms: ``y_c[k] += value * oregs[q, k]``.
    friction_pos, friction_neg, dfric_pos, dfric_neg : friction levels and derivatives (m).
    x_start, s_start : initial state (n) and its sensitivity (n x m).
    meas0, meas1 : measured outputs (the states' channels; ``meas1`` unused for n = 1).
    inv_sigma : weights of the channels (n).
    with_sens : accumulate ``J^T J`` and ``J^T r`` (else the cost only).
    block_edges : sample edges of the blocks of the score sums (increasing, from 0 to N).
    trajectory, store : when ``store``, ``trajectory[k, r, 0]`` gets ``x_r[k]`` and
        ``trajectory[k, r, 1 + j]`` gets ``S_rj[k]`` (shape N x n x (m + 1)).

    Returns ``(hessian, gradient, cost, sums_of_squares, blocks)`` per output channel ``c``
    (so that a change of the weights only rescales them): ``J_c^T J_c`` (n x m x m),
    ``J_c^T r_c`` (n x m), ``sum r^2`` (weighted, all channels), ``sum e_c^2`` (unweighted,
    n) and the score sums per block (n_blocks x n x m).
    """
    n_samples, n = forcing.shape
    m = da.shape[0]
    n_blocks = block_edges.shape[0] - 1
    hessian = np.zeros((n, m, m))
    gradient = np.zeros((n, m))
    blocks = np.zeros((n_blocks, n, m))
    sums = np.zeros(n)
    cost = 0.0
    if too_fast(a, n, dt):
        sums[:] = np.inf
        return hessian, gradient, np.inf, sums, blocks
    ad, gamma = discretise(a, n, dt)
    stick = discretise(a, 1, dt)
    stick_ad = stick[0][0, 0]
    stick_gamma = stick[1][0, 0]
    sad, sgd, sdad, sdgd = flow_matrices(a, da, n, dt)
    a1 = np.empty((1, 1))
    a1[0, 0] = a[0, 0]
    da1 = np.empty((m, 1, 1))
    for j in range(m):
        da1[j, 0, 0] = da[j, 0, 0]
    s1ad, s1gd, s1dad, s1dgd = flow_matrices(a1, da1, 1, dt)
    x = np.empty(2)
    for column in range(n):
        x[column] = x_start[column]
    s = np.empty((n, m))
    for r in range(n):
        for j in range(m):
            s[r, j] = s_start[r, j]
    s_new = np.empty((n, m))
    dg = np.empty((n, m))
    df = np.empty((n, m))
    fv = np.empty(n)
    xv = np.empty(n)
    new = np.empty(2)
    row = np.empty((n, m))
    resid = np.empty(n)
    n_reg = reg_col.shape[0]
    n_oreg = oreg_col.shape[0]
    long_oscillation = False
    block = 0
    if n == 2:
        half = 0.5 * (a[0, 0] + a[1, 1])
        delta = half * half - (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0])
        long_oscillation = delta < 0.0 and math.sqrt(-delta) * dt > 1.5
    for k in range(n_samples):
        # Output, residual and the rows of J at sample k.
        for c in range(n):
            y = x[c]
            for q in range(n_oreg):
                if oreg_chan[q] == c:
                    y += oreg_value[q] * oregs[q, k]
            meas = meas0[k] if c == 0 else meas1[k]
            error = y - meas
            sums[c] += error * error
            resid[c] = error * inv_sigma[c]
            cost += resid[c] * resid[c]
        if with_sens:
            for c in range(n):
                for j in range(m):
                    row[c, j] = s[c, j]
            for q in range(n_oreg):
                row[oreg_chan[q], oreg_col[q]] += oregs[q, k]
            while block + 1 < n_blocks and k >= block_edges[block + 1]:
                block += 1
            for c in range(n):
                weight = inv_sigma[c]
                rc = resid[c]
                for j in range(m):
                    row[c, j] *= weight
                for j in range(m):
                    rj = row[c, j]
                    if rj == 0.0:
                        continue
                    gradient[c, j] += rj * rc
                    blocks[block, c, j] += rj * rc
                    for i in range(j, m):
                        hessian[c, j, i] += rj * row[c, i]
        if store:
            for r in range(n):
                trajectory[k, r, 0] = x[r]
                for j in range(m):
                    trajectory[k, r, 1 + j] = s[r, j]
        if k == n_samples - 1:
            break
        # Forcing derivative of this sample (without the friction part).
        if with_sens:
            for r in range(n):
                gk = forcing[k, r]
                for j in range(m):
                    dg[r, j] = gscale[j, r] * gk
            for q in range(n_reg):
                dg[reg_row[q], reg_col[q]] += reg_factor[q] * regs[q, k]
        # The state: the same steps as simulate_kernel.
        w = x[n - 1]
        if w > 0.0:
            sign = 1
        elif w < 0.0:
            sign = -1
        else:
            sign = _slip_sign(_drive(a, n, x[0], forcing[k]), friction_pos, friction_neg)
        event = True
        if sign != 0:
            friction = friction_pos if sign > 0 else -friction_neg
            if n == 2:
                f0 = forcing[k, 0]
                f1 = forcing[k, 1] - friction
                n0 = ad[0, 0] * x[0] + ad[0, 1] * w + gamma[0, 0] * f0 + gamma[0, 1] * f1
                n1 = ad[1, 0] * x[0] + ad[1, 1] * w + gamma[1, 0] * f0 + gamma[1, 1] * f1
            else:
                f0 = forcing[k, 0] - friction
                f1 = 0.0
                n0 = 0.0
                n1 = ad[0, 0] * w + gamma[0, 0] * f0
            if n1 * sign > 0.0:
                if n == 1:
                    event = False
                else:
                    turned = (sign * _speed_slope(a, x[0], w, f1) < 0.0
                              and sign * _speed_slope(a, n0, n1, f1) > 0.0)
                    event = turned or long_oscillation
            if not event:
                if with_sens:
                    _slip_forcing_derivative(n, dg, sign, dfric_pos, dfric_neg, df)
                    fv[0] = f0
                    xv[0] = x[0]
                    if n == 2:
                        fv[1] = f1
                        xv[1] = x[1]
                    _propagate(n, sad, sgd, sdad, sdgd, xv, fv, s, df, s_new)
                    for r in range(n):
                        for j in range(m):
                            s[r, j] = s_new[r, j]
                if n == 1:
                    x[0] = n1
                else:
                    x[0] = n0
                    x[1] = n1
                continue
        elif n == 2:
            i_end = stick_ad * x[0] + stick_gamma * forcing[k, 0]
            if _slip_sign(_drive(a, n, i_end, forcing[k]), friction_pos, friction_neg) == 0:
                if with_sens:
                    for j in range(m):
                        value = (s1ad[0, 0] * s[0, j] + s1dad[j, 0, 0] * x[0]
                                 + s1dgd[j, 0, 0] * forcing[k, 0] + s1gd[0, 0] * dg[0, j])
                        s[0, j] = value if abs(value) > 1e-100 else 0.0
                        s[1, j] = 0.0
                x[0] = i_end
                x[1] = 0.0
                continue
        else:
            x[0] = 0.0
            if with_sens:
                for j in range(m):
                    s[0, j] = 0.0
            continue
        if with_sens:
            _event_step_sens(a, da, n, x, s, forcing[k], dg, dt, friction_pos, friction_neg,
                             dfric_pos, dfric_neg, new, s_new)
            for r in range(n):
                for j in range(m):
                    s[r, j] = s_new[r, j]
        else:
            _event_step(a, n, x, forcing[k], dt, friction_pos, friction_neg, new)
        for column in range(n):
            x[column] = new[column]
    for c in range(n):
        for j in range(m):
            for i in range(j):
                hessian[c, j, i] = hessian[c, i, j]
    return hessian, gradient, cost, sums, blocks


@njit(cache=True)
def _position_row(trajectory, k, speed, half, first, rho, weight, integral, last, row):
    """Set ``row`` to sample ``k``'s weighted, whitened position sensitivities (and 1)."""
    m = integral.shape[0]
    for j in range(m + 1):
        if j < m and k > 0:
            integral[j] += half * (trajectory[k - 1, speed, 1 + j] + trajectory[k, speed, 1 + j])
        raw = integral[j] if j < m else 1.0
        if rho == 0.0:
            row[j] = raw * weight
        elif k == 0:
            row[j] = first * raw * weight
        else:
            row[j] = (raw - rho * last[j]) * weight
        last[j] = raw


@njit(cache=True)
def position_kernel(trajectory, dt, initial_position, measured, rho, weight, with_sens,
                    block_edges):
    """
    Accumulate the position's normal equations from a stored trajectory, in one pass.

    The position is the trapezoidal integral of the speed (the last state of ``trajectory``,
    as :func:`normal_kernel` stores it) from ``initial_position``; its sensitivities are the
    speed's integrated, and 1 for the initial position (column ``m``).  Error and rows are
    whitened by the AR(1) ``rho`` and weighted by ``weight``: the values of
    :func:`dcmotor_id.identification.error_model.criterion.integrate_speed` and
    :func:`~dcmotor_id.identification.error_model.criterion.whiten` step for step.  Returns
    ``(hessian, gradient, blocks, sum_of_squares, cost)`` (the first three zero unless
    ``with_sens``; the sum of squares of the whitened error, the cost of the weighted one).
    """
    n_samples, speed, m = trajectory.shape[0], trajectory.shape[1] - 1, trajectory.shape[2] - 1
    n_blocks = block_edges.shape[0] - 1
    hessian = np.zeros((m + 1, m + 1))
    gradient = np.zeros(m + 1)
    blocks = np.zeros((n_blocks, m + 1))
    half, first = 0.5 * dt, math.sqrt(1.0 - rho * rho)
    running, previous, total, cost = 0.0, 0.0, 0.0, 0.0
    integral, last, row = np.zeros(m), np.zeros(m + 1), np.zeros(m + 1)
    block = 0
    for k in range(n_samples):
        position = initial_position
        if k > 0:
            running += half * (trajectory[k - 1, speed, 0] + trajectory[k, speed, 0])
            position = running + initial_position
        error = position - measured[k]
        if rho == 0.0:
            white = error
        elif k == 0:
            white = first * error
        else:
            white = error - rho * previous
        previous = error
        residual = white * weight
        total += white * white
        cost += residual * residual
        if not with_sens:
            continue
        _position_row(trajectory, k, speed, half, first, rho, weight, integral, last, row)
        while block + 1 < n_blocks and k >= block_edges[block + 1]:
            block += 1
        for j in range(m + 1):
            gradient[j] += row[j] * residual
            blocks[block, j] += row[j] * residual
            for i in range(j, m + 1):
                hessian[j, i] += row[j] * row[i]
    for j in range(m + 1):
        for i in range(j):
            hessian[j, i] = hessian[i, j]
    return hessian, gradient, blocks, total, cost
