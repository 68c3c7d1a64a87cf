"""
The separately excited DC motor with constant flux, in SI units.

The model (shared/paper/ERRATA.md, the paper's eqs. 1-5 with the sign slips corrected)::

    La di/dt = u - Ra i - CPhi w
    J  dw/dt = CPhi i - b w - Mc sgn(w)

with armature voltage ``u`` [V], armature current ``i`` [A], shaft speed ``w`` [rad/s].
Derived quantities: rotor gain ``Ka = 1/Ra`` [1/Ohm] and electrical time constant
``Ta = La/Ra`` [s].  When the shaft is at rest, Coulomb friction holds it (stiction) for as
long as the magnitude of the driving torque does not exceed ``Mc``.

This module holds the parameters and the linear part of the model; the hybrid (stick-slip)
solution lives in :mod:`dcmotor_id.simulation`.
"""

from dataclasses import asdict, dataclass, fields, replace

import numpy as np

#: Names of the physical parameters, in the order used everywhere.
PARAMETER_NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
#: Names of the derived parameters.
DERIVED_NAMES = ('Ka', 'Ta')
#: Mechanical parameters (the mechanical-only mode identifies these).
MECHANICAL_NAMES = ('J', 'b', 'Mc')
#: SI unit of every parameter name.
UNITS = {
    'Ra': 'Ohm', 'La': 'H', 'CPhi': 'V s', 'J': 'kg m^2', 'b': 'N m s/rad', 'Mc': 'N m',
    'Ka': '1/Ohm', 'Ta': 's',
}


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
    def Ka(self):
        """Rotor gain ``1/Ra`` [1/Ohm]."""
        return 1.0 / self.Ra

    @property
    def Ta(self):
        """Electrical time constant ``La/Ra`` [s]."""
        return self.La / self.Ra

    def as_dict(self, derived=True):
        """Return the parameters as a plain dict, with Ka and Ta when ``derived``."""
        values = {key: float(value) for key, value in asdict(self).items()}
        if derived:
            values['Ka'] = float(self.Ka)
            values['Ta'] = float(self.Ta)
        return values

    @classmethod
    def from_dict(cls, values):
        """Build from a mapping holding at least the six physical parameters."""
        missing = [name for name in PARAMETER_NAMES if name not in values]
        if missing:
            raise KeyError(f'motor parameters missing: {", ".join(missing)}')
        return cls(**{name: float(values[name]) for name in PARAMETER_NAMES})

    def replace(self, **changes):
        """Return a copy with some parameters changed."""
        return replace(self, **changes)

    def as_array(self):
        """Return ``[Ra, La, CPhi, J, b, Mc]`` as a float array."""
        return np.array([getattr(self, f.name) for f in fields(self)], dtype=float)


#: The two motors of the paper's Table 1.
PAPER_MOTORS = {
    'paper1': MotorParameters(Ra=0.208, La=0.0081, CPhi=0.8, J=0.0346, b=1.0, Mc=0.8),
    'paper2': MotorParameters(Ra=1.6, La=0.016, CPhi=0.7, J=0.0315, b=0.3, Mc=1.0),
}


def state_matrix(params):
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


def relative_errors_pct(estimate, truth, names=None):
    """Relative error ``|estimate - truth| / |truth| * 100`` (the paper's eq. 26) per name."""
    est = estimate.as_dict() if isinstance(estimate, MotorParameters) else dict(estimate)
    ref = truth.as_dict() if isinstance(truth, MotorParameters) else dict(truth)
    names = names or [name for name in est if name in ref]
    return {name: abs(est[name] - ref[name]) / abs(ref[name]) * 100.0 for name in names}
