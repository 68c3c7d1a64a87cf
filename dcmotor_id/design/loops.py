"""
The loops of the cascade with python-control: the plant, PIs, sampling, bandwidth, margins.

The motor's state-space model (:func:`motor_model`), the current PI by pole-zero
cancellation (:func:`current_pi`, :func:`sampled_current_pi` for a sampled loop), the
feedforward, the closed current loop (:func:`inner_loop`), bandwidths and stability margins,
and the speed PI placed for a phase margin at the crossover that gives the requested bandwidth
(:func:`design_speed`). See :mod:`dcmotor_id.design.control` for the method.
"""

from __future__ import annotations

import math
import warnings

import control
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq
from scipy.signal import BadCoefficients

from dcmotor_id.design.plant import breakaway_excess, DesignError, Motor


class _NoPI(DesignError):
    """No PI gives the phase margin at this crossover."""

    def __init__(self, too_little_lag: bool, message: str):
        super().__init__(message)
        self.too_little_lag = too_little_lag


# ----------------------------------------------------------------------------- models


def motor_model(motor: Motor) -> control.StateSpace:
    """
    Return the linear motor as a python-control StateSpace (continuous time).

    Full mode: states ``i, w``, inputs ``u`` [V] and ``torque`` [N m] (any further torque on
    the shaft; Coulomb friction is ``-Mc sgn(w)`` on it), outputs ``i, w``. Mechanical mode:
    state and output ``w``, input ``torque``. Voltage-speed mode: ``kA dw/dt = u - kV w``,
    state and output ``w``, input ``u``; with the armature lag ``Ta`` (the exact motor's
    ``Ta kA_inertia d2w/dt2 + kA dw/dt + kV w = u``, ``kA`` the acceleration gain), states
    ``w`` and ``a = dw/dt``.
    """
    p = motor.values
    if motor.mode == 'voltage_speed' and 'Ta' in p:
        jerk = p['Ta'] * p['kA_inertia']
        return control.ss([[0.0, 1.0], [-p['kV'] / jerk, -p['kA'] / jerk]], [[0.0], [1.0 / jerk]],
                          [[1.0, 0.0]], [[0.0]], inputs=['u'], outputs=['w'], states=['w', 'a'],
                          name='motor')
    if motor.mode == 'voltage_speed':
        return control.ss([[-p['kV'] / p['kA']]], [[1.0 / p['kA']]], [[1.0]], [[0.0]],
                          inputs=['u'], outputs=['w'], states=['w'], name='motor')
    if motor.mode == 'mechanical':
        return control.ss([[-p['b'] / p['J']]], [[1.0 / p['J']]], [[1.0]], [[0.0]],
                          inputs=['torque'], outputs=['w'], states=['w'], name='motor')
    a = [[-p['Ra'] / p['La'], -p['CPhi'] / p['La']], [p['CPhi'] / p['J'], -p['b'] / p['J']]]
    b = [[1.0 / p['La'], 0.0], [0.0, 1.0 / p['J']]]
    return control.ss(a, b, np.eye(2), np.zeros((2, 2)), inputs=['u', 'torque'],
                      outputs=['i', 'w'], states=['i', 'w'], name='motor')


def current_pi(motor: Motor, bandwidth_hz: float) -> tuple[float, float]:
    """Return ``(Kp [V/A], Ki [V/(A s)])`` cancelling the armature pole for ``bandwidth_hz``."""
    omega = 2.0 * math.pi * bandwidth_hz
    return omega * motor.values['La'], omega * motor.values['Ra']


def sampled_current_pi(motor: Motor, bandwidth_hz_: float,
                       dt: float | None) -> tuple[tuple[float, float], float]:
    """
    Return the current PI for a sampled loop and its correction factor.

    The closed form keeps ``Ti = La/Ra`` but ``Kp = 2 pi f_c La`` gives a sampled loop a
    wider bandwidth than ``f_c`` (the zero-order hold's half-sample delay makes it peak, the
    more the closer ``f_c`` comes to ``f_s``; the manual's control design page gives the
    figures on its example's motor). With ``dt`` the design frequency is
    scaled by the factor (found by brentq) that makes the sampled closed loop's -3 dB
    bandwidth ``f_c``; without ``dt`` it is the closed form (factor 1).

    Returns
    -------
    gains : tuple
        ``(Kp [V/A], Ki [V/(A s)])``.
    correction : float
        The factor on ``f_c`` in the closed form.

    """
    if dt is None:
        return current_pi(motor, bandwidth_hz_), 1.0

    def mismatch(factor):
        gains = current_pi(motor, factor * bandwidth_hz_)
        inner = inner_loop(motor, gains, None, dt)
        achieved = bandwidth_hz(inner[inner.output_labels.index('i'), 0])
        return math.log(achieved / bandwidth_hz_) if np.isfinite(achieved) else 1.0

    try:
        factor = brentq(mismatch, 0.2, 1.2, xtol=1e-10)
    except ValueError:
        raise DesignError(
            f'no current PI reaches {bandwidth_hz_:g} Hz at --sample-period {dt:g} s: lower '
            '--current-bandwidth (a twentieth of the sampling rate or less) or sample '
            'faster.') from None
    return current_pi(motor, factor * bandwidth_hz_), factor


def feedforward(motor: Motor) -> dict:
    """
    Return the feedforward gains (WPILib ``SimpleMotorFeedforward``), in shaft units.

    Full mode: ``kS = Ra Mc / CPhi`` [V], ``kV = CPhi + Ra b / CPhi`` [V s/rad],
    ``kA = Ra J / CPhi`` [V s^2/rad] (``La`` neglected).  Where a Stribeck effect was found
    ``kS`` holds the break-away friction ``Mc + excess`` (what the voltage must overcome to
    start the motor), ``kS_coulomb`` the sliding one. Mechanical mode: the torque
    feedforward ``Mc`` [N m], ``b`` [N m s/rad], ``J`` [N m s^2/rad] (and divided by the
    torque constant, in amperes, when it is known). Voltage-speed mode: the identified
    ``kS, kV, kA`` themselves.
    """
    p = motor.values
    if motor.mode == 'voltage_speed':
        return {'kS': p['kS'], 'kV': p['kV'], 'kA': p['kA'],
                'units': {'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad'},
                'convention': 'u = kS sgn(w) + kV w + kA dw/dt (WPILib SimpleMotorFeedforward)',
                'identified': 'directly, from voltage and speed (no current)'}
    excess = breakaway_excess(motor)
    if motor.mode == 'full':
        return {'kS': p['Ra'] * (p['Mc'] + excess) / p['CPhi'],
                **_coulomb_ks(p['Ra'] * p['Mc'] / p['CPhi'], excess),
                'kV': p['CPhi'] + p['Ra'] * p['b'] / p['CPhi'],
                'kA': p['Ra'] * p['J'] / p['CPhi'],
                'units': {'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad'},
                'convention': 'u = kS sgn(w) + kV w + kA dw/dt (WPILib SimpleMotorFeedforward)'}
    gains = {'kS': p['Mc'] + excess, **_coulomb_ks(p['Mc'], excess), 'kV': p['b'], 'kA': p['J'],
             'units': {'kS': 'N m', 'kV': 'N m s/rad', 'kA': 'N m s^2/rad'},
             'convention': 'torque = kS sgn(w) + kV w + kA dw/dt (no voltage: mechanical mode)'}
    if motor.torque_constant:
        k = motor.torque_constant
        gains['current'] = {'kS': (p['Mc'] + excess) / k, 'kV': p['b'] / k, 'kA': p['J'] / k,
                            'units': {'kS': 'A', 'kV': 'A s/rad', 'kA': 'A s^2/rad'}}
    return gains


def gravity_feedforward(motor: Motor) -> dict:
    """
    Return ``kG`` of WPILib's ``ElevatorFeedforward`` from the identified load torque.

    The ``load_torque`` effect's ``T_L`` (positive when it opposes positive rotation) taken
    as gravity on an elevator, constant over the travel: ``kG = Ra T_L / CPhi`` [V] (full
    mode), ``T_L`` [N m] (mechanical mode, and ``T_L / K`` [A] with the torque constant), on
    the controlled shaft; in mode ``voltage_speed`` the effect is ``Ra T_L / CPhi`` [V]
    already (``torque_V``), kG itself, the same on either shaft (as kS).

    Raises
    ------
    DesignError
        When the identification found no load torque.

    """
    volts = motor.mode == 'voltage_speed'
    scale = motor.gear_ratio if motor.shaft == 'output' and not volts else 1.0
    torques = [effect['parameters'].get('torque_V' if volts else 'torque_Nm')
               for effect in motor.effects if effect['name'] == 'load_torque']
    if not torques or not isinstance(torques[0], (int, float)):
        raise DesignError('--gravity-load: the result has no load_torque effect to take as '
                          'gravity; identify with discovery on (a record that moves the '
                          'mechanism up and down), or leave --gravity-load out')
    torque = float(torques[0]) * scale
    p = motor.values
    convention = 'u = kG + kS sgn(w) + kV w + kA dw/dt (WPILib ElevatorFeedforward)'
    if motor.mode in ('full', 'voltage_speed'):
        return {'kG': torque if volts else p['Ra'] * torque / p['CPhi'],
                'convention': convention, 'units': {'kG': 'V'}}
    gains: dict = {'kG': torque, 'convention': convention.replace('u =', 'torque ='),
                   'units': {'kG': 'N m'}}
    if motor.torque_constant:
        gains['current'] = {'kG': torque / motor.torque_constant}
    return gains


def add_gravity(feedforward: dict, gravity: dict) -> None:
    """Put ``kG`` (:func:`gravity_feedforward`) into a design's feedforward, in place."""
    feedforward['kG'] = gravity['kG']
    feedforward['convention'] = gravity['convention']
    feedforward['units'] = {**feedforward['units'], **gravity['units']}
    if 'current' in gravity and 'current' in feedforward:
        feedforward['current']['kG'] = gravity['current']['kG']
        feedforward['current']['units']['kG'] = 'A'


def _coulomb_ks(coulomb: float, excess: float) -> dict:
    """Return ``kS_coulomb`` and what ``kS`` is, when a break-away excess raised ``kS``."""
    if excess <= 0:
        return {}
    return {'kS_coulomb': coulomb,
            'kS_source': 'break-away friction Mc + excess of the Stribeck effect (kS_coulomb: '
                         'the sliding friction Mc alone)'}


def pi_controller(kp: float, ki: float, dt: float | None, inputs: str,
                  outputs: str) -> control.TransferFunction:
    """Return the PI ``kp + ki/s`` (Tustin-discretised when ``dt`` is given)."""
    pi = control.tf([kp, ki], [1.0, 0.0], inputs=inputs, outputs=outputs)
    if dt is not None:
        pi = control.c2d(pi, dt, method='tustin')
    pi.name = f'pi_{outputs}'
    return pi


def difference_equation(pi: control.TransferFunction) -> dict:
    """Coefficients of ``y[k] = y[k-1] + q0 e[k] + q1 e[k-1]`` of a Tustin PI."""
    num = np.atleast_1d(np.squeeze(pi.num[0][0])) / pi.den[0][0][0]
    return {'q0': float(num[0]), 'q1': float(num[1]) if len(num) > 1 else 0.0,
            'form': 'y[k] = y[k-1] + q0 e[k] + q1 e[k-1] (Tustin)'}


def sampled_system(system: control.LTI, dt: float | None) -> control.LTI:
    return system if dt is None else control.c2d(system, dt, method='zoh')


def inner_loop(motor: Motor, current_gains: tuple[float, float] | None,
               current_bandwidth_hz: float | None, dt: float | None) -> control.StateSpace:
    """
    Return the plant the speed loop sees: reference of the inner loop -> ``w`` (and ``i``).

    Full mode: the current PI closed around the exact motor (back-EMF included), input
    ``i_ref`` [A], outputs ``w, i, u``. Mechanical mode: the torque source, ideal or a first
    order lag of ``current_bandwidth_hz``, input ``torque_ref`` [N m], outputs ``w``.
    Voltage-speed mode: the motor itself, input ``u`` [V], output ``w``.
    """
    plant = sampled_system(motor_model(motor), dt)
    if motor.mode == 'voltage_speed':
        return control.interconnect([plant], inplist=['u'], outlist=['w'], inputs=['u'],
                                    outputs=['w'], name='inner')
    if motor.mode == 'mechanical':
        if current_bandwidth_hz is None:
            actuator = control.ss([], [], [], [[1.0]], dt=0 if dt is None else dt,
                                  inputs='torque_ref', outputs='torque')
        else:
            omega = 2.0 * math.pi * current_bandwidth_hz
            actuator = sampled_system(control.tf([omega], [1.0, omega], inputs='torque_ref',
                                                 outputs='torque'), dt)
        actuator.name = 'torque_loop'
        return control.interconnect([plant, actuator], inplist=['torque_ref'],
                                    outlist=['w'], inputs=['torque_ref'], outputs=['w'],
                                    name='inner')
    if current_gains is None:
        raise TypeError('inner_loop: a full-mode motor needs the current PI gains')
    kp, ki = current_gains
    pi = pi_controller(kp, ki, dt, 'e_i', 'u')
    junction = control.summing_junction(['i_ref', '-i'], 'e_i', dt=dt, name='sum_i')
    return control.interconnect([plant, pi, junction], inplist=['i_ref'],
                                outlist=['w', 'i', 'u'], inputs=['i_ref'],
                                outputs=['w', 'i', 'u'], ignore_inputs=['torque'],
                                name='inner')


def _response(system: control.LTI, omega: ArrayLike) -> np.ndarray:
    """Complex frequency response (handles sampled systems, unlike ``system(1j w)``)."""
    response = system.frequency_response(np.atleast_1d(omega))
    return np.atleast_1d(np.squeeze(response.complex))


def bandwidth_hz(system: control.LTI) -> float:
    """
    Return the -3 dB bandwidth [Hz]: the first frequency where the gain is 3 dB below DC.

    ``control.bandwidth`` evaluates ``system(1j w)``, which is wrong for sampled systems (it
    needs ``z = exp(1j w dt)``); this scans ``frequency_response`` and bisects with brentq.
    """
    dc = abs(_response(system, [1e-9])[0])
    level = dc * 10 ** (-3.0 / 20.0)
    top = math.pi / system.dt if system.isdtime(strict=True) else 1e7
    omega = np.logspace(-2, math.log10(top), 240)
    if system.isdtime(strict=True):
        omega = omega[omega < top * 0.999]
    gain = np.abs(_response(system, omega))
    below = np.nonzero(gain < level)[0]
    if below.size == 0 or below[0] == 0:
        return float('nan')
    k = below[0]
    root = brentq(lambda w: abs(_response(system, [w])[0]) - level, omega[k - 1], omega[k],
                  xtol=1e-10, rtol=1e-12)
    return root / (2.0 * math.pi)


def step_overshoot_pct(closed: control.LTI, bandwidth_hz_: float) -> float:
    """
    Return the overshoot [%] of a closed loop's unit step (python-control's ``step_info``).

    Over 20 periods of ``bandwidth_hz_`` (the peak of a loop of that bandwidth comes within
    one or two), relative to the DC gain; 0 without overshoot.
    """
    horizon = 20.0 / bandwidth_hz_
    if closed.isdtime(strict=True):
        times = np.arange(int(math.ceil(horizon / closed.dt)) + 1) * closed.dt
    else:
        times = np.linspace(0.0, horizon, 4001)
    info = control.step_info(closed, T=times)
    return float(info['Overshoot'])


def margins(loop: control.LTI) -> dict:
    """
    Return the stability margins of an open loop: phase [deg], gain [dB], crossovers [Hz].

    Phase crossings at zero frequency (an artefact of the integrator of a sampled loop) are
    ignored; the gain margin is the smallest upward one (``inf`` when there is none).
    """
    with warnings.catch_warnings():
        # python-control notes when it switches to its frequency-response method.
        warnings.simplefilter('ignore', UserWarning)
        gm, pm, _, wpc, wgc, _ = control.stability_margins(loop, returnall=True)
    gm, pm, wpc, wgc = (np.atleast_1d(x).astype(float) for x in (gm, pm, wpc, wgc))
    if loop.isdtime(strict=True):
        # stability_margins misses a phase crossing at the Nyquist frequency itself, where a
        # sampled loop is real: L(-1) < 0 is a -180 deg crossing.
        nyquist = complex(np.squeeze(loop(-1.0)))
        if nyquist.real < 0 and abs(nyquist.real) > 0:
            gm = np.append(gm, 1.0 / abs(nyquist.real))
            wpc = np.append(wpc, math.pi / loop.dt)
    # Gain margins above 200 dB are phase crossings where the gain is numerically zero.
    keep = (wpc > 1e-6) & (gm > 1.0) & (gm < 1e10)
    gain_margin = float(np.min(gm[keep])) if keep.any() else float('inf')
    phase_crossover = float(wpc[keep][np.argmin(gm[keep])]) if keep.any() else float('nan')
    if pm.size:
        # The distance of the phase from -180 deg at every gain crossover, the smallest one
        # (a lightly damped electromechanical mode can make the loop cross unity gain twice).
        distance = np.abs((pm + 180.0) % 360.0 - 180.0)
        first = int(np.argmin(distance))
        phase_margin, crossover = float(distance[first]), float(wgc[first])
    else:
        phase_margin, crossover = float('inf'), float('nan')
    closed = control.feedback(loop, 1)
    with warnings.catch_warnings():
        # The poles come from the denominator; near-zero numerator coefficients (a slow PI
        # zero) only make tf2zpk warn, 41 times on one design at 1.4 Hz.
        warnings.simplefilter('ignore', BadCoefficients)
        poles = closed.poles()
    stable = bool(np.all(np.abs(poles) < 1.0) if loop.isdtime(strict=True)
                  else np.all(poles.real < 0))
    return {'phase_margin_deg': phase_margin,
            'gain_margin_db': 20 * math.log10(gain_margin) if np.isfinite(gain_margin)
            else float('inf'),
            'crossover_hz': crossover / (2 * math.pi),
            'phase_crossover_hz': phase_crossover / (2 * math.pi), 'stable': stable}


def _speed_pi_at(inner_w: control.LTI, crossover: float, phase_margin_deg: float,
                 dt: float | None) -> tuple[float, float]:
    """PI ``(Kp, Ki)`` giving ``phase_margin_deg`` at the crossover ``crossover`` [rad/s]."""
    phase, gain = _plant_phase(inner_w, crossover)
    pi_phase = -math.pi + math.radians(phase_margin_deg) - phase
    if not -math.pi / 2 < pi_phase < 0:
        raise _NoPI(
            pi_phase <= -math.pi / 2,
            f'a PI cannot give {phase_margin_deg:g} deg phase margin at '
            f'{crossover / (2 * math.pi):.4g} Hz (the plant has {math.degrees(phase):.1f} deg '
            'there): lower --phase-margin or --speed-bandwidth, or raise --current-bandwidth.')
    # Tustin maps s = (2/T)(z-1)/(z+1); at z = exp(j w T) this is s = j (2/T) tan(w T/2), so
    # the sampled PI has the phase of the continuous one at that warped frequency.
    warped = crossover if dt is None else 2.0 / dt * math.tan(crossover * dt / 2.0)
    ti = 1.0 / (warped * math.tan(-pi_phase))
    kp = 1.0 / (gain * abs(1.0 - 1j / (warped * ti)))
    return kp, kp / ti


def _plant_phase(inner_w: control.LTI, crossover: float) -> tuple[float, float]:
    """Return the plant's phase [rad] (unwrapped from four decades below) and gain there."""
    grid = np.logspace(math.log10(crossover) - 4, math.log10(crossover), 80)
    response = _response(inner_w, grid)
    return float(np.unwrap(np.angle(response))[-1]), float(abs(response[-1]))


#: Phase [rad] of a PI at its crossover when its zero lies a decade below it.
DECADE_PI_PHASE = -math.atan(0.1)


def decade_speed_pi(inner: control.LTI, phase_margin_deg: float, dt: float | None,
                    reference: str, highest_hz: float) -> tuple[float, float, float, float]:
    """
    Return the fastest speed PI whose zero lies a decade below its crossover.

    Near the highest bandwidth a PI reaches with the phase margin (``highest_hz``, from
    :func:`achievable_speed_bandwidths`) the plant leaves the PI no phase: its integral
    action vanishes (``Ti`` grows without bound). This PI keeps ``Ti`` at ten times
    ``1/w_x``: its crossover ``w_x`` is where the plant leaves the margin and the PI's
    ``-5.7`` deg (brentq on the phase).

    Returns
    -------
    tuple
        ``(Kp, Ki, crossover [Hz], closed-loop bandwidth [Hz])``.

    """
    inner_w = inner[inner.output_labels.index('w'), 0]

    def excess(log_crossover):
        phase = _plant_phase(inner_w, math.exp(log_crossover))[0]
        return -math.pi + math.radians(phase_margin_deg) - phase - DECADE_PI_PHASE

    high = math.log(2 * math.pi * highest_hz)
    low = high - math.log(1000.0)
    if excess(low) >= 0 or excess(high) <= 0:
        raise DesignError(f'no PI reaches {phase_margin_deg:g} deg phase margin with its '
                          'zero a decade below the crossover: lower --phase-margin')
    crossover = math.exp(brentq(excess, low, high, xtol=1e-9))
    kp, ki = _speed_pi_at(inner_w, crossover, phase_margin_deg, dt)
    return kp, ki, crossover / (2 * math.pi), _speed_bandwidth(inner, kp, ki, dt, reference)


def feedforward_step_overshoot_pct(inner: control.LTI, kp: float, ki: float, kv: float,
                                   dt: float | None, bandwidth_hz_: float) -> float:
    """
    Return the overshoot [%] of a reference step with the static feedforward ``kV w_ref``.

    Voltage-to-speed mode: the voltage is the speed PI's output plus ``kV w_ref`` (``kS``
    cancels the Coulomb friction at a speed of one sign). With a feedforward that holds the
    steady state the integral ends where it started, so the error's integral over the step is
    zero: what the PI gathers on the rise it gives back as overshoot.
    """
    pi = pi_controller(kp, ki, dt, 'e_w', 'u_pi')
    static = control.tf([kv], [1.0], dt=0 if dt is None else dt, inputs='w_ref',
                        outputs='u_ff', name='feedforward')
    error = control.summing_junction(['w_ref', '-w'], 'e_w', dt=dt, name='sum_w')
    voltage = control.summing_junction(['u_pi', 'u_ff'], 'u', dt=dt, name='sum_u')
    closed = control.interconnect([inner, pi, static, error, voltage], inplist=['w_ref'],
                                  outlist=['w'], inputs=['w_ref'], outputs=['w'])
    return step_overshoot_pct(closed, bandwidth_hz_)


def speed_loops(inner: control.LTI, kp: float, ki: float, dt: float | None,
                reference: str) -> tuple[control.LTI, control.LTI]:
    """Return the speed loop's open loop ``L`` and closed loop ``w_ref -> [w, i_ref, ...]``."""
    pi = pi_controller(kp, ki, dt, 'e_w', reference)
    junction = control.summing_junction(['w_ref', '-w'], 'e_w', dt=dt, name='sum_w')
    outputs = ['w', reference] + [name for name in ('i', 'u') if name in inner.output_labels]
    closed = control.interconnect([inner, pi, junction], inplist=['w_ref'], outlist=outputs,
                                  inputs=['w_ref'], outputs=outputs, name='speed_loop')
    with warnings.catch_warnings():
        # Near-zero numerator coefficients of the sampled product are harmless here.
        warnings.simplefilter('ignore', BadCoefficients)
        open_loop = pi * inner[inner.output_labels.index('w'), 0]
    return open_loop, closed


def design_speed(inner: control.LTI, bandwidth_hz_: float, phase_margin_deg: float,
                 dt: float | None, reference: str) -> tuple[float, float, float]:
    """
    Return ``(Kp, Ki, crossover [Hz])`` of the speed PI meeting the bandwidth and margin.

    The crossover is found by brentq so that the closed loop's -3 dB bandwidth equals
    ``bandwidth_hz_``, the PI placing ``phase_margin_deg`` at each trial crossover.
    """
    target = 2 * math.pi * bandwidth_hz_
    inner_w = inner[inner.output_labels.index('w'), 0]

    def mismatch(log_crossover):
        try:
            kp, ki = _speed_pi_at(inner_w, math.exp(log_crossover), phase_margin_deg, dt)
        except _NoPI as error:
            # Too little plant lag (low crossover) or too much (high): steer brentq away.
            return -1.0 if error.too_little_lag else 1.0
        achieved = _speed_bandwidth(inner, kp, ki, dt, reference) * 2 * math.pi
        if not np.isfinite(achieved):
            return 1.0
        return math.log(achieved / target)

    low, high = math.log(target / 8), math.log(target * 1.2)
    f_low, f_high = mismatch(low), mismatch(high)
    while f_high < 0 and high < math.log(target * 10):
        low, f_low, high = high, f_high, high + math.log(1.5)
        f_high = mismatch(high)
    if f_low > 0 or f_high < 0:
        raise DesignError(f'no PI crossover gives a speed bandwidth of {bandwidth_hz_:g} Hz '
                          f'with {phase_margin_deg:g} deg phase margin: lower '
                          '--speed-bandwidth or --phase-margin.')
    log_crossover = brentq(mismatch, low, high, xtol=1e-9)
    try:
        kp, ki = _speed_pi_at(inner_w, math.exp(log_crossover), phase_margin_deg, dt)
    except _NoPI as error:
        raise DesignError(str(error)) from None
    achieved = _speed_bandwidth(inner, kp, ki, dt, reference)
    if not abs(achieved / bandwidth_hz_ - 1.0) <= BANDWIDTH_TOLERANCE:
        # brentq closed in on the edge where a PI stops existing, not on a root
        raise DesignError(_unmet_bandwidth(inner, bandwidth_hz_, achieved, phase_margin_deg,
                                           dt, reference))
    return kp, ki, math.exp(log_crossover) / (2 * math.pi)


#: Relative distance of the achieved speed bandwidth from the requested one that is refused.
BANDWIDTH_TOLERANCE = 0.01


def _speed_bandwidth(inner: control.LTI, kp: float, ki: float, dt: float | None,
                     reference: str) -> float:
    """Return the closed speed loop's -3 dB bandwidth [Hz] with the PI ``(kp, ki)``."""
    _, closed = speed_loops(inner, kp, ki, dt, reference)
    return bandwidth_hz(closed[0, 0])


def achievable_speed_bandwidths(inner: control.LTI, phase_margin_deg: float,
                                dt: float | None, reference: str,
                                around_hz: float) -> tuple[float, float]:
    """
    Return the lowest and highest speed bandwidth [Hz] a PI reaches with the phase margin.

    Scans crossovers from a hundredth to a thousand times ``around_hz`` (log grid; a sampled
    loop's below its Nyquist frequency, above which its response repeats): a PI exists where
    the plant's phase leaves room for the margin; the edges of that stretch are then
    bisected. nan, nan where a PI exists nowhere.
    """
    inner_w = inner[inner.output_labels.index('w'), 0]

    def pi_at(log_crossover):
        try:
            return _speed_pi_at(inner_w, math.exp(log_crossover), phase_margin_deg, dt)
        except _NoPI:
            return None

    top = around_hz * 1000 if dt is None else min(around_hz * 1000, 0.49 / dt)
    grid = list(np.log(2 * math.pi * np.geomspace(min(around_hz / 100, top / 10), top, 61)))
    exists = [pi_at(value) is not None for value in grid]
    places = [value for value, ok in zip(grid, exists) if ok]
    for index in range(len(grid) - 1):
        if exists[index] != exists[index + 1]:
            inside, outside = (grid[index], grid[index + 1]) if exists[index] else \
                (grid[index + 1], grid[index])
            for _ in range(30):
                middle = (inside + outside) / 2
                inside, outside = (middle, outside) if pi_at(middle) is not None else \
                    (inside, middle)
            places.append(inside)
    found = []
    for value in places:
        kp, ki = _speed_pi_at(inner_w, math.exp(value), phase_margin_deg, dt)
        achieved = _speed_bandwidth(inner, kp, ki, dt, reference)
        if np.isfinite(achieved):
            found.append(achieved)
    return (min(found), max(found)) if found else (float('nan'), float('nan'))


def _unmet_bandwidth(inner: control.LTI, asked_hz: float, achieved_hz: float,
                     phase_margin_deg: float, dt: float | None, reference: str) -> str:
    """Return the refusal of a speed bandwidth no PI reaches: the range a PI does reach."""
    low, high = achievable_speed_bandwidths(inner, phase_margin_deg, dt, reference, asked_hz)
    reach = (f'with {phase_margin_deg:g} deg phase margin a PI reaches {low:.3g} to '
             f'{high:.3g} Hz on this motor' if np.isfinite(low) else
             f'no PI reaches {phase_margin_deg:g} deg phase margin near it')
    if np.isfinite(low) and asked_hz < low:
        todo = (f'ask for --speed-bandwidth {low * 1.02:.3g} or more, or a larger '
                '--phase-margin (below it the plant lags too little: the integral action of a '
                'PI cannot bring the phase margin down to the one asked)')
    else:
        todo = ('ask for a --speed-bandwidth within that range, a smaller --phase-margin, or '
                'raise --current-bandwidth')
    return (f'--speed-bandwidth {asked_hz:g} Hz: no PI meets it (the closest loop has '
            f'{achieved_hz:.3g} Hz); {reach}: {todo}')
