"""The ``resistance_drift`` effect: armature resistance changing over the record."""

from __future__ import annotations

from dcmotor_id.identification.effects.base import Effect, Inner, Records, Terms, Values
from dcmotor_id.signals.filters import smooth
from dcmotor_id.simulation.coefficients import MotorEffects


class ResistanceDrift(Effect):
    """Armature resistance changing over the record (winding heating)."""

    name = 'resistance_drift'
    RANK = 80
    summary = ('armature resistance Ra(t) = Ra + rate (t - t_0), t_0 the record start (the '
               'base Ra is then the value at the start).')
    PARAMETERS = {'rate_ohm_per_s': ('Ohm/s', 0.0, 'rate, > 0 while the winding heats up')}
    MODES = ('full',)

    def motor_effects(self) -> MotorEffects:
        """Simulate with a time-varying ``Ra``."""
        return MotorEffects(resistance_rate_ohm_per_s=float(self.parameters['rate_ohm_per_s']))

    @classmethod
    def terms(cls, records: Records, inner: Inner, base: Values,
              torque_constant: float | None = None, initial: Values | None = None) -> Terms:
        """One term: voltage, regressor ``-(t - t_0) i`` with the smoothed measured current."""
        regressors = [-(rec.time_s - rec.time_s[0]) * smooth(rec.current, rec.sample_period_s)
                      for rec in records]
        duration = max(float(rec.time_s[-1] - rec.time_s[0]) for rec in records)
        scale = 0.05 * base.get('Ra', 1.0) / max(duration, 1e-9)
        return (cls._term(cls.term_name('rate_ohm_per_s'), 'voltage', regressors, scale,
                          initial),)

    def problem(self, base: Values, records: Records) -> str | None:
        """Require the resistance to stay positive over the records."""
        duration = max(float(rec.time_s[-1] - rec.time_s[0]) for rec in records)
        if base.get('Ra', 1.0) + min(self.parameters['rate_ohm_per_s'] * duration, 0.0) <= 0:
            return 'the armature resistance would become negative within the record'
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Read ``rate_ohm_per_s``."""
        return cls(rate_ohm_per_s=float(values[cls.term_name('rate_ohm_per_s')]))
