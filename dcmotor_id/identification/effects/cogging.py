"""The ``cogging`` effect: torque ripple periodic in the shaft angle."""

from __future__ import annotations

from typing import Any

import numpy as np

from dcmotor_id.identification.effects.base import (Effect, Inner, Records, shaft_angle, Terms,
                                                    torque_spread, Values)
from dcmotor_id.simulation.coefficients import MotorEffects


class Cogging(Effect):
    """Torque ripple periodic in the shaft angle (slotting, magnets, a screw's pitch)."""

    name = 'cogging'
    RANK = 90
    summary = ('torque ripple A sin(N theta + phase), theta the shaft angle (the measured '
               'position, else the integrated measured speed).')
    PARAMETERS = {
        'amplitude_Nm': ('N m', 0.0, 'A, >= 0'),
        'cycles_per_rev': ('1/rev', 1.0, 'N, ripple periods per 2 pi of angle (inner, by grid '
                                         'search)'),
        'phase_rad': ('rad', 0.0, 'phase at theta = 0 (of the angle the data define)'),
    }

    def motor_effects(self) -> MotorEffects:
        """Simulate with the ripple on the true angle."""
        return MotorEffects(cogging_amplitude_Nm=float(self.parameters['amplitude_Nm']),
                            cogging_cycles_per_rev=float(self.parameters['cycles_per_rev']),
                            cogging_phase_rad=float(self.parameters['phase_rad']))

    @classmethod
    def inner_grid(cls, records: Records, base: Values,
                   torque_constant: float | None = None) -> list[dict[str, Any]]:
        """
        Screen integer ``N``: three ripples over the angles visited to fs / 4 at median speed.

        The upper end uses the median speed (the ripple shows where the shaft turns slowly);
        at most 48 values, log-spaced when the range is wider.
        """
        span = max(float(np.ptp(shaft_angle(rec))) for rec in records)
        speeds = np.abs(np.concatenate([rec.speed for rec in records]))
        typical = max(float(np.median(speeds)), 1e-12)
        rate = 1.0 / records[0].sample_period_s
        # At least three ripple periods within the range of angles visited: a longer period
        # is a position-dependent load, not a ripple.
        lowest = max(1, int(np.ceil(3.0 * 2.0 * np.pi / max(span, 1e-12))))
        highest = int(min(0.25 * rate * 2.0 * np.pi / typical, 4096))
        if highest < lowest:
            return []
        if highest - lowest < 48:
            grid = np.arange(lowest, highest + 1)
        else:
            grid = np.unique(np.round(np.geomspace(lowest, highest, 48)).astype(int))
        return [{'cycles_per_rev': float(n)} for n in grid]

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """Two terms: torque, regressors ``sin(N theta)`` and ``cos(N theta)``."""
        cycles = inner['cycles_per_rev']
        angles = [cycles * shaft_angle(rec) for rec in records]
        scale = 0.05 * torque_spread(records, base, torque_constant)
        return (cls._term(cls.term_name('sin_Nm'), 'torque', [np.sin(a) for a in angles],
                          scale, initial),
                cls._term(cls.term_name('cos_Nm'), 'torque', [np.cos(a) for a in angles],
                          scale, initial))

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Amplitude and phase from the sine and cosine coefficients."""
        a = float(values[cls.term_name('sin_Nm')])
        b = float(values[cls.term_name('cos_Nm')])
        return cls(amplitude_Nm=float(np.hypot(a, b)), cycles_per_rev=inner['cycles_per_rev'],
                   phase_rad=float(np.arctan2(b, a)))
