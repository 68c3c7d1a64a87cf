"""The ``brush_drop`` effect: the voltage lost across the brushes."""

from __future__ import annotations

import numpy as np

from dcmotor_id.identification.effects.base import Effect, Inner, Records, Terms, Values
from dcmotor_id.signals.filters import dead_sign
from dcmotor_id.simulation.coefficients import MotorEffects


class BrushDrop(Effect):
    """The voltage lost across the brushes, nearly constant in magnitude."""

    name = 'brush_drop'
    RANK = 50
    summary = 'brush voltage drop: La di/dt = u - Ra i - CPhi w - V_b sgn(i).'
    PARAMETERS = {'drop_V': ('V', 0.0, 'V_b, > 0 for a drop (typically 0.5 to 2 V)')}
    MODES = ('full',)

    def motor_effects(self) -> MotorEffects:
        """Simulate as a voltage ``-V_b sgn(i)``."""
        return MotorEffects(brush_drop_V=float(self.parameters['drop_V']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """
        One state term, simulated exactly (drop against the current, blocking).

        A regressor ``-sgn(i)`` of the measured current cannot express the blocking (no
        current while ``|u - CPhi w| <= V_b``) and biases La by some 15 % for a 2 V drop on the
        paper's motor 2; the regressor is kept for the residual correlations.
        """
        spread = float(np.std(np.concatenate([rec.voltage for rec in records])))
        return (cls._term(cls.term_name('drop_V'), 'state',
                          [-dead_sign(rec.current, rec.sample_period_s, rec.noise_std('current'))
                           for rec in records],
                          max(0.01 * spread, 1e-9), initial, field='brush_drop_V'),)

    def problem(self, base: Values, records: Records) -> str | None:
        """Refuse a negative drop (it would be a source)."""
        if self.parameters['drop_V'] < 0.0:
            return 'negative brush drop: the brushes would be a voltage source'
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``drop_V``."""
        return cls(drop_V=float(values[cls.term_name('drop_V')]))
