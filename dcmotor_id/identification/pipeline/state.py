"""
What one run of the pipeline hands from stage to stage: frozen, a stage returns a new one.

:class:`Request`: what the caller asks (``identify``'s arguments).  :class:`RunOn`: the
choices one run makes for its fits (criterion, the position error's model, an earlier run's
further starts).  :class:`Inputs`: both, with the records as the first stage leaves them and
the estimator the base fit settles on.  :class:`Fit`: the base fit and what the armature, the
start check and the discovery loop made of it.  :class:`Answer`: the reported fit, its values
and standard errors, what the data do not determine and the per-record errors.  ``warnings``
travel in :class:`Fit`, then :class:`Answer`, in the order the stages give them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Sequence, TYPE_CHECKING

from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.checks.identifiability import Excitation
from dcmotor_id.identification.checks.start import regression_evidence
from dcmotor_id.identification.estimators.base import Estimator
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.error_model.residuals import ChannelErrors, Simulation
    from dcmotor_id.identification.estimators.base import Estimate


@dataclass(frozen=True)
class Request:
    """What the caller asks: the records and ``identify``'s choices (checked)."""

    records: Sequence[Record]
    method: str
    torque_constant: float | None
    discover: bool
    estimator: Estimator | None
    vocabulary: Sequence[type[Effect]] | None
    progress: Progress
    initial_state: str


@dataclass(frozen=True)
class RunOn:
    """
    How one run fits: the criterion, the position error's model, an earlier run's starts.

    ``position_error``: ``adaptive`` or ``white``
    (:func:`~dcmotor_id.identification.error_model.criterion.check_position_error_model`);
    ``earlier``:
    the further starts' account of an earlier run of the same identification
    (:func:`~dcmotor_id.identification.pipeline.further_starts.several_starts`); ``name``:
    what the status line calls the run when it starts (none: the first run, unnamed).
    """

    criterion: str
    position_error: str = 'adaptive'
    earlier: dict[str, Any] | None = None
    name: str = ''


@dataclass(frozen=True)
class Inputs:
    """What every stage reads: the request as the first stages settle it, and how it fits."""

    records: list[Record]
    method: str
    torque_constant: float | None
    discover: bool
    estimator: Estimator | None
    vocabulary: list[type[Effect]]
    progress: Progress
    initial_state: str
    on: RunOn
    excitation: Excitation
    warnings: tuple[str, ...] = ()  # the first stage's

    @property
    def criterion(self) -> str:
        """Return the channels the fits compare (``speed``, ``position`` or ``both``)."""
        return self.on.criterion

    @property
    def mechanical_only(self) -> bool:
        """Whether the torque constant is given (J, b and Mc only)."""
        return self.torque_constant is not None

    @cached_property
    def evidence(self) -> dict[str, float] | None:
        """Return the model-free regression on the records (computed once, for every check)."""
        return regression_evidence(self.records, self.torque_constant)

    @property
    def checkable(self) -> bool:
        """Whether the fit is checked against model-free evidence (free initial states)."""
        return self.initial_state == 'estimate' and isinstance(self.estimator, RefinedEstimator)


@dataclass(frozen=True)
class Models:
    """
    A fit's model on its records, built once for every stage that measures or scores the fit.

    ``measured``: the model whose simulation errors the stages report (current and speed);
    ``compared``: the model on the run's criterion, which the start check scores.  Each is
    built when first asked for.  ``terms``: the effect terms of a structure (none: the base
    model).
    """

    records: Sequence[Record]
    torque_constant: float | None
    quasi_static: bool = False
    criterion: str = 'speed'
    terms: tuple = ()

    @cached_property
    def measured(self) -> OutputErrorModel:
        """Return the model on the current and speed."""
        return OutputErrorModel(self.records, self.torque_constant, self.terms,
                                self.quasi_static)

    @cached_property
    def compared(self) -> OutputErrorModel:
        """Return the model on the run's criterion."""
        return OutputErrorModel(self.records, self.torque_constant, self.terms,
                                self.quasi_static, self.criterion)


@dataclass(frozen=True)
class Fit:
    """
    The base fit on all data and what the stages up to discovery made of it.

    ``estimate``: the base fit (replaced by the quasi-static refit, a further start or the
    second start); ``errors``: its simulation errors (``models.measured``'s); ``models``: the
    base model on the records (quasi-static when ``quasi``); ``found``: the discovery loop's
    result, if it ran; ``simulation``: the base fit's simulation over the records as the base
    fit stage ran it, for the later stages that measure the same fit (each takes it when it
    is of the model, values and initial states it measures,
    :meth:`~dcmotor_id.identification.error_model.residuals.Simulation.is_of`, else
    simulates).
    """

    estimate: Estimate
    errors: ChannelErrors
    models: Models
    warnings: tuple[str, ...] = ()
    not_identifiable: dict[str, str] = field(default_factory=dict)
    quasi: bool = False  # the quasi-static armature (La -> 0) is the model
    full_la: tuple[float, float, float] | None = None  # La, its stderr, Ra of the full fit
    structure_spread: dict[str, float] | None = None  # full - quasi-static, per parameter
    full_stderr: dict[str, float] | None = None  # the full fit's, under the quasi-static
    starts: dict[str, Any] | None = None  # the further starts of the base fit
    start_check: dict[str, Any] | None = None
    found: DiscoveryResult | None = None
    discovery_info: dict[str, Any] | None = None
    simulation: Simulation | None = None


@dataclass(frozen=True)
class Answer:
    """The reported fit and what is said of it, stage by stage."""

    final: Estimate
    terms: Sequence
    fitted_records: list[Record]
    warnings: tuple[str, ...]
    not_identifiable: dict[str, str]
    names: tuple[str, ...] = ()
    parameters: dict[str, float] = field(default_factory=dict)
    stderr: dict[str, float] = field(default_factory=dict)
    stderr_model: dict[str, float] = field(default_factory=dict)
    upper_bounds: dict[str, float] = field(default_factory=dict)
    combined: dict[str, Any] = field(default_factory=dict)
    bound: dict[str, str] = field(default_factory=dict)
    errors_detail: dict[str, Any] = field(default_factory=dict)
    simulation: Simulation | None = None  # the final fit over its records (stage 7's)
