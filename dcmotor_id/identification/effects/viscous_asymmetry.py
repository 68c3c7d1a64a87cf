"""The ``viscous_asymmetry`` effect: direction-dependent viscous friction."""

from __future__ import annotations

from typing import Any

import numpy as np

from dcmotor_id.identification.effects.base import (Effect, Inner, Records, Terms, torque_spread,
                                                    Values)
from dcmotor_id.signals.filters import smooth
from dcmotor_id.simulation.coefficients import MotorEffects


class ViscousAsymmetry(Effect):
    """
    Direction-dependent viscous friction (an addition to the issue's vocabulary).

    In the standard vocabulary: no false effect on the clean simulations of
    ``bench/bench_discovery.py`` and no more real records with a false effect in
    ``bench/bench_discovery_real.py`` than without it (``bench/discovery_results.md``).
    """

    name = 'viscous_asymmetry'
    RANK = 100
    summary = ('viscous friction (b + d) w for w > 0 and (b - d) w for w < 0: an extra '
               'torque -d |w|.')
    PARAMETERS = {'delta_Nm_s': ('N m s/rad', 0.0, 'd, half the difference b+ - b-')}
    MODES = ('full', 'mechanical', 'voltage_speed')
    VOLTAGE_SPEED_NAMES = {'delta_Nm_s': ('delta_V_s_per_rad', 'V s/rad', 'Ra d / CPhi')}

    def motor_effects(self) -> MotorEffects:
        """Simulate as a torque ``-d |w|``."""
        return MotorEffects(viscous_delta_Nm_s=float(self.parameters['delta_Nm_s']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """One term: torque channel, regressor ``-|w|`` of the smoothed measured speed."""
        peak = max(max(float(np.max(np.abs(rec.speed))) for rec in records), 1e-12)
        scale = 0.05 * torque_spread(records, base, torque_constant) / peak
        return (cls._term(cls.term_name('delta_Nm_s'), 'torque',
                          [-np.abs(smooth(rec.speed, rec.sample_period_s)) for rec in records],
                          scale, initial),)

    def problem(self, base: Values, records: Records) -> str | None:
        """Refuse a viscous coefficient below zero in one direction."""
        if abs(self.parameters['delta_Nm_s']) > base.get('b', 0.0):
            return 'the viscous friction would be negative in one direction'
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``delta_Nm_s``."""
        return cls(delta_Nm_s=float(values[cls.term_name('delta_Nm_s')]))

    def describe(self, base: Values | None = None) -> dict[str, Any]:
        """Add the two viscous coefficients when the base ``b`` is known."""
        out = super().describe()
        if base is not None and 'b' in base:
            out['parameters']['b_pos_Nm_s'] = float(base['b'] + self.parameters['delta_Nm_s'])
            out['parameters']['b_neg_Nm_s'] = float(base['b'] - self.parameters['delta_Nm_s'])
        return out
