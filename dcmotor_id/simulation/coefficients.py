"""
The simulator's coefficients of the effects: one typed value, and how contributions combine.

:class:`MotorEffects` is a named tuple: the numba kernel receives it as it is and reads the
state-dependent coefficients by name (:func:`dcmotor_id.simulation.kernels.effects_kernel`);
the sensor fields (offset, delays) are applied to the simulated outputs.  Each field declares,
beside its definition, how the contributions of several effects combine: ``ADD`` (they add up)
or ``REPLACE`` (a shape parameter: a contribution that sets it, i.e. differs from the default,
replaces the value).  An effect of :mod:`dcmotor_id.identification.effects` contributes a
MotorEffects with
its own fields set; :func:`combine_effects` merges the contributions.
"""

from __future__ import annotations

from typing import Annotated, Any, get_args, get_type_hints, Iterable, NamedTuple, Union

#: Contributions to the field add up.
ADD = 'add'
#: A contribution that sets the field (differs from its default) replaces the value.
REPLACE = 'replace'


class MotorEffects(NamedTuple):
    """
    The coefficients of the true effects to simulate (SI units).

    Signs: torques are positive when they drive the shaft in the positive direction unless said
    otherwise.

    Attributes
    ----------
    load_torque_Nm : float
        Constant load torque ``T_L`` opposing positive rotation: ``J dw/dt = ... - T_L``.
    coulomb_delta_Nm : float
        Half-difference of the Coulomb friction: ``Mc + d`` for ``w > 0``, ``Mc - d`` for
        ``w < 0`` (also the break-away thresholds).
    viscous_delta_Nm_s : float
        Half-difference of the viscous friction: ``(b + d) w`` for ``w > 0``, ``(b - d) w``
        for ``w < 0``.
    stribeck_excess_Nm, stribeck_velocity_rad_s : float
        Friction magnitude ``Mc + excess exp(-(w / velocity)^2)``: static friction
        ``Mc + excess`` at rest.
    drag_Nm_s2 : float
        Quadratic drag, torque ``-c w |w|`` [N m s^2/rad^2].
    brush_drop_V : float
        Brush voltage drop ``-V_b sgn(i)`` in the armature circuit.
    resistance_rate_ohm_per_s : float
        ``Ra(t) = Ra + rate (t - t_0)``, ``t_0`` the record start.
    cogging_amplitude_Nm, cogging_cycles_per_rev, cogging_phase_rad : float
        Torque ripple ``A sin(N theta + phase)`` with shaft angle ``theta``.
    current_offset_A : float
        Offset of the current sensor: measured = true + offset.
    current_delay_samples, speed_delay_samples : int
        Whole-sample delay of a sensor: measured ``y[k] = y_true[k - d]``.

    """

    load_torque_Nm: Annotated[float, ADD] = 0.0
    coulomb_delta_Nm: Annotated[float, ADD] = 0.0
    viscous_delta_Nm_s: Annotated[float, ADD] = 0.0
    stribeck_excess_Nm: Annotated[float, ADD] = 0.0
    stribeck_velocity_rad_s: Annotated[float, REPLACE] = 1.0
    drag_Nm_s2: Annotated[float, ADD] = 0.0
    brush_drop_V: Annotated[float, ADD] = 0.0
    resistance_rate_ohm_per_s: Annotated[float, ADD] = 0.0
    cogging_amplitude_Nm: Annotated[float, ADD] = 0.0
    cogging_cycles_per_rev: Annotated[float, REPLACE] = 0.0
    cogging_phase_rad: Annotated[float, REPLACE] = 0.0
    current_offset_A: Annotated[float, ADD] = 0.0
    current_delay_samples: Annotated[int, ADD] = 0
    speed_delay_samples: Annotated[int, ADD] = 0


#: Fields the exact hybrid solver handles by itself (as friction levels), without sub-steps.
EXACT_FIELDS = frozenset({'coulomb_delta_Nm'})
#: Fields applied to the simulated outputs (sensors), not inside the kernel.
SENSOR_FIELDS = frozenset({'current_offset_A', 'current_delay_samples', 'speed_delay_samples'})

_HINTS = get_type_hints(MotorEffects, include_extras=True)
#: Field -> (python type, combination rule), read from the annotations above.
FIELD_RULES: dict[str, tuple[type, str]] = {
    name: (get_args(_HINTS[name])[0], _HINTS[name].__metadata__[0])
    for name in MotorEffects._fields}
_DEFAULTS = MotorEffects()


def normalised(effects: MotorEffects) -> MotorEffects:
    """Return ``effects`` with every field of its declared type (one numba signature)."""
    return MotorEffects(*(FIELD_RULES[name][0](value)
                          for name, value in zip(MotorEffects._fields, effects)))


def set_fields(effects: MotorEffects) -> frozenset[str]:
    """Return the fields of ``effects`` that differ from their default."""
    return frozenset(name for name, value, default in zip(MotorEffects._fields, effects,
                                                          _DEFAULTS) if value != default)


def combine_contributions(parts: Iterable[MotorEffects]) -> MotorEffects:
    """Merge contributions by each field's rule (:data:`ADD` or :data:`REPLACE`), in order."""
    total = list(_DEFAULTS)
    for part in parts:
        for position, (name, value) in enumerate(zip(MotorEffects._fields, part)):
            if FIELD_RULES[name][1] == ADD:
                total[position] += value
            elif value != _DEFAULTS[position]:
                total[position] = value
    return normalised(MotorEffects._make(total))


EffectsLike = Union[None, MotorEffects, Iterable[Any]]


def combine_effects(effects: EffectsLike) -> MotorEffects:
    """
    Return one :class:`MotorEffects` from ``None``, a MotorEffects or a sequence of effects.

    The sequence holds vocabulary effects (:mod:`dcmotor_id.identification.effects`, whose
    ``motor_effects()`` returns their contribution) or MotorEffects contributions; they combine by
    the rule of each field (:func:`combine_contributions`).
    """
    if effects is None:
        return _DEFAULTS
    if isinstance(effects, MotorEffects):
        return normalised(effects)
    items: Iterable[Any] = effects
    return combine_contributions(
        effect if isinstance(effect, MotorEffects) else effect.motor_effects()
        for effect in items)
