"""The ``coulomb_asymmetry`` effect: direction-dependent Coulomb friction."""

from __future__ import annotations

from typing import Any

import numpy as np

from dcmotor_id.identification.effects.base import (Effect, Inner, Records, Terms, torque_spread,
                                                    Values)
from dcmotor_id.simulation.coefficients import MotorEffects


class CoulombAsymmetry(Effect):
    """Direction-dependent Coulomb friction, fitted exactly in the hybrid simulation."""

    name = 'coulomb_asymmetry'
    RANK = 20
    summary = ('Coulomb friction Mc + d for w > 0 and Mc - d for w < 0 (also the break-away '
               'levels); the same model as load_torque = d while |d| < Mc.')
    PARAMETERS = {'delta_Nm': ('N m', 0.0, 'd, half the difference Mc+ - Mc-')}
    MODES = ('full', 'mechanical', 'voltage_speed')
    VOLTAGE_SPEED_NAMES = {'delta_Nm': ('delta_V', 'V', 'Ra d / CPhi')}

    def motor_effects(self) -> MotorEffects:
        """Simulate with friction levels ``Mc +/- d``."""
        return MotorEffects(coulomb_delta_Nm=float(self.parameters['delta_Nm']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """One state term: the fit's simulator uses ``Mc +/- d`` (exact, fast path)."""
        scale = max(0.1 * base.get('Mc', 0.0), 0.01 * torque_spread(records, base,
                                                                    torque_constant))
        return (cls._term(cls.term_name('delta_Nm'), 'state',
                          [np.zeros(len(rec)) for rec in records], scale, initial,
                          field='coulomb_delta_Nm'),)

    def problem(self, base: Values, records: Records) -> str | None:
        """Refuse a Coulomb level below zero in one direction."""
        if abs(self.parameters['delta_Nm']) > base.get('Mc', 0.0):
            return 'the Coulomb friction would be negative in one direction'
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``delta_Nm``."""
        return cls(delta_Nm=float(values[cls.term_name('delta_Nm')]))

    def describe(self, base: Values | None = None) -> dict[str, Any]:
        """Add the two friction levels when the base ``Mc`` is known."""
        out = super().describe()
        if base is not None and 'Mc' in base:
            out['parameters']['Mc_pos_Nm'] = float(base['Mc'] + self.parameters['delta_Nm'])
            out['parameters']['Mc_neg_Nm'] = float(base['Mc'] - self.parameters['delta_Nm'])
        return out
