"""Stage 12: the result, the JSON contract's values and the objects behind them."""

from __future__ import annotations

from dcmotor_id.core.model import UNITS
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs
from dcmotor_id.identification.result import IdentificationResult
from dcmotor_id.identification.validate import operating_range


def result(inputs: Inputs, fit: Fit, answer: Answer) -> IdentificationResult:
    """Return the :class:`~dcmotor_id.identification.result.IdentificationResult` of a run."""
    found, final, records = fit.found, answer.final, inputs.records
    return IdentificationResult(
        parameters=answer.parameters,
        stderr=answer.stderr,
        method=final.method,
        effects=found.effects_json() if found is not None else [],
        error_before=found.error_before if found is not None else fit.errors,
        error_after=found.error_after if found is not None else dict(fit.errors),
        unexplained=bool(found.unexplained) if found is not None else False,
        mode='mechanical' if inputs.mechanical_only else 'full',
        torque_constant=inputs.torque_constant,
        initial_states=[list(state) for state in final.initial_states],
        noise_std=final.info.get('noise_std', {}),
        sample_period_s=records[0].sample_period_s,
        n_samples=int(sum(len(rec) for rec in records)),
        sources=[rec.source for rec in records],
        units={name: UNITS[name] for name in answer.names},
        discover=bool(inputs.discover),
        discovery=fit.discovery_info,
        stderr_model=answer.stderr_model,
        uncertainty_method=final.info.get('uncertainty_method',
                                          f"the {final.method} estimator's own"),
        not_identifiable=answer.not_identifiable,
        warnings=list(answer.warnings),
        errors=answer.errors_detail,
        combined=answer.combined,
        upper_bounds=answer.upper_bounds,
        initial_state=inputs.initial_state,
        elapsed_s=inputs.progress.elapsed(),
        start_check=fit.start_check,
        operating_range=operating_range(records),
        estimate=final,
        input_records=list(records),
        discovery_result=found,
        criterion=inputs.criterion,
        between_records=final.info.get('between_records'),
        evidence=inputs.evidence if inputs.criterion != 'speed' else None,  # the position's
    )
