"""
Channels a recording cannot identify from: recognised on reading, refused naming the channel.

Three ways a channel carries no usable information although it holds numbers:

* a **current sampled inside the PWM cycle**: the ADC catches the on- or the off-phase of the
  switching, so many samples are exactly zero between non-zero neighbours (a bimodal signal);
* a **speed quantised so coarsely** (encoder pulses counted per sample) that most differences
  between consecutive samples are zero and it spans fewer than :data:`REFUSED_LEVELS` steps
  (a coarse speed with more levels is kept, :func:`coarse_speed` words its warning);
* a **voltage that is a command never reaching the motor**: constant while the current
  changes in a way the armature balance ``u = Ra i + La di/dt + CPhi w`` cannot explain (a
  set-point, or the input of a current-controlled drive); a constant voltage logged from the
  instant it was applied, the motor starting from rest, satisfies the balance and is kept.

:func:`check_channels` raises :class:`~dcmotor_id.core.errors.InputDataError` with a message that
names the channel, what was seen and what to do.  A current that never reads below zero while
the speed reverses (:func:`magnitude_current`: a magnitude, its sign lost) is said in a note.
"""

from __future__ import annotations

from typing import Optional
import warnings

import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.core.checks import Check, register
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import Record
from dcmotor_id.formats.mapping import ReadingNote
from dcmotor_id.signals.filters import unwrap_turns

#: Fraction of the driven samples exactly zero between non-zero neighbours: PWM-sampled.
PWM_ZERO_FRACTION = 0.1
#: Fraction of consecutive differences of a moving shaft exactly zero: too coarse a speed.
QUANTISED_ZERO_FRACTION = 0.4
#: Distinct levels over the speed's range below which a speed counts as coarse (a warning).
QUANTISED_LEVELS = 64
#: Distinct levels below which a coarse speed is refused (nothing can be drawn from it).
REFUSED_LEVELS = 8
#: Relative spread of the current that counts as changing (of its largest magnitude).
CURRENT_CHANGE = 0.1
#: Fewest samples the checks look at.
MIN_CHECK_SAMPLES = 20


def pwm_sampled_current(record: Record) -> Optional[str]:
    """Return the message when the current looks sampled inside the PWM cycle, else None."""
    current = record.current
    if current is None or len(current) < MIN_CHECK_SAMPLES:
        return None
    current = np.asarray(current, dtype=float)
    scale = float(np.max(np.abs(current)))
    if not np.isfinite(scale) or scale == 0:
        return None
    driven = np.ones(current.shape, dtype=bool)
    if record.voltage is not None:
        voltage = np.abs(np.asarray(record.voltage, dtype=float))
        driven = voltage > 0.05 * float(np.max(voltage))
    zero = current == 0.0
    neighbours = np.zeros_like(zero)
    big = np.abs(current) > 0.05 * scale
    neighbours[1:-1] = big[:-2] | big[2:]
    isolated = zero & neighbours & driven
    count = int(np.count_nonzero(driven))
    fraction = np.count_nonzero(isolated) / max(count, 1)
    if count < MIN_CHECK_SAMPLES or fraction < PWM_ZERO_FRACTION:
        return None
    return (f"{record.source or 'record'}: channel 'current' looks sampled inside the PWM "
            f'cycle: {100 * fraction:.0f} % of the samples while the motor is driven are '
            'exactly 0 A between non-zero neighbours (a bimodal current: on-phase and '
            'off-phase samples), so it does not follow the armature current the model '
            'describes. Sample the current in the middle of the PWM on-phase (centre-aligned '
            'PWM, ADC triggered by the timer) or low-pass it over a PWM period before the ADC')


def speed_steps(record: Record) -> Optional[tuple[float, float, float]]:
    """
    Return ``(zero share, step, levels)`` of a coarsely quantised speed, else None.

    Coarse: at least :data:`QUANTISED_ZERO_FRACTION` of the differences of the moving shaft
    are zero and the speed spans fewer than :data:`QUANTISED_LEVELS` of its steps.
    """
    speed = record.speed
    if speed is None or len(speed) < MIN_CHECK_SAMPLES:
        return None
    speed = np.asarray(speed, dtype=float)
    moving = (speed[1:] != 0.0) | (speed[:-1] != 0.0)
    steps = np.diff(speed)[moving]
    if steps.size < MIN_CHECK_SAMPLES:
        return None
    fraction = float(np.mean(steps == 0.0))
    nonzero = np.abs(steps[steps != 0.0])
    if fraction < QUANTISED_ZERO_FRACTION or nonzero.size == 0:
        return None
    quantum = float(np.min(nonzero))
    levels = float(np.ptp(speed)) / quantum
    if levels >= QUANTISED_LEVELS:
        return None
    return fraction, quantum, levels


def quantised_speed(record: Record) -> Optional[str]:
    """
    Return the message when the speed is quantised too coarsely to draw anything from.

    Fewer than :data:`REFUSED_LEVELS` levels over its range: the steps say little more than
    the direction.  A speed with more levels is kept (:func:`coarse_speed` words the
    warning): its steady states carry the back-EMF constant and the friction, and the
    current carries the dynamics.
    """
    found = speed_steps(record)
    if found is None or found[2] >= REFUSED_LEVELS:
        return None
    fraction, quantum, levels = found
    return (f"{record.source or 'record'}: channel 'speed' is quantised so coarsely that "
            f'{100 * fraction:.0f} % of the differences between consecutive samples are zero '
            f'(steps of {quantum:.4g} rad/s, {levels:.0f} levels over its range, as encoder '
            'pulses counted per sample give): the motion between the steps is invisible. Give '
            'the encoder count as the position column instead (--position-counts-per-rev N, '
            'and no speed column: speed is then derived from the whole position record), use '
            'a finer encoder, or log at a lower rate')


def coarse_speed(record: Record) -> Optional[str]:
    """Return the warning for a coarse speed that is still used (None if it is not coarse)."""
    found = speed_steps(record)
    if found is None or found[2] < REFUSED_LEVELS:
        return None
    fraction, quantum, levels = found
    return (f"{record.source or 'record'}: channel 'speed' is coarse (steps of {quantum:.4g} "
            f'rad/s, {levels:.0f} levels over its range, {100 * fraction:.0f} % of the '
            'differences between samples zero): its steady states and the current carry the '
            'parameters, the speed between its steps does not; parameters the data do not '
            'determine are listed as not identifiable. A finer speed (or the encoder count '
            'as position, --position-counts-per-rev N) identifies them better')


#: Share of the voltage the back-EMF of a step response must visibly carry.
BACK_EMF_SHARE = 0.05
#: Residual RMS of the armature balance (of the voltage) below which a constant voltage is
#: a step response logged from its start, not a command that never reaches the motor.
BALANCE_RESIDUAL = 0.1


def back_emf_balance(voltage: float, current: np.ndarray, speed: Optional[np.ndarray],
                     sample_period_s: float) -> Optional[float]:
    """
    Return how well a constant voltage explains the current and speed, or None if it cannot.

    The armature balance ``u = Ra i + La di/dt + CPhi w`` is fitted to the constant voltage
    by least squares (no offset), on moving means of current and speed (a hundredth of the
    record, at most 50 samples: the balance is linear, so it holds for them too).  A step
    response logged from its start (the voltage applied as the log began, current and speed
    rising from rest) satisfies it with positive Ra and CPhi, and its back-EMF carries a
    visible share of the voltage (the current falls as the speed rises); a set-point that
    never reaches the motor does not (a current held by a current controller while the
    speed rises needs a back-EMF constant of zero).

    Returns
    -------
    float or None
        The fit's residual RMS relative to the voltage (0 is a perfect balance), or None when
        the fitted Ra or CPhi is not positive, the back-EMF stays below
        :data:`BACK_EMF_SHARE` of the voltage (physics rules the voltage out), or there is
        no speed to check against.

    """
    if speed is None or voltage == 0.0:
        return None
    sign = np.sign(voltage)
    # A moving mean keeps the (linear) balance and keeps the noise out of di/dt.
    width = int(np.clip(len(current) // 100, 1, 50))
    kernel = np.ones(width) / width
    current = sign * np.convolve(np.asarray(current, dtype=float), kernel, mode='valid')
    speed = sign * np.convolve(np.asarray(speed, dtype=float), kernel, mode='valid')
    rate = np.gradient(current, sample_period_s)
    regressors = np.column_stack([current, rate, speed])
    target = np.full(current.shape, abs(voltage))
    scale = np.maximum(np.sqrt(np.mean(regressors ** 2, axis=0)), 1e-300)
    coefficients = np.linalg.lstsq(regressors / scale, target, rcond=None)[0] / scale
    back_emf = coefficients[2] * float(np.ptp(speed))
    if not (coefficients[0] > 0 and back_emf > BACK_EMF_SHARE * abs(voltage)):
        return None
    residual = target - regressors @ coefficients
    return float(np.sqrt(np.mean(residual ** 2)) / abs(voltage))


def _speed_seen(record: Record, sample_period_s: float) -> Optional[np.ndarray]:
    """
    Return the record's speed, or its position's difference quotient when it has no speed.

    Speed derived from an encoder is filtered later (:mod:`~dcmotor_id.signals`); the
    balance's moving mean is filter enough for the check.
    """
    if record.speed is not None:
        return np.asarray(record.speed, dtype=float)
    if record.position is None or len(record.position) < 2:
        return None
    return np.gradient(unwrap_turns(record.position)[0], sample_period_s)


def command_voltage(record: Record) -> Optional[str]:
    """
    Return the message when the voltage is constant while current or speed change unexplained.

    A constant voltage whose current and speed follow the armature balance (a step response
    logged from the instant the voltage was applied) is usable and not refused.
    """
    voltage, current = record.voltage, record.current
    if voltage is None or current is None or len(voltage) < MIN_CHECK_SAMPLES:
        return None
    voltage = np.asarray(voltage, dtype=float)
    current = np.asarray(current, dtype=float)
    level = float(np.max(np.abs(voltage)))
    if float(np.ptp(voltage)) > 1e-9 * max(level, 1e-300) and level > 0:
        return None
    spread = float(np.ptp(current))
    changes = spread > CURRENT_CHANGE * float(np.max(np.abs(current))) and spread > 0
    speed = None if record.speed is None else np.asarray(record.speed, dtype=float)
    if speed is not None and not changes:
        # a current held constant while the speed rises: the voltage cannot be what drives it
        speed_spread = float(np.ptp(speed))
        changes = speed_spread > CURRENT_CHANGE * float(np.max(np.abs(speed))) and \
            speed_spread > 0
    if not changes:
        return None
    period = float(np.median(np.diff(record.time_s))) if len(record) > 1 else 1.0
    residual = back_emf_balance(float(voltage[0]), current, _speed_seen(record, period),
                                period)
    if residual is not None and residual < BALANCE_RESIDUAL:
        return None
    seen = ('no positive Ra with a visible back-EMF balances it' if residual is None else
            f'the best balance leaves {100 * residual:.0f} % of it unexplained')
    degrees = wrapping_degrees(record)
    if degrees is not None:
        return (f"{record.source or 'record'}: channel 'voltage' is constant "
                f'({voltage[0]:.6g} V) and the speed derived from the position does not follow '
                f'it as a motor does ({seen}): {degrees}, read here as radians. Pass '
                '--position-unit deg (if the position is in radians, the voltage looks like a '
                'command that never reaches the motor: record the armature voltage at the '
                'motor terminals)')
    return (f"{record.source or 'record'}: channel 'voltage' is constant ({voltage[0]:.6g} V) "
            f'while the current or speed changes (current {spread:.4g} A peak to peak), and '
            'the current and '
            f'speed do not follow it as a motor does (u = Ra i + La di/dt + CPhi w: {seen}): '
            'it looks like a command or set-point that never reaches the motor (e.g. the '
            'input of a current-controlled drive). Record the armature voltage at the motor '
            'terminals (or the PWM duty with --voltage-from-duty BUS_V), or identify the '
            'mechanical part only with --torque-constant K (the voltage column is then not '
            'used)')


def wrapping_degrees(record: Record) -> Optional[str]:
    """
    Say how the position looks like an angle in degrees that wraps at 360, or None.

    An absolute encoder read in degrees (0 to 360, or -180 to 180) and taken for radians
    spans more than a turn, so it is not unwrapped
    (:func:`~dcmotor_id.signals.filters.unwrap_turns`), and the speed derived from it spikes
    at every wrap.  Said when the record has a position and no speed, the position stays
    within [0, 360] or [-180, 180], and read in degrees its jumps are wraps (those
    :func:`~dcmotor_id.signals.filters.unwrap_turns` removes).
    """
    if record.speed is not None or record.position is None:
        return None
    return degrees_wrap(record.position)


def degrees_wrap(position: ArrayLike) -> Optional[str]:
    """Say how ``position`` looks like an angle in degrees that wraps at 360, or None."""
    position = np.asarray(position, dtype=float)
    if position.shape[0] < 2:
        return None
    if not np.all(np.isfinite(position)):
        return None
    low, high = float(np.min(position)), float(np.max(position))
    if not (0.0 <= low and high <= 360.0 or -180.0 <= low and high <= 180.0):
        return None
    wraps = unwrap_turns(np.deg2rad(position))[1]
    if wraps == 0:
        return None
    return (f'the position reads from {low:.4g} to {high:.4g} and jumps by about 360 {wraps} '
            'times: an angle in degrees that wraps at 360 (an absolute encoder)')


#: Share of the moving samples in each direction that makes a speed reverse (not a blip).
REVERSING_SHARE = 0.05


def magnitude_current(record: Record) -> Optional[str]:
    """
    Say when the current never reads below zero while the speed runs both ways, or None.

    A motor controller's output current is often a magnitude (a Spark MAX's
    ``OutputCurrent``, a wheel robot's current sensor): its sign is lost, and a fit of it
    reads a braking as a drive.  Only a load can turn a motor the other way with a current of
    one sign (gravity lowering an arm), so this is said in a note, not refused.
    """
    if record.current is None or record.speed is None or len(record) < MIN_CHECK_SAMPLES:
        return None
    current, speed = np.asarray(record.current), np.asarray(record.speed)
    if float(np.min(current)) < 0.0 or not float(np.max(current)) > 0.0:
        return None
    moving = np.abs(speed) > 0.1 * float(np.max(np.abs(speed)))
    share = max(int(np.count_nonzero(moving)), 1)
    if min(np.count_nonzero(speed[moving] > 0), np.count_nonzero(speed[moving] < 0)) \
            < REVERSING_SHARE * share:
        return None
    return (f'{record.source}: the current never reads below 0 while the speed runs both '
            f'ways ({float(np.min(speed)):.4g} to {float(np.max(speed)):.4g} rad/s): if it is '
            "a magnitude (a motor controller's output current), give it the sign of the torque "
            'before fitting: --current-sign-from voltage, or --current-sign-from speed where '
            'the drive never brakes (docs/formats.md, "The current as a magnitude"); fitted as '
            'it is, a braking reads as a drive')


#: The checks in the order they are applied.
CHECKS = (pwm_sampled_current, quantised_speed, command_voltage)


#: Checks that do not apply in the mechanical-only mode (the voltage is not used there).
VOLTAGE_CHECKS = (command_voltage,)


def channel_problems(record: Record, mechanical_only: bool = False) -> list[str]:
    """
    Return the message of every unusable channel of a record (empty when all are usable).

    A record with NaN/inf values is left to :func:`dcmotor_id.core.records.check_record`, which
    names those samples.  In the mechanical-only mode (``--torque-constant``) the voltage is
    not used, so it is not checked.
    """
    if not all(np.all(np.isfinite(values)) for values in record.columns().values()):
        return []
    checks = [check for check in CHECKS if not (mechanical_only and check in VOLTAGE_CHECKS)]
    return [message for message in (check(record) for check in checks) if message]


def check_channels(record: Record, mechanical_only: bool = False) -> Record:
    """
    Refuse a record with a channel that cannot identify the motor; return it otherwise.

    ``mechanical_only`` skips the checks of the voltage (:data:`VOLTAGE_CHECKS`).

    Raises
    ------
    InputDataError
        Naming the channel, what it looks like and what to record instead.

    """
    problems = channel_problems(record, mechanical_only)
    if problems:
        raise InputDataError('; '.join(problems))
    said = magnitude_current(record)
    if said:
        warnings.warn(said, ReadingNote, stacklevel=2)
    return record


register(Check('pwm_sampled_current', 'read', 'record', pwm_sampled_current,
               'a current sampled inside the PWM cycle (refused)'))
register(Check('quantised_speed', 'read', 'record', quantised_speed,
               'a speed quantised to a few levels (refused)'))
register(Check('command_voltage', 'read', 'record', command_voltage,
               'a voltage that is a command never reaching the motor (refused)'))
register(Check('magnitude_current', 'read', 'record', magnitude_current,
               'a current that never reads below 0 while the speed reverses (said in a note)'))
register(Check('coarse_speed', 'before_fit', 'record', coarse_speed,
               'a coarse speed kept, said in a warning'))
