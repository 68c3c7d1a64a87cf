"""The ``current_offset`` effect: a constant error of the current sensor."""

from __future__ import annotations

import numpy as np

from dcmotor_id.identification.effects.base import Effect, Inner, Records, Terms, Values
from dcmotor_id.simulation.coefficients import MotorEffects


class CurrentOffset(Effect):
    """A constant error of the current sensor."""

    name = 'current_offset'
    RANK = 60
    summary = 'current sensor offset: measured current = true current + offset.'
    PARAMETERS = {'offset_A': ('A', 0.0, 'added to the true current by the sensor')}
    MODES = ('full',)

    def motor_effects(self) -> MotorEffects:
        """Simulate as an offset of the measured current."""
        return MotorEffects(current_offset_A=float(self.parameters['offset_A']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """One term: current output, regressor 1."""
        spread = float(np.std(np.concatenate([rec.current for rec in records])))
        return (cls._term(cls.term_name('offset_A'), 'current',
                          [np.ones(len(rec)) for rec in records], max(0.01 * spread, 1e-12),
                          initial),)

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``offset_A``."""
        return cls(offset_A=float(values[cls.term_name('offset_A')]))
