"""The ``stribeck`` effect: friction higher at low speed (static above Coulomb)."""

from __future__ import annotations

from typing import Any

import numpy as np

from dcmotor_id.identification.effects.base import (Effect, Inner, Records, Terms, torque_spread,
                                                    Values)
from dcmotor_id.signals.filters import dead_sign, smooth
from dcmotor_id.simulation.coefficients import MotorEffects


class Stribeck(Effect):
    """Friction that is higher at low speed (static friction above Coulomb friction)."""

    name = 'stribeck'
    RANK = 30
    summary = ('friction magnitude Mc + excess exp(-(w/w_s)^2): static friction Mc + excess at '
               'rest, falling to Mc above a few w_s.')
    PARAMETERS = {
        'excess_Nm': ('N m', 0.0, 'static minus Coulomb friction, > 0 for a Stribeck dip'),
        'velocity_rad_s': ('rad/s', 1.0, 'Stribeck velocity w_s (inner, by grid search)'),
    }

    def motor_effects(self) -> MotorEffects:
        """Simulate as a speed-dependent friction level (break-away at ``Mc + excess``)."""
        return MotorEffects(stribeck_excess_Nm=float(self.parameters['excess_Nm']),
                            stribeck_velocity_rad_s=float(self.parameters['velocity_rad_s']))

    @classmethod
    def inner_grid(cls, records: Records, base: Values,
                   torque_constant: float | None = None) -> list[dict[str, Any]]:
        """Eight Stribeck velocities, log-spaced from 0.5 % to 30 % of the peak speed."""
        peak = max(float(np.max(np.abs(smooth(rec.speed, rec.sample_period_s))))
                   for rec in records)
        return [{'velocity_rad_s': float(v)} for v in np.geomspace(0.005, 0.3, 8) * peak]

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """
        One state term: the friction level follows the *simulated* speed.

        The regressor ``-exp(-(w/w_s)^2) sgn(w)`` of the measured speed (kept for the
        residual correlations) cannot raise the break-away level and, fitted as a torque,
        gave an excess three times too large on motor 2 at low speed; the fit therefore
        simulates the Stribeck friction itself.
        """
        velocity = inner['velocity_rad_s']
        regressors = []
        for rec in records:
            speed = smooth(rec.speed, rec.sample_period_s)
            regressors.append(-np.exp(-(speed / velocity) ** 2)
                              * dead_sign(rec.speed, rec.sample_period_s, rec.noise_std('speed')))
        scale = max(0.1 * base.get('Mc', 0.0), 0.01 * torque_spread(records, base,
                                                                    torque_constant))
        name = cls.term_name('velocity_rad_s')
        fitted_velocity = (initial or {}).get(name)
        return (cls._term(cls.term_name('excess_Nm'), 'state', regressors, scale, initial,
                          field='stribeck_excess_Nm'),
                cls._term(name, 'state', [np.zeros(len(rec)) for rec in records],
                          0.3 * velocity, {name: fitted_velocity or velocity},
                          field='stribeck_velocity_rad_s'))

    def problem(self, base: Values, records: Records) -> str | None:
        """Require static friction above the Coulomb level and a positive velocity."""
        if self.parameters['excess_Nm'] <= 0.0:
            return 'no Stribeck dip: the static friction came out below the Coulomb friction'
        if self.parameters['velocity_rad_s'] <= 0.0:
            return 'the Stribeck velocity must be positive'
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``excess_Nm`` and the velocity (started at the grid value, then fitted)."""
        velocity = values.get(cls.term_name('velocity_rad_s'), inner['velocity_rad_s'])
        return cls(excess_Nm=float(values[cls.term_name('excess_Nm')]),
                   velocity_rad_s=abs(float(velocity)))
