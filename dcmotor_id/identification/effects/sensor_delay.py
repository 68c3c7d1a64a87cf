"""The ``sensor_delay`` effect: a sensor a whole number of samples late or early."""

from __future__ import annotations

from typing import Any

from dcmotor_id.identification.effects.base import Effect, Inner, Records, Values
from dcmotor_id.simulation.coefficients import MotorEffects


class SensorDelay(Effect):
    """
    A sensor that reports a whole number of samples late against the others.

    The data transform also undoes an early sensor (``samples < 0``), but such a delay is not
    physical (:meth:`problem`): discovery does not accept it and ``validate`` refuses it.
    """

    name = 'sensor_delay'
    RANK = 70
    summary = ('whole-sample delay of one measured channel against the input: measured '
               'y[k] = y_true[k - samples]; handled by shifting the data.')
    PARAMETERS = {
        'channel': ('', 'speed', 'the delayed channel, current or speed'),
        'samples': ('samples', 0, 'delay, > 0 when that sensor is late (integer)'),
    }
    TRANSFORM = True
    MODES = ('full', 'mechanical', 'voltage_speed')

    def __init__(self, **parameters: Any) -> None:
        super().__init__(**parameters)
        if self.parameters['channel'] not in ('current', 'speed'):
            raise ValueError('sensor_delay: channel must be current or speed, got '
                             f"{self.parameters['channel']!r}")
        self.parameters['samples'] = int(self.parameters['samples'])

    def motor_effects(self) -> MotorEffects:
        """Simulate a late sensor (``samples >= 0``)."""
        samples = self.parameters['samples']
        if samples < 0:
            raise ValueError('sensor_delay: simulate a late sensor (samples >= 0); an early '
                             'one is the other channels being late')
        if self.parameters['channel'] == 'current':
            return MotorEffects(current_delay_samples=samples)
        return MotorEffects(speed_delay_samples=samples)

    @classmethod
    def channels(cls, mechanical_only: bool) -> tuple[str, ...]:
        """Channels a delay can be estimated on in this mode."""
        return ('speed',) if mechanical_only else ('current', 'speed')

    @classmethod
    def transform(cls, records: Records, inner: Inner) -> list[Any]:
        """Undo the delay: shift the channel back and trim every record to the overlap."""
        samples = int(inner.get('samples', 0))
        channel = inner.get('channel', 'speed')
        if samples == 0:
            return list(records)
        out = []
        for rec in records:
            n = len(rec)
            if samples > 0:
                shifted = getattr(rec, channel)[samples:]
                trimmed = rec.slice(0, n - samples)
            else:
                shifted = getattr(rec, channel)[:n + samples]
                trimmed = rec.slice(-samples, n)
            out.append(trimmed.replace(**{channel: shifted}))
        return out

    def problem(self, base: Values, records: Records) -> str | None:
        """
        Refuse an early sensor (``samples < 0``): it would report the signal before it happens.

        On real records the linearised estimate can point to an early sensor (HSM150: -16 and
        -1500 samples) where the model lacks something else; a sensor is never ahead of the
        input it responds to, so such a delay is not physical.
        """
        samples = self.parameters['samples']
        if samples < 0:
            return (f'a negative delay ({samples} samples) would put the '
                    f"{self.parameters['channel']} sensor ahead of the input: not causal")
        return None

    @classmethod
    def from_fit(cls, values: Values, inner: Inner) -> Effect:
        """Build the delay from the inner parameter itself."""
        return cls(channel=inner['channel'], samples=int(inner['samples']))
