"""
What every estimator takes and returns: the :class:`Estimator` protocol, its terms and result.

An estimator is an object with a ``name`` and ``fit(records, torque_constant=None, terms=())``
returning an :class:`Estimate`.  ``records`` are checked, uniformly sampled
:class:`~dcmotor_id.core.records.Record` objects that all carry current and speed, and voltage
unless
``torque_constant`` is given (mechanical-only mode: identify J, b, Mc with the torque
``torque_constant * current`` as the input).  Effects enter a fit as terms:
:class:`ExogenousTerm` (linear in a coefficient, regressors from the measured signals) and
:class:`StateTerm` (a coefficient of the simulated :class:`~dcmotor_id.simulation.MotorEffects`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol, runtime_checkable, Sequence


from dcmotor_id.simulation.coefficients import MotorEffects


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
        Name of the coefficient as reported (e.g. ``load_torque.torque_Nm``, see
        :func:`dcmotor_id.core.model.term_name`).
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
class StateTerm(ExogenousTerm):
    """
    An effect whose coefficient sets a field of :class:`~dcmotor_id.simulation.MotorEffects`.

    Used where a regressor of measured signals cannot express the effect: friction that
    depends on the simulated speed and changes the break-away level (Stribeck, asymmetric
    Coulomb friction), or a brush drop that blocks the current.  The model is then simulated
    with :func:`~dcmotor_id.simulation.simulate_motor_effects` (state-dependent terms held
    over half-samples); fields the hybrid solver handles exactly
    (:data:`~dcmotor_id.simulation.EXACT_FIELDS`: an asymmetric Coulomb friction) keep the
    exact fast path.  ``channel`` is ``state`` and the regressors only serve the residual
    correlations.

    Attributes
    ----------
    field : str
        The :class:`~dcmotor_id.simulation.MotorEffects` field the coefficient sets.
    fixed : tuple of (str, float)
        Other fields held at given values (e.g. the Stribeck velocity).

    """

    field: str = ''
    fixed: tuple = ()

    def __post_init__(self) -> None:
        """Refuse a field the simulator does not have."""
        for name in (self.field, *(key for key, _ in self.fixed)):
            if name not in MotorEffects._fields:
                raise ValueError(f'term {self.name}: {name!r} is not a MotorEffects field')

    def contribution(self, value: float) -> MotorEffects:
        """Return the term's contribution to the simulation with coefficient ``value``."""
        return MotorEffects(**{self.field: value, **dict(self.fixed)})

    def fields(self) -> frozenset[str]:
        """Return the MotorEffects fields the term sets."""
        return frozenset((self.field, *(key for key, _ in self.fixed)))


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
        the coefficient of every exogenous term by its name (a values mapping of
        :mod:`dcmotor_id.core.model` with the derived values added).
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
    def mechanical_only(self) -> bool:
        """Whether only J, b and Mc were identified."""
        return 'Ra' not in self.parameters


@runtime_checkable
class Estimator(Protocol):
    """
    What :func:`dcmotor_id.identification.identify.identify` needs of an estimator.

    Attributes
    ----------
    name : str
        The method's name (``Estimate.method``).
    supports_terms : bool
        Whether :meth:`fit` accepts effect terms, which the effect discovery loop needs.

    """

    name: ClassVar[str]
    supports_terms: ClassVar[bool]

    def fit(self, records: Sequence[Any], torque_constant: float | None = None,
            terms: Sequence[ExogenousTerm] = ()) -> Estimate:
        """Fit the records; return the :class:`Estimate`."""
        ...
