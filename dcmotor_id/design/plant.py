"""
The plant a controller is designed for, and the options of the design.

:class:`Motor` is the motor as the design sees it (values and 95 % intervals read from an
``identify --json`` result by :func:`motor_from_result`, on the motor or the output shaft);
:class:`DesignOptions` are the bandwidths, phase margin and sample period asked for, completed
from the motor by :func:`resolve_options`. The loops themselves are in
:mod:`dcmotor_id.design.loops`, the design in :mod:`dcmotor_id.design.control`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import json
from typing import Any

import numpy as np

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
LINEAR_VOLTAGE_SPEED = ('kA', 'kV')
#: Voltage-speed mode with the armature lag: ``Ta`` and the inertia's ``kA = Ra J/CPhi`` too.
LINEAR_VOLTAGE_SPEED_LAG = ('kA', 'kV', 'Ta', 'kA_inertia')
#: The parameters of each mode of an identify result, and those that must be positive.
MODE_NAMES = {'full': ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc'), 'mechanical': ('J', 'b', 'Mc'),
              'voltage_speed': ('kS', 'kV', 'kA')}
POSITIVE = ('Ra', 'La', 'CPhi', 'J', 'kV', 'kA')


class DesignError(DcMotorIdError):
    """The requested design cannot be met (bandwidths, phase margin, sample period)."""


@dataclass(frozen=True)
class Motor:
    """
    The identified motor seen from the controlled shaft (SI units).

    Attributes
    ----------
    values : dict
        ``Ra, La, CPhi, J, b, Mc`` (full mode), ``J, b, Mc`` (mechanical mode) or
        ``kS, kV, kA`` (voltage_speed mode: identified without a current); where the
        identification found the armature lag, ``kA`` is its acceleration gain
        ``kA + Ta Ra b/CPhi`` and ``Ta`` [s] and ``kA_inertia`` (the identified
        ``kA = Ra J/CPhi``) complete the second-order plant
        ``1/(Ta kA_inertia s^2 + kA s + kV)``.
    stderr : dict
        Standard error of each value (``nan`` when unknown), same units.
    mode : str
        ``'full'``, ``'mechanical'`` (``dcmotor-id identify --torque-constant``) or
        ``'voltage_speed'``.
    torque_constant : float or None
        ``K`` [N m/A] of the mechanical mode (torque = K * current), on the controlled shaft.
    gear_ratio : float
        ``N``, motor speed / output speed.
    shaft : str
        ``'motor'`` or ``'output'``: where speeds, torques and gains are expressed.
    effects : tuple of dict
        The effects the identification found, ``{"name", "parameters"}`` each, on the motor
        shaft (:func:`effects_of`): exported to ``sim_motor``, the break-away friction of a
        Stribeck effect in ``kS``, each named in the design's notes.

    """

    values: dict
    stderr: dict
    mode: str = 'full'
    torque_constant: float | None = None
    gear_ratio: float = 1.0
    shaft: str = 'motor'
    effects: tuple = ()

    @property
    def linear_names(self) -> tuple:
        """Names of the parameters that shape the linear loops."""
        if self.mode == 'voltage_speed' and 'Ta' in self.values:
            return LINEAR_VOLTAGE_SPEED_LAG
        return {'full': LINEAR_FULL, 'voltage_speed': LINEAR_VOLTAGE_SPEED}.get(
            self.mode, LINEAR_MECHANICAL)

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
        ``b N^2``, ``Mc N``, ``K N``; ``kV N``, ``kA N`` of the voltage-to-speed model, whose
        ``Ta`` stays).

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
    if mode not in (None, *MODE_NAMES):
        raise InputDataError(f'the result has mode {mode!r}; it must be "full", "mechanical" '
                             'or "voltage_speed" (as `dcmotor-id identify --json` writes it)')
    mechanical = mode == 'mechanical' or (mode is None and all(
        given.get(name) is None for name in ('Ra', 'La', 'CPhi')))
    mode = 'mechanical' if mechanical else mode or 'full'
    values, stderr = _checked_values(result, MODE_NAMES[mode])
    gain, lag = acceleration_gain(result), armature_lag(result)
    if gain is not None and lag is not None:
        values['kA_inertia'], stderr['kA_inertia'] = values['kA'], stderr['kA']
        values['Ta'], stderr['Ta'] = lag
    if gain is not None:
        values['kA'], stderr['kA'] = gain
    torque_constant = None
    if mechanical:
        torque_constant = _number(result.get('torque_constant'))
        if not (np.isfinite(torque_constant) and torque_constant > 0):
            torque_constant = None
    if output_shaft:
        scale = {'CPhi': gear_ratio, 'J': gear_ratio ** 2, 'b': gear_ratio ** 2,
                 'Mc': gear_ratio, 'kV': gear_ratio, 'kA': gear_ratio,
                 'kA_inertia': gear_ratio}
        values = {name: value * scale.get(name, 1.0) for name, value in values.items()}
        stderr = {name: value * scale.get(name, 1.0) for name, value in stderr.items()}
        if torque_constant is not None:
            torque_constant *= gear_ratio
    return Motor(values, stderr, mode, torque_constant, float(gear_ratio),
                 'output' if output_shaft else 'motor', effects_of(result))


def acceleration_gain(result: dict) -> tuple[float, float] | None:
    """
    Return the acceleration gain a voltage-to-speed design uses, with its standard error.

    ``combined['acceleration_gain']`` = ``kA + Ta Ra b/CPhi`` (``Ta = La/Ra``), reported when
    the armature lag shapes the speed, is the coefficient of ``dw/dt`` in the exact
    ``u = kS sgn w + kV w + (kA + Ta Ra b/CPhi) dw/dt + Ta kA d2w/dt2``: what a feedforward
    that neglects the jerk needs, and the coefficient of ``s`` in the plant's denominator;
    the data fix it far better than ``kA`` (0.09 % against 7.5 % Cramer-Rao bound on a
    SysId routine). ``bench/design_results.md`` measured the feedforward and the speed loop
    with each. None when the result has no such entry (the first-order model, whose ``kA``
    is that coefficient) or it is unusable.
    """
    if result.get('mode') != 'voltage_speed':
        return None
    entry = (result.get('combined') or {}).get('acceleration_gain')
    if not isinstance(entry, dict):
        return None
    value = _number(entry.get('value'))
    if not (np.isfinite(value) and value > 0):
        return None
    error = _number(entry.get('stderr'))
    return value, abs(error) if np.isfinite(error) else float('nan')


def armature_lag(result: dict) -> tuple[float, float] | None:
    """
    Return the armature time constant ``Ta = La/Ra`` [s] of a voltage-to-speed result.

    ``combined['armature_time_constant_s']`` with its standard error (nan when unknown); None
    for another mode, a result without it (the first-order model) or an unusable value.
    """
    if result.get('mode') != 'voltage_speed':
        return None
    entry = (result.get('combined') or {}).get('armature_time_constant_s')
    value = _number(entry.get('value')) if isinstance(entry, dict) else float('nan')
    if not (np.isfinite(value) and value > 0):
        return None
    error = _number(entry.get('stderr'))  # type: ignore[union-attr]
    return value, abs(error) if np.isfinite(error) else float('nan')


def effects_of(result: dict) -> tuple:
    """
    Return the effects of an identify result (``{"name", "parameters"}`` each, JSON numbers).

    Raises
    ------
    InputDataError
        An entry that is not ``{"name": ..., "parameters": {...}}``.

    """
    found = []
    for effect in result.get('effects') or []:
        if not (isinstance(effect, dict) and isinstance(effect.get('name'), str)
                and isinstance(effect.get('parameters', {}), dict)):
            raise InputDataError(f'effect {json.dumps(effect)[:80]} is not {{"name": ..., '
                                 '"parameters": {...}}; give the JSON written by dcmotor-id '
                                 'identify --json')
        found.append({'name': effect['name'], 'parameters': dict(effect.get('parameters', {}))})
    return tuple(found)


def breakaway_excess(motor: Motor) -> float:
    """
    Return the static minus Coulomb friction of a Stribeck effect on the controlled shaft.

    0 without a Stribeck effect (or one without a positive ``excess_Nm``); on the output
    shaft the torque is multiplied by the gear ratio as ``Mc`` is.
    """
    scale = motor.gear_ratio if motor.shaft == 'output' else 1.0
    for effect in motor.effects:
        if effect['name'] == 'stribeck':
            excess = _number(effect['parameters'].get('excess_Nm'))
            if np.isfinite(excess) and excess > 0:
                return excess * scale
    return 0.0


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
        positive = name in POSITIVE
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
            f'the result holds unusable parameters ({", ".join(bad)}): Ra, La, CPhi, J (kV, '
            'kA) must be finite and positive, b and Mc (kS) finite and >= 0. Identify the '
            'motor again (more excitation, `dcmotor-id identify ... --json OUT`) before '
            'designing a controller.')
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
    if current is not None and motor.mode == 'voltage_speed':
        raise DesignError(f'--current-bandwidth {current:g} Hz: the result was identified '
                          'without a current (kS, kV, kA), so there is no current loop to '
                          'design; leave --current-bandwidth out (the speed loop then acts on '
                          'the voltage)')
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


def armature_lag_note(result: dict, speed_bandwidth_hz: float) -> list[str]:
    """
    Return the notes on the armature lag of a voltage-to-speed result, when it was found.

    The identification reports ``Ta = La/Ra`` in ``combined['armature_time_constant_s']``
    when the lag shapes the speed, and with it the acceleration gain
    (:func:`acceleration_gain`), which the design then uses for ``kA`` (a note says so,
    with both values). The speed loop's plant is then the second-order
    ``1/(Ta kA s^2 + (kA + Ta Ra b/CPhi) s + kV)`` (a note gives it, and says when the speed
    bandwidth comes within a factor 5 of the lag's pole ``1/(2 pi Ta)``: the margins then
    rest on ``Ta``).
    """
    lag, gain = armature_lag(result), acceleration_gain(result)
    if lag is None:
        return []
    identified = _number(result['parameters'].get('kA'))
    pole_hz = 1.0 / (2.0 * np.pi * lag[0])
    if gain is None:  # no coefficient of dw/dt to go with Ta: the first-order plant
        return [f'the armature lag Ta = {lag[0]:.3g} s (a pole at {pole_hz:.3g} Hz) is '
                'neglected by the speed loop (plant kA s + kV; the result has no '
                'combined.acceleration_gain to go with it)']
    notes = [
        f'kA of the feedforward is the acceleration gain kA + Ta Ra b/CPhi = {gain[0]:.4g} V '
        f's^2/rad (combined.acceleration_gain), not the identified kA = {identified:.4g}: '
        'the coefficient of dw/dt when the jerk is neglected, determined far better by the '
        'data; it predicts the voltage and tracks a speed profile at least as well on '
        'simulated motors (bench/design_results.md)']
    text = (f"the speed loop's plant includes the armature lag Ta = {lag[0]:.3g} s: "
            f'1/(Ta kA s^2 + (kA + Ta Ra b/CPhi) s + kV) with kA = {identified:.4g} (a pole '
            f'near {pole_hz:.3g} Hz)')
    if speed_bandwidth_hz > 0.2 * pole_hz:
        text += (f'; the speed bandwidth {speed_bandwidth_hz:.3g} Hz is above a fifth of '
                 '1/(2 pi Ta): the margins rest on Ta (its 95 % interval is in the robustness '
                 'range)')
    return notes + [text]
