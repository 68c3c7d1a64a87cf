"""
Controller design from an identification result: cascaded PI gains, feedforward, robustness.

The motor (:mod:`dcmotor_id.core.model`)::

    La di/dt = u - Ra i - CPhi w
    J  dw/dt = CPhi i - b w - Mc sgn(w) + torque

is controlled by the usual cascade: a PI current loop giving the armature voltage ``u`` and,
around it, a PI speed loop giving the current reference. Every loop is built, closed and
measured with python-control (``ss``, ``tf``, ``interconnect``, ``feedback``,
``stability_margins``, ``c2d``), on the exact linear plant (back-EMF included); Coulomb
friction is a constant torque at any operating speed and leaves the linear loops unchanged.

* Current loop: pole-zero cancellation of the armature pole, ``Ti = La/Ra``,
  ``Kp = 2 pi f_c La`` (``Ki = Kp/Ti = 2 pi f_c Ra``): the open loop is ``2 pi f_c / s`` when
  the back-EMF is neglected, so the closed loop is first order with bandwidth ``f_c``.
* Speed loop: a PI ``Kp (1 + 1/(Ti s))`` placed on the exact closed current loop so that the
  open loop has the requested phase margin at its crossover; the crossover is then chosen
  (root finding) so that the closed speed loop's -3 dB bandwidth is the requested one.
* With a sample period ``T`` the plant is sampled with a zero-order hold (exact for a drive
  whose voltage is held between samples, as the simulator does) and the PIs are discretised
  with Tustin's rule; margins and bandwidths are then those of the sampled loops.
* Feedforward in WPILib's ``SimpleMotorFeedforward`` convention,
  ``u = kS sgn(w) + kV w + kA dw/dt``: with ``La`` neglected the steady state gives
  ``u = Ra i + CPhi w`` and ``CPhi i = b w + Mc sgn(w) + J dw/dt``, so
  ``kS = Ra Mc / CPhi`` [V], ``kV = CPhi + Ra b / CPhi`` [V s/rad],
  ``kA = Ra J / CPhi`` [V s^2/rad].
* Gear ratio ``N`` (motor speed / output speed): on the output shaft the motor is the
  equivalent motor ``CPhi N, J N^2, b N^2, Mc N`` (same ``Ra, La``), so every formula holds
  unchanged in output-shaft units.
* Robustness: the nominal gains are kept and the loops re-evaluated with the motor at the
  ends of every parameter's 95 % interval (one at a time) and at every corner of the box of
  the linear parameters' intervals.

This module imports no rclpy; :mod:`dcmotor_id.design.export` writes the model files and
:mod:`dcmotor_id.reports.design` the HTML page.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import itertools
import json
import math
from typing import Any
import warnings

import control
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import brentq
from scipy.signal import BadCoefficients

from dcmotor_id.core.errors import DcMotorIdError, InputDataError
from dcmotor_id.formats.json_file import load_json

#: z of the two-sided 95 % interval.
Z95 = 1.959964
#: Default closed current-loop bandwidth [Hz] (lowered to a twentieth of the sampling rate).
DEFAULT_CURRENT_BANDWIDTH_HZ = 200.0
#: Default speed bandwidth as a fraction of the current bandwidth.
DEFAULT_SPEED_RATIO = 0.1
#: Default phase margin of the speed loop [deg].
DEFAULT_PHASE_MARGIN_DEG = 60.0
#: Parameters of the linear loops (Mc only shifts the operating point).
LINEAR_FULL = ('Ra', 'La', 'CPhi', 'J', 'b')
LINEAR_MECHANICAL = ('J', 'b')


class DesignError(DcMotorIdError):
    """The requested design cannot be met (bandwidths, phase margin, sample period)."""


class _NoPI(DesignError):
    """No PI gives the phase margin at this crossover."""

    def __init__(self, too_little_lag: bool, message: str):
        super().__init__(message)
        self.too_little_lag = too_little_lag


@dataclass(frozen=True)
class Motor:
    """
    The identified motor seen from the controlled shaft (SI units).

    Attributes
    ----------
    values : dict
        ``Ra, La, CPhi, J, b, Mc`` (full mode) or ``J, b, Mc`` (mechanical mode).
    stderr : dict
        Standard error of each value (``nan`` when unknown), same units.
    mode : str
        ``'full'`` or ``'mechanical'`` (``dcmotor-id identify --torque-constant``).
    torque_constant : float or None
        ``K`` [N m/A] of the mechanical mode (torque = K * current), on the controlled shaft.
    gear_ratio : float
        ``N``, motor speed / output speed.
    shaft : str
        ``'motor'`` or ``'output'``: where speeds, torques and gains are expressed.

    """

    values: dict
    stderr: dict
    mode: str = 'full'
    torque_constant: float | None = None
    gear_ratio: float = 1.0
    shaft: str = 'motor'

    @property
    def linear_names(self) -> tuple:
        """Names of the parameters that shape the linear loops."""
        return LINEAR_FULL if self.mode == 'full' else LINEAR_MECHANICAL

    def with_values(self, **changes: float) -> Motor:
        """Return a copy with some parameter values changed."""
        return replace(self, values={**self.values, **changes})


@dataclass(frozen=True)
class DesignOptions:
    """
    What the design asks for.

    Attributes
    ----------
    current_bandwidth_hz : float or None
        Closed current-loop bandwidth [Hz]; ``None``: 200 Hz or a twentieth of the sampling
        rate, whichever is lower (mechanical mode: ``None`` = an ideal torque source).
    speed_bandwidth_hz : float or None
        Closed speed-loop -3 dB bandwidth [Hz]; ``None``: a tenth of the current bandwidth
        (of its default when the torque source is ideal).
    phase_margin_deg : float
        Phase margin of the speed loop [deg].
    sample_period_s : float or None
        Sample period of the digital controller [s]; ``None``: continuous design.

    """

    current_bandwidth_hz: float | None = None
    speed_bandwidth_hz: float | None = None
    phase_margin_deg: float = DEFAULT_PHASE_MARGIN_DEG
    sample_period_s: float | None = None


# ----------------------------------------------------------------------------- input


def load_result(path: str) -> dict:
    """
    Read the JSON written by ``dcmotor-id identify --json``.

    Raises
    ------
    InputDataError
        When the file is missing, not JSON, or has no ``parameters`` mapping.

    """
    try:
        with open(path, encoding='utf-8') as stream:
            result = load_json(stream)
    except FileNotFoundError:
        raise InputDataError(f'{path}: no such file; give the JSON written by '
                             '`dcmotor-id identify FILE --json OUT`') from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputDataError(f'{path}: not a readable JSON file ({error}); give the JSON '
                             'written by `dcmotor-id identify FILE --json OUT`') from None
    if not isinstance(result, dict) or not isinstance(result.get('parameters'), dict):
        raise InputDataError(f'{path}: no "parameters" mapping; give the JSON written by '
                             '`dcmotor-id identify FILE --json OUT`')
    from dcmotor_id.identification.validate import check_one_model
    check_one_model(result, path)  # validate scores the "model" block: one motor for both
    return result


def _number(value: Any) -> float:
    """Return a JSON number as a float; anything else (``true``, ``"1.6"``, null) is NaN."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return float('nan')
    return float(value)


def motor_from_result(result: dict, gear_ratio: float = 1.0,
                      output_shaft: bool = False) -> Motor:
    """
    Check an identification result and return the motor on the controlled shaft.

    Parameters
    ----------
    result : dict
        The identify JSON (``parameters``, ``stderr``, ``mode``, ``torque_constant``); its
        values are taken as those of the motor shaft.
    gear_ratio : float
        ``N`` = motor speed / output speed (> 0).
    output_shaft : bool
        Express everything on the output shaft (the equivalent motor ``CPhi N``, ``J N^2``,
        ``b N^2``, ``Mc N``, ``K N``).

    Raises
    ------
    InputDataError
        Missing, non-finite or non-physical parameters (``Ra, La, CPhi, J`` must be > 0,
        ``b, Mc`` >= 0), or a bad gear ratio.

    """
    if not (np.isfinite(gear_ratio) and gear_ratio > 0):
        raise InputDataError(f'--gear-ratio must be a positive number, got {gear_ratio}')
    given = result['parameters']
    # Mechanical only when the result says so (or, an older result without a mode, has no
    # electrical parameter at all): NaN electrical values of a full result are refused, not
    # silently designed around.
    mode = result.get('mode')
    if mode not in (None, 'full', 'mechanical'):
        raise InputDataError(f'the result has mode {mode!r}; it must be "full" or '
                             '"mechanical" (as `dcmotor-id identify --json` writes it)')
    mechanical = mode == 'mechanical' or (mode is None and all(
        given.get(name) is None for name in ('Ra', 'La', 'CPhi')))
    names = ('J', 'b', 'Mc') if mechanical else ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
    values, stderr = _checked_values(result, names)
    torque_constant = None
    if mechanical:
        torque_constant = _number(result.get('torque_constant'))
        if not (np.isfinite(torque_constant) and torque_constant > 0):
            torque_constant = None
    if output_shaft:
        scale = {'CPhi': gear_ratio, 'J': gear_ratio ** 2, 'b': gear_ratio ** 2,
                 'Mc': gear_ratio}
        values = {name: value * scale.get(name, 1.0) for name, value in values.items()}
        stderr = {name: value * scale.get(name, 1.0) for name, value in stderr.items()}
        if torque_constant is not None:
            torque_constant *= gear_ratio
    return Motor(values, stderr, 'mechanical' if mechanical else 'full', torque_constant,
                 float(gear_ratio), 'output' if output_shaft else 'motor')


def _checked_values(result: dict, names: tuple[str, ...]) -> tuple[dict, dict]:
    """
    Return the values and standard errors of ``names`` in an identify JSON.

    Raises
    ------
    InputDataError
        Naming every missing, non-finite or non-physical value.

    """
    given = result['parameters']
    values, stderr, bad = {}, {}, []
    for name in names:
        value = _number(given.get(name))
        positive = name in ('Ra', 'La', 'CPhi', 'J')
        if not np.isfinite(value) or value < 0 or (positive and value == 0):
            raw = given.get(name)
            typed = raw is None or (isinstance(raw, (int, float)) and not isinstance(raw, bool))
            bad.append(f'{name} = {json.dumps(raw)}' + (
                '' if typed else f' (a {type(raw).__name__}, not a number)'))
        values[name] = value
        error = _number((result.get('stderr') or {}).get(name))
        stderr[name] = abs(error) if np.isfinite(error) else float('nan')
    if bad:
        raise InputDataError(
            f'the result holds unusable parameters ({", ".join(bad)}): Ra, La, CPhi, J must be '
            'finite and positive, b and Mc finite and >= 0. Identify the motor again (more '
            'excitation, `dcmotor-id identify ... --json OUT`) before designing a controller.')
    return values, stderr


def resolve_options(motor: Motor, options: DesignOptions) -> DesignOptions:
    """
    Fill the defaults in and check that the request makes sense.

    Raises
    ------
    DesignError
        A bandwidth at or above the Nyquist frequency of the sample period, a speed bandwidth
        not below the current bandwidth, or a phase margin outside (0, 90) degrees.

    """
    dt = options.sample_period_s
    if dt is not None and not (np.isfinite(dt) and dt > 0):
        raise DesignError(f'--sample-period must be a positive number of seconds, got {dt}')
    current = options.current_bandwidth_hz
    if current is None and motor.mode == 'full':
        current = DEFAULT_CURRENT_BANDWIDTH_HZ
        if dt is not None:
            current = min(current, 1.0 / (20.0 * dt))
    speed = options.speed_bandwidth_hz
    if speed is None:
        reference = current if current is not None else DEFAULT_CURRENT_BANDWIDTH_HZ
        if current is None and dt is not None:
            reference = min(reference, 1.0 / (20.0 * dt))
        speed = DEFAULT_SPEED_RATIO * reference
    for label, value in (('--current-bandwidth', current), ('--speed-bandwidth', speed)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise DesignError(f'{label} must be a positive number of Hz, got {value}')
        if value is not None and dt is not None and value >= 0.5 / dt:
            raise DesignError(
                f'{label} {value:g} Hz is at or above the Nyquist frequency {0.5 / dt:g} Hz of '
                f'--sample-period {dt:g} s: lower the bandwidth (a tenth of the sampling rate '
                'or less works well) or sample faster.')
    if current is not None and speed >= current:
        raise DesignError(
            f'--speed-bandwidth {speed:g} Hz must be below --current-bandwidth {current:g} Hz '
            '(the speed loop acts through the current loop); a factor 5-10 below is usual.')
    if not 0 < options.phase_margin_deg < 90:
        raise DesignError(f'--phase-margin must lie between 0 and 90 degrees, got '
                          f'{options.phase_margin_deg:g}')
    return replace(options, current_bandwidth_hz=current, speed_bandwidth_hz=speed)


# ----------------------------------------------------------------------------- models


def motor_model(motor: Motor) -> control.StateSpace:
    """
    Return the linear motor as a python-control StateSpace (continuous time).

    Full mode: states ``i, w``, inputs ``u`` [V] and ``torque`` [N m] (any further torque on
    the shaft; Coulomb friction is ``-Mc sgn(w)`` on it), outputs ``i, w``. Mechanical mode:
    state and output ``w``, input ``torque``.
    """
    p = motor.values
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
    wider bandwidth than ``f_c`` (the zero-order hold's half-sample delay makes it peak:
    +7 % at ``f_c = f_s/50``, +22 % at ``f_s/20``). With ``dt`` the design frequency is
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
    ``kA = Ra J / CPhi`` [V s^2/rad] (``La`` neglected). Mechanical mode: the torque
    feedforward ``Mc`` [N m], ``b`` [N m s/rad], ``J`` [N m s^2/rad] (and divided by the
    torque constant, in amperes, when it is known).
    """
    p = motor.values
    if motor.mode == 'full':
        return {'kS': p['Ra'] * p['Mc'] / p['CPhi'],
                'kV': p['CPhi'] + p['Ra'] * p['b'] / p['CPhi'],
                'kA': p['Ra'] * p['J'] / p['CPhi'],
                'units': {'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad'},
                'convention': 'u = kS sgn(w) + kV w + kA dw/dt (WPILib SimpleMotorFeedforward)'}
    gains = {'kS': p['Mc'], 'kV': p['b'], 'kA': p['J'],
             'units': {'kS': 'N m', 'kV': 'N m s/rad', 'kA': 'N m s^2/rad'},
             'convention': 'torque = kS sgn(w) + kV w + kA dw/dt (no voltage: mechanical mode)'}
    if motor.torque_constant:
        k = motor.torque_constant
        gains['current'] = {'kS': p['Mc'] / k, 'kV': p['b'] / k, 'kA': p['J'] / k,
                            'units': {'kS': 'A', 'kV': 'A s/rad', 'kA': 'A s^2/rad'}}
    return gains


def pi_controller(kp: float, ki: float, dt: float | None, inputs: str,
                  outputs: str) -> control.TransferFunction:
    """Return the PI ``kp + ki/s`` (Tustin-discretised when ``dt`` is given)."""
    pi = control.tf([kp, ki], [1.0, 0.0], inputs=inputs, outputs=outputs)
    if dt is not None:
        pi = control.c2d(pi, dt, method='tustin')
    pi.name = f'pi_{outputs}'
    return pi


def _difference_equation(pi: control.TransferFunction) -> dict:
    """Coefficients of ``y[k] = y[k-1] + q0 e[k] + q1 e[k-1]`` of a Tustin PI."""
    num = np.atleast_1d(np.squeeze(pi.num[0][0])) / pi.den[0][0][0]
    return {'q0': float(num[0]), 'q1': float(num[1]) if len(num) > 1 else 0.0,
            'form': 'y[k] = y[k-1] + q0 e[k] + q1 e[k-1] (Tustin)'}


def _sampled(system: control.LTI, dt: float | None) -> control.LTI:
    return system if dt is None else control.c2d(system, dt, method='zoh')


def inner_loop(motor: Motor, current_gains: tuple[float, float] | None,
               current_bandwidth_hz: float | None, dt: float | None) -> control.StateSpace:
    """
    Return the plant the speed loop sees: reference of the inner loop -> ``w`` (and ``i``).

    Full mode: the current PI closed around the exact motor (back-EMF included), input
    ``i_ref`` [A], outputs ``w, i, u``. Mechanical mode: the torque source, ideal or a first
    order lag of ``current_bandwidth_hz``, input ``torque_ref`` [N m], outputs ``w``.
    """
    plant = _sampled(motor_model(motor), dt)
    if motor.mode == 'mechanical':
        if current_bandwidth_hz is None:
            actuator = control.ss([], [], [], [[1.0]], dt=0 if dt is None else dt,
                                  inputs='torque_ref', outputs='torque')
        else:
            omega = 2.0 * math.pi * current_bandwidth_hz
            actuator = _sampled(control.tf([omega], [1.0, omega], inputs='torque_ref',
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
    stable = bool(np.all(np.abs(closed.poles()) < 1.0) if loop.isdtime(strict=True)
                  else np.all(closed.poles().real < 0))
    return {'phase_margin_deg': phase_margin,
            'gain_margin_db': 20 * math.log10(gain_margin) if np.isfinite(gain_margin)
            else float('inf'),
            'crossover_hz': crossover / (2 * math.pi),
            'phase_crossover_hz': phase_crossover / (2 * math.pi), 'stable': stable}


def _speed_pi_at(inner_w: control.LTI, crossover: float, phase_margin_deg: float,
                 dt: float | None) -> tuple[float, float]:
    """PI ``(Kp, Ki)`` giving ``phase_margin_deg`` at the crossover ``crossover`` [rad/s]."""
    grid = np.logspace(math.log10(crossover) - 4, math.log10(crossover), 80)
    response = _response(inner_w, grid)
    phase = np.unwrap(np.angle(response))[-1]
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
    kp = 1.0 / (abs(response[-1]) * abs(1.0 - 1j / (warped * ti)))
    return kp, kp / ti


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
        _, closed = speed_loops(inner, kp, ki, dt, reference)
        achieved = bandwidth_hz(closed[0, 0]) * 2 * math.pi
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
    return kp, ki, math.exp(log_crossover) / (2 * math.pi)


# ----------------------------------------------------------------------------- evaluation


@dataclass(frozen=True)
class Gains:
    """
    The controller gains of a design (continuous PI form ``kp + ki/s``).

    Attributes
    ----------
    current : tuple or None
        ``(Kp [V/A], Ki [V/(A s)])``; ``None`` in mechanical mode.
    speed : tuple
        ``(Kp, Ki)`` of the speed PI, output in A (full) or N m (mechanical).
    dt : float or None
        Sample period [s] of the discrete implementation (Tustin).
    torque_loop_hz : float or None
        Mechanical mode: the bandwidth assumed for the drive's torque loop (``None``: ideal).

    """

    current: tuple[float, float] | None
    speed: tuple[float, float]
    dt: float | None
    torque_loop_hz: float | None = None


def loops(motor: Motor, gains: Gains) -> dict:
    """
    Build every loop of a design for a (possibly perturbed) motor.

    Returns
    -------
    dict
        ``current_open``, ``current_closed`` (``i_ref -> i``; full mode only), ``speed_open``,
        ``speed_closed`` (``w_ref -> w, reference, ...``), as python-control systems.

    """
    reference = 'i_ref' if motor.mode == 'full' else 'torque_ref'
    inner = inner_loop(motor, gains.current, gains.torque_loop_hz, gains.dt)
    speed_open, speed_closed = speed_loops(inner, *gains.speed, gains.dt, reference)
    systems = {'speed_open': speed_open, 'speed_closed': speed_closed, 'inner': inner}
    if motor.mode == 'full':
        # inner_loop above has already refused a full-mode motor without current gains.
        assert gains.current is not None
        plant = _sampled(motor_model(motor), gains.dt)
        pi = pi_controller(*gains.current, gains.dt, 'e_i', 'u')
        systems['current_open'] = pi * plant[0, 0]
        systems['current_closed'] = inner[inner.output_labels.index('i'), 0]
    return systems


def loop_metrics(motor: Motor, gains: Gains) -> dict:
    """Return margins and closed-loop bandwidths of both loops for ``motor``."""
    systems = loops(motor, gains)
    out = {}
    if 'current_open' in systems:
        out['current'] = {**margins(systems['current_open']),
                          'bandwidth_hz': bandwidth_hz(systems['current_closed'])}
    out['speed'] = {**margins(systems['speed_open']),
                    'bandwidth_hz': bandwidth_hz(systems['speed_closed'][0, 0])}
    return out


def interval_motors(motor: Motor) -> tuple[list, list, list]:
    """
    Return the motors at the ends of the 95 % intervals.

    Returns
    -------
    ends : list of (name, side, Motor)
        One parameter at a time at ``value -/+ 1.96 stderr``.
    corners : list of (dict, Motor)
        Every corner of the box of the linear parameters' intervals.
    notes : list of str
        Parameters without a standard error, and lower ends clipped at 1 % of the value.

    """
    bounds, notes = {}, []
    for name in motor.linear_names:
        value, error = motor.values[name], motor.stderr.get(name, float('nan'))
        if not np.isfinite(error) or error == 0:
            if not np.isfinite(error):
                notes.append(f'{name} has no standard error: held at its value')
            continue
        low = value - Z95 * error
        if low <= 0.01 * value:
            notes.append(f'the 95 % interval of {name} reaches {low:.3g}: lower end clipped '
                         f'at 1 % of the value')
            low = 0.01 * value if value > 0 else 0.0
        bounds[name] = (low, value + Z95 * error)
    ends = [(name, side, motor.with_values(**{name: bounds[name][k]}))
            for name in bounds for k, side in enumerate(('low', 'high'))]
    corners = []
    for combination in itertools.product((0, 1), repeat=len(bounds)):
        values = {name: bounds[name][k] for name, k in zip(bounds, combination)}
        corners.append((values, motor.with_values(**values)))
    return ends, corners, notes


def robustness(motor: Motor, gains: Gains) -> dict:
    """
    Re-evaluate the nominal gains across the parameters' 95 % intervals.

    Returns
    -------
    dict
        ``one_at_a_time`` (a row per parameter end with its metrics), ``corners`` (number
        evaluated), ``range`` (min and max of every metric over ends and corners) and
        ``worst_corner`` (the corner of the smallest speed phase margin), ``notes``.

    """
    ends, corners, notes = interval_motors(motor)
    rows = []
    for name, side, perturbed in ends:
        rows.append({'parameter': name, 'end': side, 'value': perturbed.values[name],
                     **_flat(loop_metrics(perturbed, gains))})
    corner_rows = [({**values}, _flat(loop_metrics(perturbed, gains)))
                   for values, perturbed in corners]
    table = rows + [metrics for _, metrics in corner_rows]
    keys = list(_flat(loop_metrics(motor, gains)))
    spread = {}
    for key in keys:
        column = [row[key] for row in table if isinstance(row.get(key), float)]
        if column:
            spread[key] = [min(column), max(column)]
    worst = None
    if corner_rows:
        values, metrics = min(corner_rows, key=lambda item: item[1]['speed.phase_margin_deg'])
        worst = {'parameters': values, **metrics}
    return {'one_at_a_time': rows, 'corners': len(corner_rows), 'range': spread,
            'worst_corner': worst, 'notes': notes}


def _flat(metrics: dict) -> dict:
    return {f'{loop}.{key}': value for loop, values in metrics.items()
            for key, value in values.items() if key != 'phase_crossover_hz'}


def design(motor: Motor, options: DesignOptions) -> tuple[dict, Gains]:
    """
    Design the cascade for ``motor``.

    Parameters
    ----------
    motor : Motor
        From :func:`motor_from_result`.
    options : DesignOptions
        The request (defaults filled in by :func:`resolve_options`).

    Returns
    -------
    result : dict
        The design (the ``--json`` layout, see the README): ``current_loop``, ``speed_loop``,
        ``feedforward``, ``nominal`` metrics, ``robustness``, ``requested``, ``notes``.
    gains : Gains
        The gains, for :func:`loops` and the report.

    Raises
    ------
    DesignError
        When the request cannot be met.

    """
    options = resolve_options(motor, options)
    dt = options.sample_period_s
    full = motor.mode == 'full'
    # resolve_options sets the speed bandwidth always and the current one in full mode.
    current_bandwidth, speed_bandwidth = options.current_bandwidth_hz, options.speed_bandwidth_hz
    assert speed_bandwidth is not None
    current: tuple[float, float] | None = None
    correction: float | None = None
    if full:
        assert current_bandwidth is not None
        current, correction = sampled_current_pi(motor, current_bandwidth, dt)
    torque_loop = None if full else current_bandwidth
    notes = _design_notes(full, torque_loop, current_bandwidth or speed_bandwidth, dt)
    reference = 'i_ref' if full else 'torque_ref'
    inner = inner_loop(motor, current, torque_loop, dt)
    kp, ki, crossover = design_speed(inner, speed_bandwidth,
                                     options.phase_margin_deg, dt, reference)
    gains = Gains(current, (kp, ki), dt, torque_loop)
    nominal = loop_metrics(motor, gains)
    if not all(values['stable'] for values in nominal.values()):
        raise DesignError('the designed loops are unstable at this sample period: lower the '
                          'bandwidths or sample faster.')
    result = _design_header(motor, options)
    if full:
        assert current is not None and current_bandwidth is not None
        result['current_loop'] = _current_loop(motor, current, correction, current_bandwidth, dt)
    result['speed_loop'] = _speed_loop(motor, (kp, ki), crossover, options, reference)
    result['feedforward'] = feedforward(motor)
    result['nominal'] = nominal
    result['robustness'] = robustness(motor, gains)
    result['notes'] = notes + result['robustness']['notes']
    return result, gains


def _design_notes(full: bool, torque_loop: float | None, fastest: float,
                  dt: float | None) -> list[str]:
    """Return the notes on the mode and on a bandwidth close to the sampling rate."""
    notes = []
    if not full:
        notes.append('mechanical-only result (J, b, Mc): the speed loop acts on a torque '
                     'command; the current loop needs Ra and La (identify with voltage).')
        notes.append('torque loop assumed ideal' if torque_loop is None else
                     f'torque loop assumed first order with {torque_loop:g} Hz bandwidth')
    if dt is not None and fastest > 0.1 / dt:
        notes.append(f'{fastest:g} Hz is above a tenth of the sampling rate {1 / dt:g} Hz: the '
                     'sampled loop keeps the bandwidth but loses gain margin (see the table); '
                     'a computation delay in the drive would cost more.')
    return notes


def _design_header(motor: Motor, options: DesignOptions) -> dict[str, Any]:
    """Return the design's first keys: the mode, the shaft, the request and the motor."""
    return {
        'mode': motor.mode, 'shaft': motor.shaft, 'gear_ratio': motor.gear_ratio,
        'sample_period_s': options.sample_period_s,
        'requested': {'current_bandwidth_hz': options.current_bandwidth_hz,
                      'speed_bandwidth_hz': options.speed_bandwidth_hz,
                      'phase_margin_deg': options.phase_margin_deg},
        'motor': {'values': dict(motor.values), 'stderr': dict(motor.stderr),
                  'torque_constant': motor.torque_constant},
    }


def _current_loop(motor: Motor, current: tuple[float, float], correction: float | None,
                  bandwidth_hz: float, dt: float | None) -> dict[str, Any]:
    """Return the ``current_loop`` entry of the design (full mode)."""
    pi = pi_controller(*current, dt, 'e_i', 'u')
    return {
        'kp': current[0], 'ki': current[1], 'ti_s': current[0] / current[1],
        'units': {'kp': 'V/A', 'ki': 'V/(A s)'}, 'input': 'i_ref - i [A]', 'output': 'u [V]',
        'method': 'pole-zero cancellation of the armature pole (Ti = La/Ra, '
                  'Kp = 2 pi f_c La)' + ('' if dt is None else
                                         ', f_c scaled for the sampled loop'),
        'closed_form': dict(zip(('kp', 'ki'),
                                current_pi(motor, bandwidth_hz))),
        'sampling_correction': correction,
        'discrete': _difference_equation(pi) if dt is not None else None,
        'back_emf_feedforward_v_per_rad_s': motor.values['CPhi'],
    }


def _speed_loop(motor: Motor, speed: tuple[float, float], crossover: float,
                options: DesignOptions, reference: str) -> dict[str, Any]:
    """Return the ``speed_loop`` entry of the design (and its current gains if known)."""
    kp, ki = speed
    dt = options.sample_period_s
    pi = pi_controller(kp, ki, dt, 'e_w', reference)
    unit = 'A' if motor.mode == 'full' else 'N m'
    speed_loop = {
        'kp': kp, 'ki': ki, 'ti_s': kp / ki,
        'units': {'kp': f'{unit} s/rad', 'ki': f'{unit}/rad'},
        'input': 'w_ref - w [rad/s]', 'output': f'{reference} [{unit}]',
        'method': f'PI with {options.phase_margin_deg:g} deg phase margin at the crossover '
                  'giving the requested closed-loop bandwidth (exact closed inner loop)',
        'design_crossover_hz': crossover,
        'discrete': _difference_equation(pi) if dt is not None else None,
    }
    if motor.mode != 'full' and motor.torque_constant:
        speed_loop['current'] = {'kp': kp / motor.torque_constant,
                                 'ki': ki / motor.torque_constant,
                                 'units': {'kp': 'A s/rad', 'ki': 'A/rad'}}
    return speed_loop


def format_design(result: dict) -> str:
    """Render a design as a readable table."""
    dt = result['sample_period_s']
    made = ('current and speed loops' if result['mode'] == 'full' else
            'speed loop only, on an ideal torque source: the result has no electrical model')
    lines = [f"design: mode {result['mode']} ({made}), {result['shaft']} shaft (gear ratio "
             f"{result['gear_ratio']:g}), " + (f'sample period {dt:g} s (Tustin)' if dt
                                               else 'continuous')]
    request = result['requested']
    for name, label in (('current_loop', 'current'), ('speed_loop', 'speed')):
        if name not in result:
            continue
        loop = result[name]
        metrics = result['nominal'][label]
        asked = request[f'{label}_bandwidth_hz']
        lines.append(f"{label + ' PI':<9} kp = {loop['kp']:.5g} {loop['units']['kp']}, "
                     f"ki = {loop['ki']:.5g} {loop['units']['ki']} (Ti {loop['ti_s']:.4g} s)")
        lines.append(f"{'':<9} bandwidth {metrics['bandwidth_hz']:.4g} Hz (asked "
                     f"{asked:.4g}), phase margin {metrics['phase_margin_deg']:.3g} deg, gain "
                     f"margin {metrics['gain_margin_db']:.3g} dB")
    ff = result['feedforward']
    lines.append(f"feedforward kS = {ff['kS']:.5g} {ff['units']['kS']}, kV = {ff['kV']:.5g} "
                 f"{ff['units']['kV']}, kA = {ff['kA']:.5g} {ff['units']['kA']}")
    spread = result['robustness']['range']
    for key in ('current.phase_margin_deg', 'speed.phase_margin_deg', 'speed.bandwidth_hz'):
        if key in spread:
            lines.append(f'over the 95 % intervals: {key} {spread[key][0]:.4g} .. '
                         f'{spread[key][1]:.4g}')
    lines.extend(f'note: {note}' for note in result['notes'])
    return '\n'.join(lines)


# ----------------------------------------------------------------------------- simulation


def simulate_cascade(params: Any, result: dict, reference: np.ndarray, loop: str = 'speed',
                     initial_speed_rad_s: float = 0.0) -> dict:
    """
    Run the discrete cascade of a design on the exact (hybrid, Coulomb friction) simulator.

    The controller measures ``i[k], w[k]`` at each sample instant and holds its voltage
    ``u[k]`` over the next period (no computation delay), with the Tustin difference
    equations of the design (``result[...]['discrete']``).

    Parameters
    ----------
    params : MotorParameters
        The true motor, in the units of the design's shaft.
    result : dict
        A full-mode design with a sample period.
    reference : numpy.ndarray
        ``w_ref[k]`` [rad/s] (``loop='speed'``) or ``i_ref[k]`` [A] (``loop='current'``: the
        speed loop open, the current loop alone).
    loop : str
        ``'speed'`` or ``'current'``.
    initial_speed_rad_s : float
        The run starts in the steady state at this speed (controllers initialised to hold it).

    Returns
    -------
    dict
        ``speed``, ``current``, ``voltage`` per sample.

    """
    from dcmotor_id.simulation import MotorStepper
    dt = result['sample_period_s']
    if result['mode'] != 'full' or dt is None:
        raise DesignError('the cascade simulation needs a full-mode design with a sample period')
    current_pi_, speed_pi = result['current_loop']['discrete'], result['speed_loop']['discrete']
    w = float(initial_speed_rad_s)
    i = (params.b * w + params.Mc * np.sign(w)) / params.CPhi
    u = params.Ra * i + params.CPhi * w
    stepper = MotorStepper(params, dt, (i, w))
    i_ref, e_w_prev, e_i_prev = i, 0.0, 0.0
    out = {name: np.empty(len(reference)) for name in ('speed', 'current', 'voltage')}
    for k, target in enumerate(np.asarray(reference, dtype=float)):
        if loop == 'speed':
            e_w = target - w
            i_ref += speed_pi['q0'] * e_w + speed_pi['q1'] * e_w_prev
            e_w_prev = e_w
        else:
            i_ref = target
        e_i = i_ref - i
        u += current_pi_['q0'] * e_i + current_pi_['q1'] * e_i_prev
        e_i_prev = e_i
        out['speed'][k], out['current'][k], out['voltage'][k] = w, i, u
        i, w = stepper.step(u)
    return out


def measured_bandwidth_hz(params: Any, result: dict, loop: str = 'speed',
                          bias_rad_s: float = 40.0, amplitude: float | None = None) -> dict:
    """
    Measure a closed loop's -3 dB bandwidth on the exact simulator (multisine lock-in).

    At a steady bias speed (Coulomb friction then a constant torque the integrators hold)
    the reference gets a Schroeder-phased multisine of 60 tones spaced ``f/20`` up to ``3 f``
    (``f`` the requested bandwidth). After one settling period the gain ``|Y/R|`` at every
    tone comes from the FFT of one full period; the bandwidth is the first frequency where
    the gain falls below ``1/sqrt(2)`` (the DC gain is 1: integral action), interpolated
    linearly in log gain over log frequency between the two tones around it.

    Returns
    -------
    dict
        ``bandwidth_hz``, ``frequency_hz`` and ``gain`` of the tones.

    """
    dt = result['sample_period_s']
    target = result['requested'][f'{loop}_bandwidth_hz']
    samples = int(round(20.0 / target / dt))
    resolution = 1.0 / (samples * dt)
    tones = np.arange(1, 61)
    phases = -np.pi * tones * (tones - 1) / len(tones)
    time = np.arange(2 * samples) * dt
    if amplitude is None:
        amplitude = 0.05 if loop == 'speed' else 0.02
    w0 = bias_rad_s
    i0 = (params.b * w0 + params.Mc) / params.CPhi
    bias = w0 if loop == 'speed' else i0
    scale = bias * amplitude / np.sqrt(len(tones))
    wave = scale * np.sin(2 * np.pi * resolution * tones[:, None] * time + phases[:, None]).sum(0)
    run = simulate_cascade(params, result, bias + wave, loop, w0)
    output = run['speed'] if loop == 'speed' else run['current']
    spectrum_out = np.fft.rfft(output[samples:] - bias)[tones]
    spectrum_in = np.fft.rfft(wave[samples:])[tones]
    gain = np.abs(spectrum_out / spectrum_in)
    frequency = tones * resolution
    level = 1.0 / math.sqrt(2.0)
    below = np.nonzero(gain < level)[0]
    bandwidth = float('nan')
    if below.size and below[0] > 0:
        k = below[0]
        x = np.log([frequency[k - 1], frequency[k]])
        y = np.log([gain[k - 1], gain[k]])
        bandwidth = float(np.exp(x[0] + (math.log(level) - y[0]) * (x[1] - x[0]) / (y[1] - y[0])))
    return {'bandwidth_hz': bandwidth, 'frequency_hz': frequency, 'gain': gain}
