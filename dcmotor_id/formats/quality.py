"""
Channels a recording cannot identify from: recognised on reading, refused naming the channel.

Three ways a channel carries no usable information although it holds numbers:

* a **current sampled inside the PWM cycle**: the ADC catches the on- or the off-phase of the
  switching, so many samples are exactly zero between non-zero neighbours (a bimodal signal);
* a **speed quantised so coarsely** (encoder pulses counted per sample) that most differences
  between consecutive samples are zero: the dynamics between the steps are invisible;
* a **voltage that is a command never reaching the motor**: constant while the current
  changes (a set-point, or the input of a current-controlled drive).

:func:`check_channels` raises :class:`~dcmotor_id.core.errors.InputDataError` with a message that
names the channel, what was seen and what to do.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import Record

#: Fraction of the driven samples exactly zero between non-zero neighbours: PWM-sampled.
PWM_ZERO_FRACTION = 0.1
#: Fraction of consecutive differences of a moving shaft exactly zero: too coarse a speed.
QUANTISED_ZERO_FRACTION = 0.4
#: Fewest distinct levels over the speed's range that a usable speed has.
QUANTISED_LEVELS = 64
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


def quantised_speed(record: Record) -> Optional[str]:
    """Return the message when the speed is quantised too coarsely to identify from."""
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
    return (f"{record.source or 'record'}: channel 'speed' is quantised so coarsely that "
            f'{100 * fraction:.0f} % of the differences between consecutive samples are zero '
            f'(steps of {quantum:.4g} rad/s, {levels:.0f} levels over its range, as encoder '
            'pulses counted per sample give): the motion between the steps is invisible. Give '
            'the encoder count as the position column instead (--position-counts-per-rev N, '
            'and no speed column: speed is then derived from the whole position record), use '
            'a finer encoder, or log at a lower rate')


def command_voltage(record: Record) -> Optional[str]:
    """Return the message when the voltage is constant while the current changes."""
    voltage, current = record.voltage, record.current
    if voltage is None or current is None or len(voltage) < MIN_CHECK_SAMPLES:
        return None
    voltage = np.asarray(voltage, dtype=float)
    current = np.asarray(current, dtype=float)
    level = float(np.max(np.abs(voltage)))
    if float(np.ptp(voltage)) > 1e-9 * max(level, 1e-300) and level > 0:
        return None
    spread = float(np.ptp(current))
    if not spread > CURRENT_CHANGE * float(np.max(np.abs(current))) or spread == 0:
        return None
    return (f"{record.source or 'record'}: channel 'voltage' is constant ({voltage[0]:.6g} V) "
            f'while the current changes ({spread:.4g} A peak to peak): it looks like a '
            'command or set-point that never reaches the motor (e.g. the input of a '
            'current-controlled drive). Record the armature voltage at the motor terminals '
            '(or the PWM duty with --voltage-from-duty BUS_V), or identify the mechanical '
            'part only with --torque-constant K')


#: The checks in the order they are applied.
CHECKS = (pwm_sampled_current, quantised_speed, command_voltage)


def channel_problems(record: Record) -> list[str]:
    """
    Return the message of every unusable channel of a record (empty when all are usable).

    A record with NaN/inf values is left to :func:`dcmotor_id.core.records.check_record`, which
    names those samples.
    """
    if not all(np.all(np.isfinite(values)) for values in record.columns().values()):
        return []
    return [message for message in (check(record) for check in CHECKS) if message]


def check_channels(record: Record) -> Record:
    """
    Refuse a record with a channel that cannot identify the motor; return it otherwise.

    Raises
    ------
    InputDataError
        Naming the channel, what it looks like and what to record instead.

    """
    problems = channel_problems(record)
    if problems:
        raise InputDataError('; '.join(problems))
    return record
