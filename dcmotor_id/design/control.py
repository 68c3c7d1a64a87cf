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

The motor and the options come from :mod:`dcmotor_id.design.plant`, the loops from
:mod:`dcmotor_id.design.loops`; this module designs, evaluates and simulates the cascade.
It imports no rclpy; :mod:`dcmotor_id.design.export` writes the model files and
:mod:`dcmotor_id.reports.design` the HTML page.
"""


from __future__ import annotations

from dataclasses import dataclass
import itertools
import math
from typing import Any

import numpy as np

from dcmotor_id.design.loops import (achievable_speed_bandwidths, bandwidth_hz, current_pi,
                                     decade_speed_pi, design_speed, difference_equation,
                                     feedforward, feedforward_step_overshoot_pct,
                                     inner_loop, margins, motor_model, pi_controller,
                                     sampled_current_pi, sampled_system, speed_loops,
                                     step_overshoot_pct)
from dcmotor_id.design.plant import DesignError, DesignOptions, Motor, resolve_options, Z95


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


def reference_of(motor: Motor) -> str:
    """Return the speed PI's output: the current, torque or voltage reference."""
    return {'full': 'i_ref', 'voltage_speed': 'u'}.get(motor.mode, 'torque_ref')


def loops(motor: Motor, gains: Gains) -> dict:
    """
    Build every loop of a design for a (possibly perturbed) motor.

    Returns
    -------
    dict
        ``current_open``, ``current_closed`` (``i_ref -> i``; full mode only), ``speed_open``,
        ``speed_closed`` (``w_ref -> w, reference, ...``), as python-control systems.

    """
    reference = reference_of(motor)
    inner = inner_loop(motor, gains.current, gains.torque_loop_hz, gains.dt)
    speed_open, speed_closed = speed_loops(inner, *gains.speed, gains.dt, reference)
    systems = {'speed_open': speed_open, 'speed_closed': speed_closed, 'inner': inner}
    if motor.mode == 'full':
        # inner_loop above has already refused a full-mode motor without current gains.
        assert gains.current is not None
        plant = sampled_system(motor_model(motor), gains.dt)
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
    notes = _design_notes(motor.mode, torque_loop, current_bandwidth or speed_bandwidth, dt)
    reference = reference_of(motor)
    inner = inner_loop(motor, current, torque_loop, dt)
    kp, ki, crossover, speed_notes = _speed_pi(motor, inner, speed_bandwidth,
                                               options.phase_margin_deg, dt)
    gains = Gains(current, (kp, ki), dt, torque_loop)
    nominal = loop_metrics(motor, gains)
    speed_notes += _step_overshoot(motor, inner, gains, nominal['speed'])
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
    result['notes'] = notes + speed_notes + effect_notes(motor) + result['robustness']['notes']
    return result, gains


def _speed_pi(motor: Motor, inner: Any, bandwidth: float, phase_margin_deg: float,
              dt: float | None) -> tuple[float, float, float, list[str]]:
    """
    Return the speed PI ``(Kp, Ki, crossover [Hz])`` and the notes on a lowered bandwidth.

    A voltage-to-speed plant with the armature lag has a highest speed bandwidth a PI reaches
    with the phase margin (the lag's phase), where the PI's integral action vanishes; a
    bandwidth above it is lowered to that of the fastest PI whose zero lies a decade below its
    crossover (:func:`~dcmotor_id.design.loops.decade_speed_pi`), and a note says so. Any
    other unmet request is refused (:class:`DesignError`).
    """
    reference = reference_of(motor)
    try:
        return (*design_speed(inner, bandwidth, phase_margin_deg, dt, reference), [])
    except DesignError:
        if not (motor.mode == 'voltage_speed' and 'Ta' in motor.values):
            raise
        highest = achievable_speed_bandwidths(inner, phase_margin_deg, dt, reference,
                                              bandwidth)[1]
        if not (np.isfinite(highest) and bandwidth > highest):
            raise
    kp, ki, crossover, lowered = decade_speed_pi(inner, phase_margin_deg, dt, reference,
                                                 highest)
    note = (f'--speed-bandwidth {bandwidth:g} Hz is beyond the armature lag: with '
            f'{phase_margin_deg:g} deg phase margin a PI reaches at most {highest:.3g} Hz on '
            'this plant, its integral action vanishing there; the loop is designed for '
            f'{lowered:.3g} Hz, the fastest PI whose zero lies a decade below its crossover '
            '(ask for less, or a smaller --phase-margin)')
    return kp, ki, crossover, [note]


def _step_overshoot(motor: Motor, inner: Any, gains: Gains, nominal: dict) -> list[str]:
    """
    Put the speed step's overshoot into the nominal figures; return the note on it.

    ``nominal['step_overshoot_pct']``: the closed speed loop's ``w_ref -> w`` (the PI alone).
    Voltage-speed mode also notes the step with the static feedforward added.
    """
    nominal['step_overshoot_pct'] = step_overshoot_pct(
        loops(motor, gains)['speed_closed'][0, 0], nominal['bandwidth_hz'])
    if motor.mode != 'voltage_speed':
        return []
    with_feedforward = feedforward_step_overshoot_pct(inner, *gains.speed, motor.values['kV'],
                                                      gains.dt, nominal['bandwidth_hz'])
    return [f"a step of the speed reference overshoots by {nominal['step_overshoot_pct']:.3g} "
            f'% with the PI alone, by {with_feedforward:.3g} % with the static feedforward '
            'kS sgn(w_ref) + kV w_ref added: the feedforward holds the new speed, so the '
            'integral gives back what it gathered on the rise; feed the feedforward and the PI '
            'a profiled reference (e.g. WPILib TrapezoidProfile), not a step']


#: What the controller does with each effect beyond ignoring it in the linear loops.
EFFECT_REMARKS = {
    'stribeck': 'kS is its break-away friction (Mc + excess); the speed PI ignores the '
                "friction's fall with speed",
    'load_torque': "the speed PI's integral holds the constant torque; the feedforward leaves "
                   'it out',
    'coulomb_asymmetry': 'kS is one value for both directions',
    'viscous_asymmetry': 'kV is one value for both directions',
    'cogging': 'the torque ripple with the angle is left to the speed PI',
    'quadratic_drag': 'kV holds the viscous part alone',
    'sensor_delay': 'the loops assume sensors without delay: the margins are lower by the '
                    'phase of the delay',
}


def effect_notes(motor: Motor) -> list[str]:
    """Return a note per effect of the identification: what the controller ignores of it."""
    notes = []
    for effect in motor.effects:
        values = ', '.join(f'{key} = {value:.4g}' if isinstance(value, float) else
                           f'{key} = {value}' for key, value in effect['parameters'].items())
        remark = EFFECT_REMARKS.get(effect['name'])
        notes.append(f"effect {effect['name']} ({values}): the linear loops ignore it"
                     + (f'; {remark}' if remark else ''))
    return notes


def design_controller(result: Any, current_bandwidth_hz: float | None = None,
                      speed_bandwidth_hz: float | None = None,
                      phase_margin_deg: float = 60.0, sample_period_s: float | None = None,
                      gear_ratio: float = 1.0, output_shaft: bool = False,
                      gravity_load: bool = False) -> dict:
    """
    Design the controller for an identification result (what ``dcmotor-id design`` prints).

    Parameters
    ----------
    result : IdentificationResult or dict
        The result of :func:`~dcmotor_id.identification.identify.identify`, or its JSON.
    current_bandwidth_hz, speed_bandwidth_hz, phase_margin_deg, sample_period_s : float
        The request (:class:`~dcmotor_id.design.plant.DesignOptions`; None: the defaults).
    gear_ratio : float
        Motor speed / output speed.
    output_shaft : bool
        Design on the output shaft.
    gravity_load : bool
        Take the identified load torque as an elevator's gravity (``kG``).

    Returns
    -------
    dict
        The design JSON: ``speed_loop``, ``current_loop`` (full mode), ``feedforward``,
        ``nominal``, ``robustness``, ``notes``.

    Examples
    --------
    >>> import dcmotor_id as dm
    >>> values = dm.PAPER_MOTORS['paper2'].as_dict(derived=False)
    >>> made = dm.design_controller({'parameters': values, 'stderr': {}, 'mode': 'full'})
    >>> round(made['feedforward']['kV'], 4), round(made['nominal']['speed']['bandwidth_hz'], 3)
    (1.3857, 20.0)

    """
    from dcmotor_id.design.loops import add_gravity, gravity_feedforward
    from dcmotor_id.design.plant import armature_lag_note, motor_from_result
    data = result if isinstance(result, dict) else result.as_dict()
    motor = motor_from_result(data, gear_ratio, output_shaft)
    made, _ = design(motor, DesignOptions(current_bandwidth_hz, speed_bandwidth_hz,
                                          phase_margin_deg, sample_period_s))
    made['notes'] += armature_lag_note(data, made['nominal']['speed']['bandwidth_hz'])
    if gravity_load:
        add_gravity(made['feedforward'], gravity_feedforward(motor))
    return made


def _design_notes(mode: str, torque_loop: float | None, fastest: float,
                  dt: float | None) -> list[str]:
    """Return the notes on the mode and on a bandwidth close to the sampling rate."""
    notes = []
    if mode == 'voltage_speed':
        notes.append('voltage-to-speed result (kS, kV, kA; no current): the speed PI acts on '
                     'the voltage, plant kA s + kV (with Ta kA s^2 where the identification '
                     'found the armature lag Ta); no current loop (it needs Ra and La: '
                     'identify with the current)')
    elif mode == 'mechanical':
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
        'discrete': difference_equation(pi) if dt is not None else None,
        'back_emf_feedforward_v_per_rad_s': motor.values['CPhi'],
    }


def _speed_loop(motor: Motor, speed: tuple[float, float], crossover: float,
                options: DesignOptions, reference: str) -> dict[str, Any]:
    """Return the ``speed_loop`` entry of the design (and its current gains if known)."""
    kp, ki = speed
    dt = options.sample_period_s
    pi = pi_controller(kp, ki, dt, 'e_w', reference)
    unit = {'full': 'A', 'voltage_speed': 'V'}.get(motor.mode, 'N m')
    speed_loop = {
        'kp': kp, 'ki': ki, 'ti_s': kp / ki,
        'units': {'kp': f'{unit} s/rad', 'ki': f'{unit}/rad'},
        'input': 'w_ref - w [rad/s]', 'output': f'{reference} [{unit}]',
        'method': f'PI with {options.phase_margin_deg:g} deg phase margin at the crossover '
                  'giving the requested closed-loop bandwidth (exact closed inner loop)',
        'design_crossover_hz': crossover,
        'discrete': difference_equation(pi) if dt is not None else None,
    }
    if motor.mode != 'full' and motor.torque_constant:
        speed_loop['current'] = {'kp': kp / motor.torque_constant,
                                 'ki': ki / motor.torque_constant,
                                 'units': {'kp': 'A s/rad', 'ki': 'A/rad'}}
    return speed_loop


def format_design(result: dict) -> str:
    """Render a design as a readable table."""
    dt = result['sample_period_s']
    made = {'full': 'current and speed loops',
            'voltage_speed': 'speed loop on the voltage: the result has no current'}.get(
        result['mode'], 'speed loop only, on an ideal torque source: the result has no '
        'electrical model')
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
                     f"margin {metrics['gain_margin_db']:.3g} dB" + (
                         f", step overshoot {metrics['step_overshoot_pct']:.3g} %"
                         if 'step_overshoot_pct' in metrics else ''))
    ff = result['feedforward']
    lines.append(f"feedforward kS = {ff['kS']:.5g} {ff['units']['kS']}, kV = {ff['kV']:.5g} "
                 f"{ff['units']['kV']}, kA = {ff['kA']:.5g} {ff['units']['kA']}"
                 + (f", kG = {ff['kG']:.5g} {ff['units']['kG']}" if 'kG' in ff else ''))
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
