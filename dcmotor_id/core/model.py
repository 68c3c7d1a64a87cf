"""
The motor model's parameters: names, units, derived values, admissibility and term names.

The separately excited DC motor with constant flux, in SI units (shared/paper/ERRATA.md, the
paper's eqs. 1-5 with the sign slips corrected)::

    La di/dt = u - Ra i - CPhi w
    J  dw/dt = CPhi i - b w - Mc sgn(w)

with armature voltage ``u`` [V], armature current ``i`` [A], shaft speed ``w`` [rad/s].
Derived quantities: rotor gain ``Ka = 1/Ra`` [1/Ohm] and electrical time constant
``Ta = La/Ra`` [s].  When the shaft is at rest, Coulomb friction holds it (stiction) for as
long as the magnitude of the driving torque does not exceed ``Mc``.

The parameters travel in these forms, each for a reason:

* :class:`MotorParameters`: the six base parameters of one motor, typed (the simulator's input
  and a ground truth).
* A *values* mapping ``name -> float``: the base parameters of a mode (:func:`parameter_names`)
  plus the coefficient of every effect term, named ``<effect>.<parameter>``
  (:func:`term_name`).  This is the flat parameter vector of a fit, by name;
  :attr:`~dcmotor_id.identification.estimators.base.Estimate.parameters` is such a mapping with the
  derived
  values (:func:`derived_values`) added.
* :class:`~dcmotor_id.simulation.MotorEffects`: what the simulator needs to reproduce effects (its
  own coefficients, combined from the effects of :mod:`dcmotor_id.identification.effects`, whose
  ``parameters`` are the effect's parameters as reported in JSON).

The hybrid (stick-slip) solution lives in :mod:`dcmotor_id.simulation`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping, Sequence

import numpy as np

#: Names of the physical parameters, in the order used everywhere.
PARAMETER_NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
#: Names of the derived parameters.
DERIVED_NAMES = ('Ka', 'Ta')
#: Mechanical parameters (the mechanical-only mode identifies these).
MECHANICAL_NAMES = ('J', 'b', 'Mc')
#: Parameters that must be strictly positive for a physical motor.
POSITIVE_NAMES = ('Ra', 'La', 'CPhi', 'J')
#: Parameters that must be non-negative (friction).
NON_NEGATIVE_NAMES = ('b', 'Mc')
#: SI unit of every parameter name.
UNITS = {
    'Ra': 'Ohm', 'La': 'H', 'CPhi': 'V s', 'J': 'kg m^2', 'b': 'N m s/rad', 'Mc': 'N m',
    'Ka': '1/Ohm', 'Ta': 's',
}
#: Separator of an effect term's name: ``<effect>.<parameter>``.
TERM_SEPARATOR = '.'


@dataclass(frozen=True)
class MotorParameters:
    """
    Physical parameters of a separately excited DC motor (SI units).

    Attributes
    ----------
    Ra : float
        Armature resistance [Ohm].
    La : float
        Armature inductance [H].
    CPhi : float
        Back-EMF (and torque) constant, the flux linkage [V s] = [N m/A].
    J : float
        Moment of inertia of the rotor and load [kg m^2].
    b : float
        Viscous friction coefficient [N m s/rad].
    Mc : float
        Coulomb friction torque [N m].

    """

    Ra: float
    La: float
    CPhi: float
    J: float
    b: float
    Mc: float

    @property
    def Ka(self) -> float:
        """Rotor gain ``1/Ra`` [1/Ohm]."""
        return derived_values(self.as_dict(derived=False))['Ka']

    @property
    def Ta(self) -> float:
        """Electrical time constant ``La/Ra`` [s]."""
        return derived_values(self.as_dict(derived=False))['Ta']

    def as_dict(self, derived: bool = True) -> dict[str, float]:
        """Return the parameters as a plain dict, with Ka and Ta when ``derived``."""
        values = {key: float(value) for key, value in asdict(self).items()}
        if derived:
            values.update(derived_values(values))
        return values

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> MotorParameters:
        """Build from a mapping holding at least the six physical parameters (others ignored)."""
        missing = [name for name in PARAMETER_NAMES if name not in values]
        if missing:
            raise KeyError(f'motor parameters missing: {", ".join(missing)}')
        return cls(**{name: float(values[name]) for name in PARAMETER_NAMES})

    def replace(self, **changes: float) -> MotorParameters:
        """Return a copy with some parameters changed."""
        return replace(self, **changes)

    def as_array(self) -> np.ndarray:
        """Return ``[Ra, La, CPhi, J, b, Mc]`` as a float array."""
        return np.array([getattr(self, f.name) for f in fields(self)], dtype=float)


#: The two motors of the paper's Table 1.
PAPER_MOTORS = {
    'paper1': MotorParameters(Ra=0.208, La=0.0081, CPhi=0.8, J=0.0346, b=1.0, Mc=0.8),
    'paper2': MotorParameters(Ra=1.6, La=0.016, CPhi=0.7, J=0.0315, b=0.3, Mc=1.0),
}


def parameter_names(mechanical_only: bool) -> tuple[str, ...]:
    """Return the base parameter names identified in a mode."""
    return MECHANICAL_NAMES if mechanical_only else PARAMETER_NAMES


def derived_values(values: Mapping[str, float]) -> dict[str, float]:
    """
    Return the derived parameters ``Ka = 1/Ra`` [1/Ohm] and ``Ta = La/Ra`` [s].

    Examples
    --------
    >>> derived_values({'Ra': 2.0, 'La': 0.01})
    {'Ka': 0.5, 'Ta': 0.005}

    """
    ra, la = values['Ra'], values['La']
    return {'Ka': 1.0 / ra, 'Ta': la / ra}


def derived_stderr(values: Mapping[str, float], covariance: np.ndarray,
                   names: Sequence[str]) -> dict[str, float]:
    """
    Return the standard errors of Ka and Ta by the delta method.

    Parameters
    ----------
    values : mapping
        Parameter values holding ``Ra`` and ``La``.
    covariance : numpy.ndarray
        Covariance of the parameters ``names`` (rows and columns in that order).
    names : sequence of str
        Names of the covariance's rows; must include ``Ra`` and ``La``.

    """
    index = {name: position for position, name in enumerate(names)}
    ra, la = values['Ra'], values['La']
    if not (np.isfinite(ra) and ra ** 2 > 0.0):
        # Ra pressed to its bound (1e-170 Ohm: its square is zero): Ka and Ta are not
        # determined
        return {'Ka': float('inf'), 'Ta': float('inf')}
    grad_ka = np.zeros(len(names))
    grad_ka[index['Ra']] = -1.0 / ra ** 2
    grad_ta = np.zeros(len(names))
    grad_ta[index['Ra']] = -la / ra ** 2
    grad_ta[index['La']] = 1.0 / ra
    return {
        'Ka': float(np.sqrt(max(grad_ka @ covariance @ grad_ka, 0.0))),
        'Ta': float(np.sqrt(max(grad_ta @ covariance @ grad_ta, 0.0))),
    }


def inadmissible(values: Mapping[str, float]) -> dict[str, float]:
    """
    Return the base parameters of ``values`` that no physical motor has, by name.

    Admissible: finite, ``Ra, La, CPhi, J`` positive, ``b`` and ``Mc`` non-negative.  Only the
    base names present are checked (the mechanical-only mode has J, b, Mc); term coefficients
    and derived values are ignored.
    """
    bad = {}
    for name in PARAMETER_NAMES:
        if name not in values:
            continue
        value = values[name]
        if not (np.isfinite(value) and (value > 0 if name in POSITIVE_NAMES else value >= 0)):
            bad[name] = value
    return bad


def is_admissible(values: Mapping[str, float]) -> bool:
    """Whether every base parameter in ``values`` is physical (see :func:`inadmissible`)."""
    return not inadmissible(values)


def make_admissible(values: Mapping[str, float]) -> dict[str, float] | None:
    """
    Return a start point made admissible, or None when it cannot be.

    ``Ra, La, CPhi, J`` take their magnitude (None if zero), ``b`` and ``Mc`` are floored at
    zero; any non-finite value gives None.
    """
    out = {}
    for name, value in values.items():
        value = float(value)
        if not np.isfinite(value):
            return None
        if name in POSITIVE_NAMES:
            value = abs(value)
            if value == 0.0:
                return None
        elif name in NON_NEGATIVE_NAMES:
            value = max(value, 0.0)
        out[name] = value
    return out


def term_name(effect: str, parameter: str) -> str:
    """Name of an effect's coefficient in a values mapping: ``<effect>.<parameter>``."""
    return f'{effect}{TERM_SEPARATOR}{parameter}'


def split_term_name(name: str) -> tuple[str, str] | None:
    """Return ``(effect, parameter)`` of a term name, or None for a base or derived name."""
    effect, separator, parameter = name.partition(TERM_SEPARATOR)
    return (effect, parameter) if separator else None


def base_values(values: Mapping[str, float], mechanical_only: bool = False) -> dict[str, float]:
    """Return the base parameters of a mode from a values mapping (terms and derived dropped)."""
    return {name: float(values[name]) for name in parameter_names(mechanical_only)}


def state_matrix(params: MotorParameters) -> np.ndarray:
    """
    Continuous-time state matrix of the motor for the state ``[i, w]``.

    Parameters
    ----------
    params : MotorParameters
        The motor.

    Returns
    -------
    numpy.ndarray
        ``A`` (2x2) such that ``d[i, w]/dt = A [i, w] + [u/La, (tau - Mc sgn w)/J]``
        where ``tau`` is any other torque acting on the shaft [N m].

    """
    return np.array([
        [-params.Ra / params.La, -params.CPhi / params.La],
        [params.CPhi / params.J, -params.b / params.J],
    ])


def relative_errors_pct(estimate: MotorParameters | Mapping[str, float],
                        truth: MotorParameters | Mapping[str, float],
                        names: Sequence[str] | None = None) -> dict[str, float]:
    """Relative error ``|estimate - truth| / |truth| * 100`` (the paper's eq. 26) per name."""
    est = estimate.as_dict() if isinstance(estimate, MotorParameters) else dict(estimate)
    ref = truth.as_dict() if isinstance(truth, MotorParameters) else dict(truth)
    names = names or [name for name in est if name in ref]
    return {name: abs(est[name] - ref[name]) / abs(ref[name]) * 100.0 for name in names}
