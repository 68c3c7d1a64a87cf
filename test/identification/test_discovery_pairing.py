"""A delay candidate's held-out part paired with the current fit's by time (issue 29, round 9)."""

import numpy as np
import pytest

from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.judging import (common_instants, heldout_t,
                                                         innovation_t, paired_heldout)
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Fit, Structure

N, STOP, LATE = 3000, 2000, 3


def _fit(records, errors):
    """Return a fit whose simulation is each record's measurement plus ``errors`` (by channel)."""
    simulated = [{channel: getattr(rec, channel) + error[:len(rec)]
                  for channel, error in errors.items()} for rec in records]
    return Fit(Structure(), None, list(records), [STOP], simulated, ())


def _pair(seed=0):
    """
    Return the current fit and a candidate that undid a late speed sensor (its record trimmed).

    The current fit's speed error is white noise plus a ripple of half its level; the
    candidate's, on its record cut by :data:`LATE` samples at the end as
    :class:`~dcmotor_id.identification.effects.SensorDelay` cuts it, is the same noise
    without the ripple, at the same instants.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 1e-3
    record = Record(t, np.sin(t), np.zeros(N), np.cos(t))
    noise = {'current': rng.standard_normal(N), 'speed': rng.standard_normal(N)}
    ripple = 0.5 * np.sqrt(2.0) * np.sin(2 * np.pi * 5.0 * t)
    current = _fit([record], {'current': noise['current'],
                              'speed': noise['speed'] + ripple})
    candidate = _fit([record.slice(0, N - LATE)], noise)
    loop = LoopState([record], weights={'current': 1.0, 'speed': 1.0})
    return loop, current, candidate


def test_common_instants_pair_by_time():
    _, current, candidate = _pair()
    spans = common_instants(current, candidate, 0)
    assert spans == (slice(STOP, N - LATE), slice(STOP, N - LATE))
    before, after = paired_heldout(current, candidate, 'current')
    np.testing.assert_array_equal(before, after)  # the same noise at the same instants


@pytest.mark.parametrize('test', [heldout_t, innovation_t])
def test_a_trimmed_candidate_is_judged_at_the_same_instants(test):
    # Paired by the records' ends, the candidate's held-out noise met the current fit's
    # three samples later: t about 1.4, where the ripple's removal gives about 5.6.
    loop, current, candidate = _pair()
    t, effective = test(loop, current, candidate)
    assert t > 4.0
    assert effective > 900
