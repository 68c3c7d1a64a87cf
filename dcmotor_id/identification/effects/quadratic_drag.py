"""The ``quadratic_drag`` effect: a drag torque in the square of the speed."""

from __future__ import annotations

import numpy as np

from dcmotor_id.identification.effects.base import (Effect, Inner, Records, Terms, torque_spread,
                                                    Values)
from dcmotor_id.signals.filters import smooth
from dcmotor_id.simulation.coefficients import MotorEffects


class QuadraticDrag(Effect):
    """Aerodynamic or fluid drag, a torque in the square of the speed."""

    name = 'quadratic_drag'
    RANK = 40
    summary = 'drag torque -c w |w| (fan, fluid load).'
    PARAMETERS = {'coefficient_Nm_s2': ('N m s^2/rad^2', 0.0, 'c, > 0 for a drag')}

    def motor_effects(self) -> MotorEffects:
        """Simulate as a torque ``-c w |w|``."""
        return MotorEffects(drag_Nm_s2=float(self.parameters['coefficient_Nm_s2']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """One term: torque, regressor ``-w |w|`` of the smoothed measured speed."""
        regressors = []
        peak = 1e-12
        for rec in records:
            speed = smooth(rec.speed, rec.sample_period_s)
            regressors.append(-speed * np.abs(speed))
            peak = max(peak, float(np.max(speed ** 2)))
        scale = 0.05 * torque_spread(records, base, torque_constant) / peak
        return (cls._term(cls.term_name('coefficient_Nm_s2'), 'torque', regressors, scale,
                          initial),)

    def problem(self, base: Values, records: Records) -> str | None:
        """Refuse a negative drag (it would drive the shaft)."""
        if self.parameters['coefficient_Nm_s2'] < 0.0:
            return 'negative drag: the torque would drive the shaft'
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``coefficient_Nm_s2``."""
        return cls(coefficient_Nm_s2=float(values[cls.term_name('coefficient_Nm_s2')]))
