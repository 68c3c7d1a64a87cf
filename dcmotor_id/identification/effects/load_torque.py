"""The ``load_torque`` effect: a constant torque on the shaft."""

from __future__ import annotations

import numpy as np

from dcmotor_id.identification.effects.base import (Effect, Inner, Records, Terms, torque_spread,
                                                    Values)
from dcmotor_id.simulation.coefficients import MotorEffects


class LoadTorque(Effect):
    """A constant torque on the shaft (a load, a drive offset)."""

    name = 'load_torque'
    RANK = 10
    summary = ('constant load torque T_L on the shaft: J dw/dt = ... - T_L (the "offset" of '
               'the EMPS IDIM model).')
    PARAMETERS = {'torque_Nm': ('N m', 0.0, 'T_L, positive when it opposes positive rotation')}
    MODES = ('full', 'mechanical', 'voltage_speed')
    VOLTAGE_SPEED_NAMES = {'torque_Nm': ('torque_V', 'V', 'Ra T_L / CPhi')}

    def motor_effects(self) -> MotorEffects:
        """Simulate as a constant torque."""
        return MotorEffects(load_torque_Nm=float(self.parameters['torque_Nm']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """One term: torque channel, regressor -1."""
        scale = 0.05 * torque_spread(records, base, torque_constant)
        return (cls._term(cls.term_name('torque_Nm'), 'torque',
                          [-np.ones(len(rec)) for rec in records], scale, initial),)

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``torque_Nm``."""
        return cls(torque_Nm=float(values[cls.term_name('torque_Nm')]))
