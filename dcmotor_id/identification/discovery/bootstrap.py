"""
A candidate's Diebold-Mariano t when the current structure is the truth: a parametric bootstrap.

With a noisy input current (errors in variables) the output-error fit of the position is
biased by the noise the shaft integrates, and a candidate that absorbs that drift predicts the
held-out position better although the motor lacks it: the null of equal predictive accuracy
is false for the fits, so no test of it alone has the right size there.  The bootstrap
replicates that mechanism under the current structure: the current fit simulated from the
logged current (the replica's true input), the logged input given fresh noise of the current's
noise level and the position the position's noise; both structures refitted on each replica
from the fits' values; the Diebold-Mariano t of each replica
(:func:`~dcmotor_id.identification.discovery.judging.innovation_dm`) is what chance and the
fit's bias give.  A candidate's t must lie beyond their prediction bound at the loop's size
(:func:`~dcmotor_id.identification.discovery.judging.unearned_dm`).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Fit

#: A test statistic of a candidate against the current fit: ``(t, degrees of freedom)``.
Statistic = Callable[[LoopState, Fit, Fit], tuple[float, Any]]
#: Replicas of the null (the current structure with the input's noise).
REPLICAS = 19
#: Fewest replicas refitted for a judgement (else the bootstrap says nothing).
MIN_REPLICAS = 5
#: Seed of the replicas' noise (the judgement of a record is repeatable).
SEED = 20260


def null_t(loop: LoopState, current: Fit, fitted: Fit, replicas: int = REPLICAS,
           statistic: Statistic | None = None) -> list[float]:
    """
    Return the t of ``fitted``'s structure on replicas of ``current``'s.

    ``statistic``: ``(loop, current fit, candidate fit) -> (t, degrees of freedom)``, the
    Diebold-Mariano t of :func:`~dcmotor_id.identification.discovery.judging.innovation_dm`
    by default.  Only for a mechanical-only loop on records whose position the current fit
    simulates (else an empty list); a replica whose refit fails is left out.
    """
    from dcmotor_id.identification.discovery.judging import innovation_dm
    from dcmotor_id.identification.discovery.refitting import _try_from, base_start

    test = statistic or innovation_dm
    rng = np.random.default_rng(SEED)
    out: list[float] = []
    for _ in range(replicas if loop.torque_constant is not None else 0):
        records = replica_records(loop, current, rng)
        if records is None:
            return []
        replica = replace(loop, records=records, anchor=None)
        start = base_start(loop, current)
        base = _try_from(replica, current.structure, start, dict(current.values), None)
        refit = _try_from(replica, fitted.structure, start, dict(fitted.values), None)
        if base is not None and refit is not None:
            out.append(float(test(replica, base, refit)[0]))
    return out


def replica_records(loop: LoopState, current: Fit,
                    rng: np.random.Generator) -> list[Record] | None:
    """Return one replica of the records under the current fit (None if it cannot be made)."""
    from dcmotor_id.identification.error_model.criterion import noise_level
    from dcmotor_id.identification.prepare import prepare_records

    if not loop.records or len(loop.records) != len(current.simulated):
        return None
    records = []
    for rec, simulated in zip(loop.records, current.simulated):
        position = simulated.get('position')
        if (rec.current is None or rec.position is None or position is None
                or position.shape != rec.position.shape):
            return None
        n = rec.time_s.shape[0]
        logged = rec.current + rng.normal(0.0, noise_level(rec.current), n)
        records.append(Record(rec.time_s, logged, None, None,
                              position + rng.normal(0.0, noise_level(rec.position), n),
                              source=rec.source))
    try:
        return prepare_records(records, torque_constant=loop.torque_constant)
    except DcMotorIdError:
        return None
