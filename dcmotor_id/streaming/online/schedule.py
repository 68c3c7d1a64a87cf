"""
Motor parameters that change over time on a schedule: parsing and exact simulation (no ROS).

``sim_motor``'s ``schedule`` parameter, the online benchmark and the tests use it to make a
motor heat up, wear or take a load, so that online tracking and change alarms can be shown
with the real node graph.  The text is a ``;``-separated list of changes::

    NAME:CHANGE:step:AT            e.g.  b:+50%:step:30
    NAME:CHANGE:ramp:FROM:TO       e.g.  Ra:+25%:ramp:10:70

``NAME`` is ``Ra``, ``La``, ``CPhi``, ``J``, ``b``, ``Mc`` or ``load_torque`` (a constant
torque on the shaft [N m], positive when it opposes positive rotation, as the
``load_torque`` effect); ``CHANGE`` is relative to the value at the start (``+25%``) or
absolute in SI units (``+0.3``; ``load_torque`` takes only absolute changes); times are
seconds since the simulation started.  A step happens at ``AT``; a ramp goes linearly from
``FROM`` to ``TO``.  Changes of the same parameter add up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.core.model import MotorParameters, PARAMETER_NAMES
from dcmotor_id.simulation import motor_forcing, motor_system

__all__ = ['Change', 'LOAD', 'parse_schedule', 'ParameterSchedule', 'simulate_scheduled']

#: Name of the load torque in a schedule.
LOAD = 'load_torque'
_NAMES = PARAMETER_NAMES + (LOAD,)
_KINDS = ('step', 'ramp')


@dataclass(frozen=True)
class Change:
    """One change: ``amount`` (relative if ``relative``) from ``start_s`` to ``end_s``."""

    name: str
    amount: float
    relative: bool
    kind: str
    start_s: float
    end_s: float

    def fraction(self, time_s: float) -> float:
        """How much of the change has happened at ``time_s`` (0 to 1)."""
        if self.kind == 'step' or self.end_s <= self.start_s:
            return 1.0 if time_s >= self.start_s else 0.0
        return float(np.clip((time_s - self.start_s) / (self.end_s - self.start_s), 0.0, 1.0))


def _parse_change(entry: str) -> Change:
    fields = [part.strip() for part in entry.split(':')]
    if len(fields) < 4:
        raise ValueError('expected NAME:CHANGE:step:AT or NAME:CHANGE:ramp:FROM:TO')
    name, amount_text, kind = fields[:3]
    if name not in _NAMES:
        raise ValueError(f'unknown parameter {name!r}; one of {", ".join(_NAMES)}')
    if kind not in _KINDS:
        raise ValueError(f'unknown kind {kind!r}; step or ramp')
    relative = amount_text.endswith('%')
    amount = float(amount_text.rstrip('%'))
    if relative:
        amount /= 100.0
        if name == LOAD:
            raise ValueError('load_torque starts at 0: give an absolute change [N m]')
    if not np.isfinite(amount):
        raise ValueError(f'change {amount_text!r} is not finite')
    times = [float(value) for value in fields[3:]]
    if kind == 'step' and len(times) != 1 or kind == 'ramp' and len(times) != 2:
        raise ValueError('step takes one time (AT), ramp two (FROM:TO)')
    if not all(np.isfinite(times)) or kind == 'ramp' and times[1] < times[0]:
        raise ValueError('times must be finite, a ramp must end after it starts')
    return Change(name, amount, relative, kind, times[0], times[-1])


def parse_schedule(text: str) -> ParameterSchedule:
    """Parse a schedule text (see the module docstring); raise ``ValueError`` naming the entry."""
    changes = []
    for entry in filter(None, (part.strip() for part in text.split(';'))):
        try:
            changes.append(_parse_change(entry))
        except ValueError as error:
            raise ValueError(f'schedule entry {entry!r}: {error}') from None
    return ParameterSchedule(tuple(changes))


@dataclass(frozen=True)
class ParameterSchedule:
    """A list of :class:`Change` applied to a motor."""

    changes: tuple[Change, ...] = ()

    def __bool__(self) -> bool:
        """Return whether anything changes."""
        return bool(self.changes)

    def at(self, base: MotorParameters, time_s: float) -> tuple[MotorParameters, float]:
        """Return the motor and the load torque [N m] at ``time_s``."""
        values = base.as_dict(derived=False)
        values[LOAD] = 0.0
        start = dict(values)
        for change in self.changes:
            step = change.amount * change.fraction(time_s)
            values[change.name] += step * start[change.name] if change.relative else step
        load = values.pop(LOAD)
        return MotorParameters.from_dict(values), load


def simulate_scheduled(params: MotorParameters, schedule: ParameterSchedule,
                       voltage: ArrayLike, sample_period_s: float, update_s: float = 0.01,
                       initial_state: Sequence[float] = (0.0, 0.0),
                       start_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """
    Simulate the motor exactly while its parameters follow ``schedule``.

    The parameters are held over blocks of ``update_s`` (as ``sim_motor`` holds them over a
    timer tick) and the state carries over; within a block the solution is the exact one of
    :func:`~dcmotor_id.simulation.simulate_motor`.  Returns ``current, speed`` at the samples.
    """
    voltage = np.asarray(voltage, dtype=float)
    block = max(1, int(round(update_s / sample_period_s)))
    state = np.asarray(initial_state, dtype=float)
    out = np.empty((voltage.size, 2))
    for first in range(0, voltage.size, block):
        part = slice(first, min(first + block, voltage.size))
        motor, load = schedule.at(params, start_s + first * sample_period_s)
        # the load opposes positive rotation (as the load_torque effect): minus on the shaft
        forcing = motor_forcing(motor, voltage[part], extra_torque=np.full(
            part.stop - part.start, -load))
        states = motor_system(motor).simulate(forcing, state, sample_period_s)
        out[part] = states[:-1]
        state = states[-1]
    return out[:, 0].copy(), out[:, 1].copy()
