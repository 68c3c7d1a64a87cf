"""
The result of :func:`~dcmotor_id.identification.identify.identify` and its JSON layout.

:class:`IdentificationResult` holds the values of the CLI's and the node's JSON contract
(:meth:`~IdentificationResult.as_dict`) plus the objects behind them (the final estimate, the
records, the discovery loop's result) for callers that go further (the report, studies).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, TYPE_CHECKING

from dcmotor_id.identification.validate import model_block

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.error_model.residuals import ChannelErrors
    from dcmotor_id.identification.estimators.base import Estimate


@dataclass
class IdentificationResult:
    """
    The result of an identification: the JSON contract's values plus the objects behind them.

    Returned by :func:`~dcmotor_id.identification.identify.identify`.

    The fields up to ``upper_bounds`` are the JSON layout (:meth:`as_dict`, the ``--json``
    file and the node's result); ``sources`` is written as ``records``.  The remaining fields
    are for callers that go further (the report, studies): the final :class:`Estimate`, the
    records identified and the discovery loop's result.

    Attributes
    ----------
    parameters, stderr : dict
        Final values and their standard errors, by name.  ``stderr`` is the larger of the
        model-based (Gauss-Newton) and the data-based figure (``uncertainty_method``), with
        the part from the choice of structure added when ``structure_uncertainty`` says so;
        NaN (JSON null) for a parameter at its bound or given as an upper bound.
    method : str
        Estimator name.
    effects : list of dict
        Effects found, in the order added, each ``{"name", "parameters"}``.
    error_before, error_after : dict
        Simulation error (``{current,speed}_nrmse_pct``) of the base and the final model on
        the held-out data, in percent of the spread of all records joined; in-sample when the
        loop did not run.  ``errors`` has the per-record figures.
    unexplained : bool
        Structure that matters remains that no candidate effect explains.
    mode : str
        ``full`` or ``mechanical``.
    torque_constant : float or None
        Given for the mechanical-only mode.
    initial_states : list of list of float
        Initial state of every record.
    noise_std : dict
        Noise level per channel as the estimator saw it.
    sample_period_s : float
        Sample period.
    n_samples : int
        Samples over all records.
    sources : list of str or None
        Source of every record (the JSON key ``records``).
    units : dict
        Unit of every parameter.
    discover : bool
        Whether discovery was asked for.
    discovery : dict or None
        The loop's JSON account, or ``{"skipped": reason}``, or None when not asked for.
    stderr_model : dict
        The Gauss-Newton standard errors (white residual, exact model assumed).
    uncertainty_method : str
        How ``stderr`` was obtained.
    not_identifiable : dict
        Parameter (or effect) -> why the data do not determine it.
    warnings : list of str
        What the user must know to trust the numbers.
    errors : dict
        Per-record simulation errors
        (:func:`~dcmotor_id.identification.pipeline.heldout.record_errors`).
    combined : dict
        Combinations reported instead of their parts, e.g. ``friction_torque_Nm``
        (``{"value", "stderr", "direction", "of"}``) on one-direction data.
    upper_bounds : dict
        Parameters given as an upper bound (``La``, ``Ta`` when the electrical time constant
        is below the sample period); ``parameters`` holds the bound.
    initial_state : str
        ``estimate`` or ``measured``.
    elapsed_s : float
        Run time.
    operating_range : dict
        Speed and current ranges and directions of the records
        (:func:`~dcmotor_id.identification.validate.operating_range`; copied into ``model``
        for ``validate``).
    start_check : dict or None
        The fit checked against model-free evidence
        (:mod:`~dcmotor_id.identification.checks.start`): ``evidence``
        (the regression's values), ``doubts``, and when doubted ``second_start``, ``bic``,
        ``effective_samples`` (the samples the BIC counts) and ``chosen``; None when not
        checked (pinned initial states, other estimators).
    estimate : Estimate
        The final estimate (all data).
    input_records : list of Record
        The records identified (as given, before any data effect).
    discovery_result : DiscoveryResult or None
        The loop's result, when it ran.
    criterion : str
        The channels the fit compared: ``speed``, ``position`` or ``both``
        (:mod:`dcmotor_id.identification.error_model.criterion`).
    structure_uncertainty : dict or None
        The noise bootstrap over the structure choice
        (:mod:`~dcmotor_id.identification.structure_uncertainty`; its part is in ``stderr``),
        ``{"skipped": reason}``, or None when not asked for.
    position_error : dict or None
        The position error's model of a fit on the position
        (:mod:`~dcmotor_id.identification.pipeline.position_error`): ``model`` (``white`` or
        ``adaptive``), ``evidence`` (the regression's J, b, Mc), ``agreement_factor``,
        ``disagreement`` (each model's largest factor from the evidence; None: a parameter
        at zero), ``alternative`` (the other model's J, b, Mc when both ran); None when the
        position is not compared.
    evidence : dict or None
        The model-free regression on the records
        (:func:`~dcmotor_id.identification.checks.start.regression_evidence`) as the run
        computed it for its checks (once), for the position error's choice; not in the JSON
        (its values are in ``start_check`` and ``position_error``).  None when the run did not
        compute it.
    between_records : dict or None
        With several records, the record-level (cluster) standard errors that cover a
        difference between the records
        (:func:`~dcmotor_id.identification.estimators.uncertainty.between_records`):
        ``records``, ``dof``, ``estimator``, ``stderr_within``, ``stderr_records``,
        ``dominant``, ``t_95`` and ``interval_95`` (Student t with ``dof`` degrees of freedom
        where the record-level figure sets ``stderr``), ``note``; None for one record.

    """

    parameters: dict[str, float]
    stderr: dict[str, float]
    method: str
    effects: list[dict[str, Any]]
    error_before: ChannelErrors
    error_after: ChannelErrors
    unexplained: bool
    mode: str
    torque_constant: float | None
    initial_states: list[list[float]]
    noise_std: dict[str, float]
    sample_period_s: float
    n_samples: int
    sources: list[str | None]
    units: dict[str, str]
    discover: bool
    discovery: dict[str, Any] | None
    stderr_model: dict[str, float] = field(default_factory=dict)
    uncertainty_method: str = ''
    not_identifiable: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    errors: dict[str, Any] = field(default_factory=dict)
    combined: dict[str, Any] = field(default_factory=dict)
    upper_bounds: dict[str, float] = field(default_factory=dict)
    initial_state: str = 'estimate'
    elapsed_s: float = 0.0
    start_check: dict[str, Any] | None = None
    operating_range: dict[str, Any] = field(default_factory=dict)
    estimate: Estimate | None = field(repr=False, default=None)
    input_records: list[Record] = field(repr=False, default_factory=list)
    discovery_result: DiscoveryResult | None = field(repr=False, default=None)
    criterion: str = 'speed'
    structure_uncertainty: dict[str, Any] | None = None
    position_error: dict[str, Any] | None = None
    between_records: dict[str, Any] | None = None
    evidence: dict[str, float] | None = field(repr=False, default=None)

    def as_dict(self) -> dict[str, Any]:
        """Return the JSON layout of the CLI and node contract (a new dict)."""
        out = {
            'parameters': self.parameters,
            'stderr': self.stderr,
            'method': self.method,
            'effects': self.effects,
            'error_before': self.error_before,
            'error_after': self.error_after,
            'unexplained': self.unexplained,
            'mode': self.mode,
            'torque_constant': self.torque_constant,
            'initial_states': self.initial_states,
            'noise_std': self.noise_std,
            'sample_period_s': self.sample_period_s,
            'n_samples': self.n_samples,
            'records': self.sources,
            'units': self.units,
            'discover': self.discover,
            'discovery': self.discovery,
            'stderr_model': self.stderr_model,
            'uncertainty_method': self.uncertainty_method,
            'not_identifiable': self.not_identifiable,
            'warnings': self.warnings,
            'errors': self.errors,
            'combined': self.combined,
            'upper_bounds': self.upper_bounds,
            'initial_state': self.initial_state,
            'elapsed_s': self.elapsed_s,
            'start_check': self.start_check,
            'operating_range': self.operating_range,
            'criterion': self.criterion,
            'structure_uncertainty': self.structure_uncertainty,
            'position_error': self.position_error,
            'between_records': self.between_records,
        }
        out['model'] = model_block(out)  # all that `dcmotor-id validate` needs to simulate
        return out

    def plot(self) -> list[Figure]:
        """
        Return matplotlib figures: measured against simulated channels, and the residual.

        One row per record and channel (at most four records), the model simulated from each
        record's identified initial state (:func:`~dcmotor_id.identification.figures.
        result_figures`); the figures are not shown (``fig.savefig`` or a notebook shows
        them).
        """
        from dcmotor_id.identification.figures import result_figures
        speeds = self.estimate.info.get('simulated_speeds') if self.estimate else None
        return result_figures(self.as_dict(), self.input_records, speeds)

    def design(self, current_bandwidth_hz: float | None = None,
               speed_bandwidth_hz: float | None = None, phase_margin_deg: float = 60.0,
               sample_period_s: float | None = None, gear_ratio: float = 1.0,
               output_shaft: bool = False, gravity_load: bool = False) -> dict[str, Any]:
        """
        Design the controller for this result: what ``dcmotor-id design`` computes.

        The same as :func:`dcmotor_id.design_controller` ``(self, ...)`` (the design floor
        sits above this one: the call goes through the package face's binding,
        :func:`dcmotor_id.core.lazy.bind`).

        Parameters
        ----------
        current_bandwidth_hz, speed_bandwidth_hz, phase_margin_deg, sample_period_s : float
            The request (None: the defaults of ``dcmotor-id design``).
        gear_ratio : float
            Motor speed / output speed.
        output_shaft : bool
            Design on the output shaft.
        gravity_load : bool
            Take the identified load torque as an elevator's gravity (``kG``).

        Returns
        -------
        dict
            The design JSON: ``speed_loop``, ``current_loop`` (full mode), ``feedforward``,
            ``nominal``, ``robustness``, ``notes``.

        Raises
        ------
        dcmotor_id.design.plant.DesignError
            When no controller meets the request (the message says what to ask instead).

        """
        from dcmotor_id.core.lazy import bound
        return bound('design_controller')(
            self, current_bandwidth_hz=current_bandwidth_hz,
            speed_bandwidth_hz=speed_bandwidth_hz, phase_margin_deg=phase_margin_deg,
            sample_period_s=sample_period_s, gear_ratio=gear_ratio, output_shaft=output_shaft,
            gravity_load=gravity_load)

    def _repr_html_(self) -> str:
        """Return the notebook view: the parameters, effects and warnings as HTML."""
        from dcmotor_id.identification.figures import result_html
        return result_html(self.as_dict())
