"""What the loop found (:class:`DiscoveryResult`) and its errors on other records."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence, TYPE_CHECKING

from dcmotor_id.identification.discovery.refitting import refit_all_data, refit_start
from dcmotor_id.identification.discovery.structure import Fit, Structure
from dcmotor_id.identification.error_model.residuals import ChannelErrors, model_errors
from dcmotor_id.identification.estimators.refined import OutputErrorModel

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.base import Estimate


@dataclass(eq=False)
class DiscoveryResult:
    """
    What the loop found, with everything the report plots (plain data, built by the loop).

    Attributes
    ----------
    holdout_fraction, min_gain : float
        The loop's settings.
    outputs : tuple of str
        The simulated channels.
    torque_constant : float or None
        Mechanical-only mode.
    source_records : list of Record
        The records the loop ran on.
    base, final : Fit
        Base and final structure fitted on the training parts.
    steps : list of dict
        One report per search round (candidates scored, effect added, errors).
    analysis_before, analysis_after : dict
        Held-out residual analyses of the base and the final model.
    reason : str
        Why the loop stopped.
    unexplained : bool
        Structure that matters remains in the final residual.
    records, terms, estimate :
        The final structure refitted on all the data.
    effects : list of Effect
        The effects found, with the all-data values.
    base_estimate : Estimate
        The base structure refitted on all the data.
    error_before, error_after : dict
        Held-out simulation error of the base and the final model.
    out_of_time : bool
        The time budget ran out: the structure is the best so far and, when there was no
        time for the all-data refit, ``estimate`` is the training-part fit.
    quasi_static : bool
        The quasi-static armature (La -> 0) was fitted.

    """

    holdout_fraction: float
    min_gain: float
    outputs: tuple
    torque_constant: float | None
    source_records: list
    base: Fit
    final: Fit
    steps: list
    analysis_before: dict
    analysis_after: dict
    reason: str
    unexplained: bool
    records: list
    terms: tuple
    estimate: Estimate
    effects: list
    base_estimate: Estimate
    error_before: ChannelErrors
    error_after: ChannelErrors
    out_of_time: bool = False
    quasi_static: bool = False
    criterion: str = 'speed'

    def errors_on(self, records: Sequence[Record]) -> dict[str, ChannelErrors]:
        """
        Simulate the all-data base and final models on other records; return their errors.

        Each record is simulated from its first measured sample (speed, and current in the
        full mode) with the measured input; data effects (delays) are applied first.

        Returns
        -------
        dict
            ``before`` and ``after``, each ``{current_nrmse_pct, speed_nrmse_pct}``.

        """
        tc = self.torque_constant
        return {'before': structure_errors(Structure(), self.base_estimate, records, tc),
                'after': structure_errors(self.final.structure, self.estimate, records, tc)}

    def effects_json(self) -> list[dict]:
        """``[{"name", "parameters"}]`` in the order added, with the all-data values."""
        return [effect.describe(self.estimate.parameters) for effect in self.effects]

    def evidence(self) -> dict[str, dict[str, Any]]:
        """Summary of the final residual analysis (JSON-ready)."""
        out = {}
        for channel, item in self.analysis_after.items():
            out[channel] = {
                'ljung_box_statistic': item['ljung_box']['statistic'],
                'ljung_box_p_value': item['ljung_box']['p_value'],
                'lags': item['ljung_box']['lags'],
                'predictable_fraction': item['predictable_fraction'],
                'acf_outside_band': item['acf_outside_band'],
                'input_correlation': {name: value['max_abs']
                                      for name, value in item['inputs'].items()},
                'nrmse_pct': item['nrmse_pct'],
            }
        return out

    def summary(self) -> dict[str, Any]:
        """JSON-ready account of the loop."""
        return {
            'holdout_fraction': self.holdout_fraction,
            'min_gain_pct': self.min_gain * 100.0,
            'reason': self.reason,
            'base_heldout_parameters': {key: float(value) for key, value in
                                        self.base.values.items()},
            'steps': self.steps,
            'evidence_before': _evidence(self.analysis_before),
            'evidence_after': self.evidence(),
        }


def errors_by_step(found: DiscoveryResult, records: Sequence[Record]) -> list[dict[str, Any]]:
    """
    Errors on other records after each effect added (all-data refits), in order.

    The base and the final structure are the result's all-data fits; every structure in
    between is refitted here on the loop's records.

    Returns
    -------
    list of dict
        ``{'effects': [names], current_nrmse_pct, speed_nrmse_pct}``, the base model
        first.

    """
    items = found.final.structure.items
    tc = found.torque_constant
    out = []
    for count in range(len(items) + 1):
        structure = Structure(items[:count])
        if count == 0:
            estimate = found.base_estimate
        elif count == len(items):
            estimate = found.estimate
        else:
            estimate = refit_all_data(
                structure, found.source_records, tc, found.estimate.parameters,
                refit_start(found.final.values, found.source_records, tc),
                quasi_static=found.quasi_static, criterion=found.criterion)[2]
        errors = structure_errors(structure, estimate, records, tc)
        out.append({'effects': structure.names(), **errors})
    return out


def structure_errors(structure: Structure, estimate: Estimate, records: Sequence[Record],
                     torque_constant: float | None = None) -> ChannelErrors:
    """
    Simulate a fitted structure on records, each from its first sample; return the errors.

    Returns
    -------
    dict
        ``{current_nrmse_pct, speed_nrmse_pct}`` (current None in mechanical-only mode).

    """
    prepared = structure.transformed(records)
    values = estimate.parameters
    terms = structure.terms(prepared, values, torque_constant, values)
    model = OutputErrorModel(prepared, torque_constant, terms,
                             bool(estimate.info.get('quasi_static')))
    states = [[float(getattr(rec, channel)[0]) for channel in model.outputs]
              for rec in prepared]
    return model_errors(model, values, states)


def _evidence(analysis):
    return {channel: {'ljung_box_p_value': item['ljung_box']['p_value'],
                      'predictable_fraction': item['predictable_fraction'],
                      'nrmse_pct': item['nrmse_pct']}
            for channel, item in analysis.items()}
