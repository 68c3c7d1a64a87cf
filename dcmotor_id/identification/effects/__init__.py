"""
The vocabulary of effects the base motor model lacks: the registry of the effect modules.

Each effect is one module of this package (named as the effect) holding one
:class:`~dcmotor_id.identification.effects.base.Effect` subclass: its parameters, its contribution
to the
simulation and its terms for the fit.  The modules are imported here automatically and every
subclass registers itself, so adding an effect is adding its module (and its test).

Sign convention throughout: the shaft equation is ``J dw/dt = CPhi i - b w - Mc sgn(w) + ...``
(``K i`` in the mechanical-only mode) and the armature circuit ``La di/dt = u - Ra i - CPhi w
+ ...``; each class says what it adds.  Units are SI (N m, rad/s, V, A, Ohm, s); for a linear
axis such as EMPS read N for N m and m for rad.

Two effects of the vocabulary are the same model in most data: a constant load torque ``T`` on
a shaft with Coulomb friction ``Mc`` behaves exactly like direction-dependent Coulomb friction
``Mc + T`` / ``Mc - T`` (in motion and at rest) as long as ``|T| < Mc``; they differ only when
the load can turn the shaft by itself.  The discovery loop reports such ties (the earlier
effect in :data:`VOCABULARY` wins and the other is listed as equivalent).
"""

from __future__ import annotations

import importlib
import math
import pkgutil
from typing import Any

from dcmotor_id.identification.effects.base import Effect, REGISTRY, shaft_angle, torque_spread
from dcmotor_id.identification.effects.brush_drop import BrushDrop
from dcmotor_id.identification.effects.cogging import Cogging
from dcmotor_id.identification.effects.coulomb_asymmetry import CoulombAsymmetry
from dcmotor_id.identification.effects.current_offset import CurrentOffset
from dcmotor_id.identification.effects.load_torque import LoadTorque
from dcmotor_id.identification.effects.quadratic_drag import QuadraticDrag
from dcmotor_id.identification.effects.resistance_drift import ResistanceDrift
from dcmotor_id.identification.effects.sensor_delay import SensorDelay
from dcmotor_id.identification.effects.stribeck import Stribeck
from dcmotor_id.identification.effects.viscous_asymmetry import ViscousAsymmetry

# The imports above name the classes other modules use; this loop imports any further effect
# module of the package, so a new effect needs no edit here.
for _module in pkgutil.iter_modules(__path__):
    if _module.name != 'base':
        importlib.import_module(f'{__name__}.{_module.name}')

#: The vocabulary the discovery loop searches by default, in the order ties are broken (the
#: earlier wins).
VOCABULARY: tuple[type[Effect], ...] = tuple(sorted(
    (cls for cls in REGISTRY if not cls.EXTENDED), key=lambda cls: cls.RANK))
#: The vocabulary with the additions beyond the issue's list (opt-in for the loop).
EXTENDED_VOCABULARY: tuple[type[Effect], ...] = VOCABULARY + tuple(sorted(
    (cls for cls in REGISTRY if cls.EXTENDED), key=lambda cls: cls.RANK))
#: Effect classes by name (every effect, for simulation and the CLI).
EFFECTS: dict[str, type[Effect]] = {cls.name: cls for cls in EXTENDED_VOCABULARY}

__all__ = [
    'BrushDrop', 'Cogging', 'CoulombAsymmetry', 'CurrentOffset', 'Effect', 'EFFECTS',
    'EXTENDED_VOCABULARY', 'LoadTorque', 'make_effect', 'parse_effect', 'QuadraticDrag',
    'ResistanceDrift', 'SensorDelay', 'shaft_angle', 'Stribeck', 'torque_spread',
    'ViscousAsymmetry', 'VOCABULARY',
]


def make_effect(name: str, **parameters: Any) -> Effect:
    """Build an effect by its name (e.g. ``stribeck`` with ``excess_Nm=0.3``)."""
    if name not in EFFECTS:
        raise ValueError(f'unknown effect {name!r}; the vocabulary is {", ".join(EFFECTS)}')
    return EFFECTS[name](**parameters)


def parse_effect(text: str) -> Effect:
    """
    Parse ``NAME[:param=value,...]`` (the CLI's ``--effect``) into an effect.

    Examples
    --------
    >>> effect = parse_effect('load_torque:torque_Nm=0.3')
    >>> effect.name, effect.parameters['torque_Nm']
    ('load_torque', 0.3)

    """
    name, _, rest = text.partition(':')
    parameters: dict[str, Any] = {}
    for item in filter(None, (part.strip() for part in rest.split(','))):
        key, sep, value = item.partition('=')
        if not sep:
            raise ValueError(f'--effect {text!r}: write param=value, got {item!r}')
        key = key.strip()
        try:
            parameters[key] = float(value)
        except ValueError:
            parameters[key] = value.strip()
        if isinstance(parameters[key], float) and not math.isfinite(parameters[key]):
            raise ValueError(f'--effect {text!r}: {key} = {value.strip()} is not a finite '
                             'number; give a value')
    return make_effect(name.strip(), **parameters)
