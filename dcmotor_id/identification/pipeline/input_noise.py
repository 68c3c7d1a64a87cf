"""
Stage 10b: standard errors that cover the measured current's noise when it explains the misfit.

In mechanical mode the measured current drives the model.  When its own white noise, run
through the model, is the speed misfit
(:func:`~dcmotor_id.identification.checks.identifiability.input_noise_misfit`, the check
behind the input-noise warning), the output-error standard errors miss the noise of the
input: they treat the current as exact.  On the HSM150 servo's single records they were 4-6
times too small (``bench/hsm150_singles_results.md``).  A parametric bootstrap of the input
then measures it: :data:`REFITS` refits from the final fit, each on the records with white
noise of the current's own estimated level added to the current
(:func:`~dcmotor_id.signals.filters.noise_std`), and each parameter's standard error becomes
the larger of the stated one and the refits' spread (the spread of a fit to the noise added
is the spread the recorded noise gives).  Only then: every other result is unchanged.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.identification.checks.identifiability import input_noise_misfit
from dcmotor_id.identification.error_model.residuals import output_channels
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.identification.pipeline.fit_warnings import final_rms
from dcmotor_id.identification.pipeline.state import Answer, Fit, Inputs
from dcmotor_id.signals.filters import noise_std

#: Refits of the parametric bootstrap of the current's noise.
REFITS = 8
#: Least refits whose spread is used (fewer: the stated standard errors stay).
MIN_REFITS = 4
#: Seed of the noise added (the same record gives the same standard errors).
SEED = 20260
#: What the account of the standard errors says when the bootstrap ran.
METHOD = ("; at least the spread of {n} refits with white noise of the current's own level "
          '({sigma} A) added to the current (the speed misfit is that noise: '
          'parametric bootstrap of the input)')


def input_noise_stderr(inputs: Inputs, fit: Fit, answer: Answer) -> Answer:
    """
    Return the answer with standard errors that cover the current's noise, when it fires.

    Unchanged unless the mode is mechanical and the speed misfit is the current's own
    noise; then each parameter's standard error is the larger of the stated one and the
    spread of :func:`resampled_spread`.
    """
    if not inputs.mechanical_only or inputs.torque_constant is None:
        return answer
    outputs = output_channels(True)
    records = answer.fitted_records
    rms = final_rms(answer, outputs)
    if input_noise_misfit(answer.final, records, outputs, rms, inputs.torque_constant) is None:
        return answer
    spread, draws = resampled_spread(inputs, fit, answer)
    if draws < MIN_REFITS:
        return answer
    stderr = dict(answer.stderr)
    for name, value in spread.items():
        if name in stderr and np.isfinite(value) and not value <= stderr[name]:
            stderr[name] = float(value)
    sigma = float(np.sqrt(np.mean([noise_std(_current(rec)) ** 2 for rec in records])))
    info = dict(answer.final.info)
    info['uncertainty_method'] = str(info.get(
        'uncertainty_method', f"the {answer.final.method} estimator's own")) + METHOD.format(
        n=draws, sigma=f'{sigma:.3g}')
    info['input_noise_spread'] = {'refits': draws, 'current_noise_A': sigma, **spread}
    return replace(answer, stderr=stderr, final=replace(answer.final, info=info))


def resampled_spread(inputs: Inputs, fit: Fit, answer: Answer) -> tuple[dict[str, float], int]:
    """
    Return each parameter's spread over refits with the current's noise added, and their number.

    Up to :data:`REFITS` refits from the final fit (its parameters and initial states, its
    effect terms), each on the records with white noise of each record's own current noise
    level added; refits that fail are not counted, and no refit starts that would end past the
    time budget (twice the longest so far).
    """
    rng = np.random.default_rng(SEED)
    final, records = answer.final, answer.fitted_records
    estimator = RefinedEstimator(
        initial={name: float(final.parameters[name]) for name in answer.names
                 if name in final.parameters},
        quasi_static=fit.quasi, initial_state=inputs.initial_state,
        initial_states=final.initial_states)
    drawn: list[dict[str, Any]] = []
    took = 0.0
    for refit in range(REFITS):
        if inputs.progress.remaining() < 2.0 * took:
            break  # the next refit would end past the time budget
        inputs.progress.set_stage(f'current-noise refit {refit + 1} of {REFITS}')
        started = inputs.progress.now()
        noisy = [rec.replace(current=_current(rec)
                             + rng.normal(0.0, noise_std(_current(rec)), len(rec)))
                 for rec in records]
        try:
            drawn.append(estimator.fit(noisy, inputs.torque_constant, answer.terms).parameters)
        except (FitError, np.linalg.LinAlgError, FloatingPointError):
            pass
        took = max(took, inputs.progress.now() - started)
    if len(drawn) < 2:
        return {}, len(drawn)
    return ({name: float(np.std([draw[name] for draw in drawn], ddof=1))
             for name in answer.names if all(name in draw for draw in drawn)}, len(drawn))


def _current(record: Any) -> np.ndarray:
    """Return a record's measured current as floats (mechanical mode: always measured)."""
    return np.asarray(record.current, dtype=float)
