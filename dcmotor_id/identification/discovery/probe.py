"""
A quick look before a costly candidate refit: the same refit on an excerpt of the records.

A candidate whose terms the compiled sensitivities do not cover (a Stribeck friction, simulated
on sub-steps) is refitted with finite differences: every evaluation simulates every record once
per parameter.  On many records that is seconds per start (twelve HSM150 records, 168,000
training samples: 6.5 s a start, two starts, both running out of their evaluations).  Such a
refit is first tried on evenly spread records holding at most :data:`PROBE_SAMPLES` training
samples and at most :data:`PROBE_SHARE` of them, from the same starts; when it fails there
from every start, the refit on all of the records is not run (:func:`fails_on_an_excerpt`).
A refit that succeeds on the excerpt is then run on all records exactly as without the look
(the look then cost at most a quarter more), so only refits that fail on the excerpt are
affected; records within the budget are never cut.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Sequence

import numpy as np

from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Fit, Structure
from dcmotor_id.identification.estimators.refined import (has_analytic_sensitivities,
                                                          OutputErrorModel)

#: Training samples beyond which a finite-difference candidate refit is first tried on an
#: excerpt of the records holding at most this many.
PROBE_SAMPLES = 40_000
#: Largest share of the training samples an excerpt holds (a look that succeeds costs little).
PROBE_SHARE = 0.25

#: ``attempt(loop, structure, start, initial, initial_states)``: a Fit, or None when it fails.
Attempt = Callable[..., 'Fit | None']


def needs_differences(loop: LoopState, structure: Structure, values: dict) -> bool:
    """Whether the structure's refit needs finite-difference sensitivities (built on a record)."""
    records = structure.transformed(loop.records[:1])
    terms = structure.terms(records, values, loop.torque_constant)
    model = OutputErrorModel(records, loop.torque_constant, terms, loop.quasi_static,
                             loop.criterion)
    return not has_analytic_sensitivities(model)


def excerpt(stops: Sequence[int], budget: int | None = None) -> list[int] | None:
    """
    Return evenly spread records (indices) whose training parts hold at most ``budget`` samples.

    ``budget`` defaults to :data:`PROBE_SAMPLES`; the excerpt also holds at most
    :data:`PROBE_SHARE` of all the samples.  None when all of them fit the budget (no
    excerpt is needed) or no two records do.
    """
    budget = PROBE_SAMPLES if budget is None else int(budget)
    stops = [int(stop) for stop in stops]
    if sum(stops) <= budget or len(stops) < 2:
        return None
    budget = min(budget, int(PROBE_SHARE * sum(stops)))
    for count in range(len(stops) - 1, 1, -1):
        chosen = sorted({int(index) for index in np.round(np.linspace(0, len(stops) - 1,
                                                                      count))})
        if sum(stops[index] for index in chosen) <= budget:
            return chosen
    return None


def fails_on_an_excerpt(loop: LoopState, current: Fit, structure: Structure, start: dict,
                        initials: Sequence[dict], attempt: Attempt) -> bool:
    """
    Whether a costly refit fails from every start on an excerpt of the records.

    ``initials`` are the refit's starts (the current values with the candidate's terms),
    ``start`` its base start and ``attempt`` the refit (``refitting._try_from``).  False
    when the refit is cheap (compiled sensitivities), the records need no excerpt, or the
    refit succeeds on the excerpt from one of the starts.
    """
    chosen = excerpt(current.stops)
    if chosen is None or not needs_differences(loop, structure, dict(current.values)):
        return False
    probe = replace(loop, records=[loop.records[index] for index in chosen],
                    position_ar=None if loop.position_ar is None else
                    [loop.position_ar[index] for index in chosen])
    states = [current.estimate.initial_states[index] for index in chosen]
    if loop.progress is not None:
        loop.progress.set_stage(f'discovery: {structure.names()[-1]} on '
                                f'{len(chosen)} of {len(loop.records)} records first')
    return all(attempt(probe, structure, dict(start), dict(initial), states) is None
               for initial in initials)
