"""
Units and signs checked against physics: a column off by 1000 or reversed is named.

Every channel scaled by 1000 still fits a DC motor (the model is scale invariant), so the
fit alone cannot tell millivolts from volts.  What gives them away is the answer measured
against what DC motors are: an electrical time constant ``La/Ra`` of seconds (DC motors have
0.01 ms to 100 ms) with a sample period of a second says the time is in milliseconds;
thousands of volts across an armature of kilo-ohms say millivolts; thousands of amperes
through milli-ohms say milliamperes.  Each finding is a warning naming the channel, the
numbers behind it and what to do.  A channel whose sign is reversed (an encoder counting the
other way) gives no fit at all: :func:`sign_problem` names it from the signs of the
model-free regression's Ra, CPhi and J, for the refusal.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.checks.start import regression_evidence

if TYPE_CHECKING:
    from dcmotor_id.identification.checks.answer import FinalFit

#: Longest electrical time constant La/Ra of a DC motor armature [s] (large motors: 0.1 s).
MAX_ELECTRICAL_S = 1.0
#: Longest sample period of a drive recording [s].
MAX_SAMPLE_PERIOD_S = 0.5

__all__ = ['sign_problem', 'unit_warnings']


def _peak(records: Sequence[Any], channel: str) -> float:
    values = [np.abs(np.asarray(getattr(rec, channel))) for rec in records
              if getattr(rec, channel, None) is not None]
    return float(max((np.max(v) for v in values if v.size), default=0.0))


def unit_warnings(parameters: Mapping[str, float], records: Sequence[Any],
                  mechanical_only: bool = False) -> list[str]:
    """
    Return a warning for every channel whose units look off by 1000, by the answer's physics.

    Parameters
    ----------
    parameters : dict
        The identified parameters (SI).
    records : list of Record
        The records fitted.
    mechanical_only : bool
        The current is the input: the electrical checks do not apply.

    """
    found = []
    dt = float(np.median([rec.sample_period_s for rec in records]))
    ra, la = parameters.get('Ra', np.nan), parameters.get('La', np.nan)
    tau_e = la / ra if not mechanical_only and ra > 0 else np.nan
    if dt > MAX_SAMPLE_PERIOD_S or (np.isfinite(tau_e) and tau_e > MAX_ELECTRICAL_S):
        shown = f', La/Ra = {tau_e:.3g} s' if np.isfinite(tau_e) else ''
        found.append(
            f'the time looks like milliseconds (or another unit than seconds): the sample '
            f'period is {dt:.3g} s{shown}, where DC motors have electrical time constants of '
            '0.01 ms to 100 ms and drives sample at 0.01 ms to 100 ms; give the time column in '
            'seconds (--time-unit ms reads one in milliseconds), else La and J are off by '
            'that factor')
    if mechanical_only:
        return found
    voltage, current = _peak(records, 'voltage'), _peak(records, 'current')
    if voltage > 1000.0 and ra > 100.0:
        found.append(
            f'the voltage looks like millivolts: it reaches {voltage:.4g} "V" across an '
            f'armature of Ra = {ra:.4g} Ohm; give it in volts (divide by 1000), else Ra, La, '
            'CPhi, J, b and Mc are 1000 times too large')
    if current > 1000.0 and ra < 0.01:
        found.append(
            f'the current looks like milliamperes: it reaches {current:.4g} "A" through an '
            f'armature of Ra = {ra:.4g} Ohm; give --current-unit mA, else Ra and La are 1000 '
            'times too small and J, b and Mc 1000 times too large')
    return found


def sign_problem(records: Sequence[Any], torque_constant: float | None = None) -> str | None:
    """
    Name the channel whose sign looks reversed, by the model-free regression; None if none.

    ``u = Ra i + La di/dt + CPhi w`` needs Ra and CPhi positive: CPhi negative with Ra
    positive is a reversed speed, Ra negative with CPhi positive a reversed current, both
    negative a reversed voltage.  In the mechanical-only mode ``K i = J dw/dt + ...`` needs J
    positive: negative is a speed (or current) reversed against the other.  The channel is
    named only when the regression with it negated gives them all positive (a current that is
    zero, or columns of noise, give signs that no flip mends).
    """
    evidence = regression_evidence(records, torque_constant)
    if evidence is None:
        return None
    if torque_constant is not None:
        reversed_channel = 'speed' if evidence['J'] < 0 else None
        seen = f'J = {evidence["J"]:.3g} kg m^2'
    else:
        ra, cphi = evidence['Ra'], evidence['CPhi']
        reversed_channel = {(True, False): 'speed', (False, True): 'current',
                            (False, False): 'voltage'}.get((ra > 0, cphi > 0))
        seen = f'Ra = {ra:.3g} Ohm, CPhi = {cphi:.3g} V s'
    if reversed_channel is None:
        return None
    if not _consistent_when_negated(records, torque_constant, reversed_channel):
        return None
    if reversed_channel == 'current' and _magnitude(records):
        return (f'the current looks reversed against the other channels ({seen}), and it never '
                'reads below 0 while the speed runs both ways: it is logged as a magnitude (a '
                "motor controller's output current), which negating does not mend; give it the "
                'sign of the voltage with --current-sign-from voltage (or of the speed, '
                '--current-sign-from speed, where the drive never brakes), or leave the current '
                'out (voltage and speed alone give kS, kV, kA)')
    speed_note = (' (or --negate position, when the speed is derived from it)'
                  if reversed_channel == 'speed' else '')
    return (f'the {reversed_channel} looks reversed against the other channels: a regression '
            f'on the data gives {seen}, where a motor has them positive; flip its sign with '
            f'--negate {reversed_channel}{speed_note}')


def _magnitude(records: Sequence[Any]) -> bool:
    """Whether the current never reads below zero while the speed runs both ways."""
    current = np.concatenate([np.asarray(rec.current, dtype=float) for rec in records])
    speed = np.concatenate([np.asarray(rec.speed, dtype=float) for rec in records])
    return bool(current.min() >= 0.0 and speed.min() < 0.0 < speed.max())


def _consistent_when_negated(records: Sequence[Any], torque_constant: float | None,
                             channel: str) -> bool:
    """Whether the regression on the records with ``channel`` negated has Ra, CPhi, J > 0."""
    flipped = [rec.replace(**{channel: -np.asarray(getattr(rec, channel), dtype=float)})
               for rec in records]
    evidence = regression_evidence(flipped, torque_constant)
    if evidence is None:
        return False
    names = ('J',) if torque_constant is not None else ('Ra', 'CPhi', 'J')
    return all(evidence[name] > 0 for name in names)


def units_check(fit: FinalFit) -> list[str]:
    """Check the answer (:mod:`~.answer`): :func:`unit_warnings` on the records identified."""
    return unit_warnings(fit.estimate.parameters, fit.records, fit.mechanical_only)
