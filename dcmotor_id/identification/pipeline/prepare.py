"""
Stage 1: held samples restored, coarse channels named, data that do not move refused.

The registered before-fit checks of one record
(:func:`~dcmotor_id.core.checks.registered`, ``before_fit``, ``record``: a record in, a
warning or None out) run here, in their order of registration.

(:mod:`~dcmotor_id.identification.prepare` makes records ready before ``identify``.)  A drive
at an amplifier's current limit takes its own path (:func:`current_limit`,
:mod:`~dcmotor_id.identification.pipeline.current_limited`).
"""

from __future__ import annotations

import numpy as np

from dcmotor_id.core.checks import registered
from dcmotor_id.formats import quality  # noqa: F401 (registers its before-fit record checks)
from dcmotor_id.formats.held import restore_held
from dcmotor_id.identification.checks.identifiability import limited_samples
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.pipeline.state import Inputs, Request, RunOn
from dcmotor_id.identification.prepare import check_excitation


def prepare(request: Request, on: RunOn) -> Inputs:
    """
    Restore held samples, name coarse channels, refuse data without excitation.

    A run the status line names (``on.name``: after the first) is said to start here.
    """
    if on.name:
        request.progress.set_run(on.name)
    # Sensors refreshing slower than the log: fit on their real updates (said in a warning).
    restored, warnings = restore_held(list(request.records))
    for check in registered('before_fit', 'record'):  # e.g. a coarse speed, said
        warnings += [text for text in map(check.run, restored) if text]
    excitation = check_excitation(restored, request.torque_constant is not None)
    return Inputs(restored, request.method, request.torque_constant, request.discover,
                  request.estimator, list(request.vocabulary or VOCABULARY), request.progress,
                  request.initial_state, on, excitation, tuple(warnings))


def current_limit(inputs: Inputs) -> list[np.ndarray] | None:
    """Return the samples at an amplifier's current limit (refined method, full mode), or None."""
    if inputs.mechanical_only or inputs.estimator is not None or inputs.method != 'refined':
        return None
    return limited_samples(inputs.records)
