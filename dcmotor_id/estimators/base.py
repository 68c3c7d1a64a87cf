"""
What every estimator takes and returns, and the data layout they share.

An estimator is an object with a ``name`` and ``fit(records, torque_constant=None, terms=())``
returning an :class:`Estimate`.  ``records`` are checked, uniformly sampled
:class:`~dcmotor_id.io.Record` objects that all carry current and speed, and voltage unless
``torque_constant`` is given (mechanical-only mode: identify J, b, Mc with the torque
``torque_constant * current`` as the input).
"""

from dataclasses import dataclass, field

import numpy as np

from dcmotor_id.model import MECHANICAL_NAMES, PARAMETER_NAMES


@dataclass(frozen=True)
class ExogenousTerm:
    """
    A linear-in-its-coefficient term added to the model, for effects.

    The model gains ``coefficient * regressor[k]`` on one channel: ``voltage`` (added to the
    armature voltage, V), ``torque`` (added to the shaft torque, N m), ``current`` or ``speed``
    (added to that measured output: a sensor offset or error).

    Attributes
    ----------
    name : str
        Name of the coefficient as reported (e.g. ``load_torque.torque_Nm``).
    channel : str
        ``voltage``, ``torque``, ``current`` or ``speed``.
    regressors : tuple of numpy.ndarray
        One regressor array per record, each as long as its record.
    scale : float
        Typical magnitude of the coefficient (for conditioning), > 0.
    initial : float
        Starting value of the coefficient.

    """

    name: str
    channel: str
    regressors: tuple
    scale: float = 1.0
    initial: float = 0.0


@dataclass(frozen=True)
class Estimate:
    """
    Result of one estimator on a set of records.

    Attributes
    ----------
    method : str
        Estimator name.
    parameters : dict
        Physical parameters (Ra, La, CPhi, J, b, Mc, Ka, Ta; or J, b, Mc) in SI units, plus
        the coefficient of every exogenous term by its name.
    stderr : dict
        Standard error of every entry of ``parameters`` (NaN where none is available).
    initial_states : list of tuple
        Estimated or assumed initial state of every record.
    info : dict
        Estimator-specific diagnostics (iterations, noise estimates, ...).

    """

    method: str
    parameters: dict
    stderr: dict
    initial_states: list = field(default_factory=list)
    info: dict = field(default_factory=dict)

    @property
    def mechanical_only(self):
        """Whether only J, b and Mc were identified."""
        return 'Ra' not in self.parameters


def parameter_names(mechanical_only):
    """Return the base parameter names identified in a mode."""
    return MECHANICAL_NAMES if mechanical_only else PARAMETER_NAMES


def derived_stderr(values, covariance, names):
    """Return the standard errors of Ka = 1/Ra and Ta = La/Ra from a covariance."""
    index = {name: position for position, name in enumerate(names)}
    ra, la = values['Ra'], values['La']
    grad_ka = np.zeros(len(names))
    grad_ka[index['Ra']] = -1.0 / ra ** 2
    grad_ta = np.zeros(len(names))
    grad_ta[index['Ra']] = -la / ra ** 2
    grad_ta[index['La']] = 1.0 / ra
    return {
        'Ka': float(np.sqrt(max(grad_ka @ covariance @ grad_ka, 0.0))),
        'Ta': float(np.sqrt(max(grad_ta @ covariance @ grad_ta, 0.0))),
    }


def nrmse_pct(simulated, measured):
    """Return the simulation error in percent of the measured signal's standard deviation."""
    spread = np.std(measured)
    if spread == 0:
        return float('nan')
    return float(np.sqrt(np.mean((simulated - measured) ** 2)) / spread * 100.0)
