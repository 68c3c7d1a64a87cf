"""
The :class:`Effect` base class: what every effect of the vocabulary declares and does.

Every effect documents its parameters (units, sign convention) and does two jobs:

* **Simulate** (:meth:`Effect.motor_effects`): its typed contribution, a
  :class:`~dcmotor_id.simulation.MotorEffects` with its own fields set, for
  :func:`dcmotor_id.simulation.simulate_motor_effects` and the ``effects=`` option of
  :class:`dcmotor_id.simulation.MotorStepper`, to make data with the effect in it.
* **Estimate** (:meth:`Effect.terms`, :meth:`Effect.transform`): what the output-error fit
  needs to model the effect: linear
  :class:`~dcmotor_id.identification.estimators.base.ExogenousTerm`
  regressors built from the *measured* signals (the sign of the speed, ``w |w|``, the shaft
  angle...), a :class:`~dcmotor_id.identification.estimators.base.StateTerm` simulated exactly by
  the fit, or
  a data transform (:class:`~dcmotor_id.identification.effects.sensor_delay.SensorDelay`).
  Nonlinear inner
  parameters (the Stribeck velocity, the cogging period) are found by the small grid of
  :meth:`Effect.inner_grid`; the discovery loop (:mod:`dcmotor_id.identification.discovery`)
  screens the grid
  and refits all parameters at the best point.

Every subclass with a ``name`` registers itself (:data:`REGISTRY`);
:mod:`dcmotor_id.identification.effects`
builds the vocabulary from the registry, ordered by :attr:`Effect.RANK`.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from dcmotor_id.core.model import term_name
from dcmotor_id.identification.estimators.base import ExogenousTerm, StateTerm
from dcmotor_id.signals.filters import integrate_trapezoid
from dcmotor_id.simulation.coefficients import MotorEffects

#: Parameter values by name (base parameters and term coefficients).
Values = Mapping[str, float]
#: Inner (grid-searched) parameters of an effect.
Inner = Mapping[str, Any]
#: Records (:class:`~dcmotor_id.core.records.Record`).
Records = Sequence[Any]
#: The terms an effect adds to the fit.
Terms = tuple[ExogenousTerm, ...]

#: Every effect class with a name, in definition order (filled by :class:`Effect`).
REGISTRY: list[type[Effect]] = []


def shaft_angle(record: Any) -> np.ndarray:
    """Shaft angle [rad]: the measured position, else the integral of the measured speed."""
    if record.position is not None:
        return np.asarray(record.position, dtype=float)
    return integrate_trapezoid(record.speed, record.sample_period_s)


def torque_spread(records: Sequence[Any], base: Mapping[str, float],
                  torque_constant: float | None = None) -> float:
    """Return the standard deviation of the driving torque (``CPhi i`` or ``K i``) [N m]."""
    constant = torque_constant if torque_constant is not None else base.get('CPhi', 1.0)
    current = np.concatenate([rec.current for rec in records])
    return max(float(constant * np.std(current)), 1e-12)


class Effect:
    """
    One effect: its parameters, its simulation and its estimation.

    Subclasses set :attr:`name`, :attr:`PARAMETERS`, :attr:`MODES` and :attr:`RANK` and
    implement :meth:`motor_effects`, :meth:`terms` (or :meth:`transform`) and
    :meth:`from_fit`.  Defining the subclass registers it.

    Parameters
    ----------
    **parameters : float
        Values of the effect's parameters by name (see :attr:`PARAMETERS`); missing ones take
        their default.

    """

    #: Vocabulary name (as in the JSON result).
    name: ClassVar[str] = ''
    #: One-line description.
    summary: ClassVar[str] = ''
    #: Parameter name -> (unit, default, meaning and sign).
    PARAMETERS: ClassVar[dict[str, tuple[str, Any, str]]] = {}
    #: Modes where the effect applies: ``full``, ``mechanical`` and/or ``voltage_speed``
    #: (records without a current: the effect acts on the shaft and is fitted in volts).
    MODES: ClassVar[tuple[str, ...]] = ('full', 'mechanical')
    #: In mode ``voltage_speed``: each parameter's name, unit and make-up there (a torque on
    #: the shaft is the voltage ``Ra T/CPhi``); parameters not listed keep their name and unit.
    VOLTAGE_SPEED_NAMES: ClassVar[dict[str, tuple[str, str, str]]] = {}
    #: Whether the effect acts by transforming the data instead of by terms.
    TRANSFORM: ClassVar[bool] = False
    #: Place in the vocabulary: ties between equivalent effects go to the lower rank.
    RANK: ClassVar[int] = 1000
    #: Beyond the issue's vocabulary: only in the extended vocabulary (opt-in for the loop).
    EXTENDED: ClassVar[bool] = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Register every named effect class."""
        super().__init_subclass__(**kwargs)
        if cls.name:
            REGISTRY.append(cls)

    def __init__(self, **parameters: Any) -> None:
        unknown = sorted(set(parameters) - set(self.PARAMETERS))
        if unknown:
            raise ValueError(f'{self.name}: unknown parameter(s) {", ".join(unknown)}; it has '
                             f'{", ".join(self.PARAMETERS) or "none"}')
        self.parameters = {key: parameters.get(key, spec[1])
                           for key, spec in self.PARAMETERS.items()}

    def __repr__(self) -> str:
        """Return e.g. ``LoadTorque(torque_Nm=0.5)``."""
        listing = ', '.join(f'{key}={value!r}' for key, value in self.parameters.items())
        return f'{type(self).__name__}({listing})'

    @classmethod
    def applies(cls, mechanical_only: bool) -> bool:
        """Whether the effect can act in this mode."""
        return ('mechanical' if mechanical_only else 'full') in cls.MODES

    @classmethod
    def in_voltage_speed(cls) -> bool:
        """Whether the effect acts in the voltage-to-speed model (records without a current)."""
        return 'voltage_speed' in cls.MODES

    def describe_voltage_speed(self) -> dict[str, Any]:
        """
        JSON form in mode ``voltage_speed``: the parameters named in volts.

        The values of an effect of the voltage-to-speed model are in volts already (its
        torque parameters hold ``Ra T/CPhi``); only the names change
        (:attr:`VOLTAGE_SPEED_NAMES`).
        """
        return {'name': self.name,
                'parameters': {self.VOLTAGE_SPEED_NAMES.get(key, (key,))[0]: value
                               for key, value in self.parameters.items()}}

    @classmethod
    def from_voltage_speed(cls, parameters: Mapping[str, Any]) -> Effect:
        """
        Build the effect from its ``voltage_speed`` JSON parameters (values stay in volts).

        The inverse of :meth:`describe_voltage_speed`: what the voltage-to-speed simulation
        takes (its shaft fields in volts); unknown names are left out.
        """
        names = {entry[0]: key for key, entry in cls.VOLTAGE_SPEED_NAMES.items()}
        return cls(**{names.get(key, key): value for key, value in parameters.items()
                      if names.get(key, key) in cls.PARAMETERS})

    def motor_effects(self) -> MotorEffects:
        """Return the effect's contribution to the simulation (its fields set)."""
        raise NotImplementedError

    @classmethod
    def inner_grid(cls, records: Sequence[Any], base: Mapping[str, float],
                   torque_constant: float | None = None) -> list[dict[str, Any]]:
        """Values of the nonlinear inner parameters to screen (``[{}]`` when there are none)."""
        return [{}]

    @classmethod
    def terms(cls, records: Sequence[Any], inner: Mapping[str, Any], base: Mapping[str, float],
              torque_constant: float | None = None,
              initial: Mapping[str, float] | None = None) -> tuple[ExogenousTerm, ...]:
        """
        Exogenous terms of the effect for these records (regressors from measured signals).

        Parameters
        ----------
        records : list of Record
            The records (the regressors are as long as each).
        inner : dict
            Inner parameters (from :meth:`inner_grid`).
        base : dict
            Current parameter values (for the coefficients' typical magnitude).
        torque_constant : float, optional
            Mechanical-only mode.
        initial : dict, optional
            Start values of the coefficients by term name.

        """
        return ()

    @classmethod
    def transform(cls, records: Sequence[Any], inner: Mapping[str, Any]) -> list[Any]:
        """Return the records as the model should see them (identity but for data effects)."""
        return list(records)

    @classmethod
    def from_fit(cls, values: Mapping[str, float], inner: Mapping[str, Any]) -> Effect:
        """Build the effect from the parameters fitted in ``values`` (by term name)."""
        raise NotImplementedError

    def problem(self, base: Mapping[str, float], records: Sequence[Any]) -> str | None:
        """
        Why the fitted effect is not physical (a sentence), or None when it is.

        The discovery loop rejects a candidate whose fit is not physical (a drag that drives
        the shaft, a negative brush drop...) instead of reporting a wrong effect.
        """
        return None

    @classmethod
    def term_name(cls, coefficient: str) -> str:
        """Name of a coefficient in the fit: ``<effect>.<parameter>``."""
        return term_name(cls.name, coefficient)

    def describe(self, base: Mapping[str, float] | None = None) -> dict[str, Any]:
        """JSON form ``{"name": ..., "parameters": {...}}``."""
        return {'name': self.name, 'parameters': dict(self.parameters)}

    @classmethod
    def documentation(cls) -> str:
        """Markdown-ready description of the effect and its parameters."""
        lines = [f'`{cls.name}`: {cls.summary}']
        for key, (unit, _, meaning) in cls.PARAMETERS.items():
            lines.append(f'  - `{key}` [{unit}]: {meaning}')
        for key, (volts, unit, of) in cls.VOLTAGE_SPEED_NAMES.items():
            lines.append(f'  - `{volts}` [{unit}]: {of}, in mode voltage_speed (no current)')
        return '\n'.join(lines)

    @staticmethod
    def _term(name: str, channel: str, regressors: Sequence[Any], scale: float,
              initial: Mapping[str, float] | None, field: str | None = None,
              fixed: tuple[tuple[str, float], ...] = ()) -> ExogenousTerm:
        """Build a linear term, or a :class:`StateTerm` (channel ``state``) if ``field``."""
        start = 0.0 if initial is None else float(initial.get(name, 0.0))
        arrays = tuple(np.asarray(r, dtype=float) for r in regressors)
        if field is not None:
            return StateTerm(name, 'state', arrays, float(scale), start, field, tuple(fixed))
        return ExogenousTerm(name, channel, arrays, float(scale), start)
