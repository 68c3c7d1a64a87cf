"""A delay candidate's held-out residuals paired with the current fit's (issue 29, round 9)."""

import numpy as np
import pytest

from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.judging import (common_instants, heldout_t,
                                                         innovation_t, paired_heldout)
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Fit, Structure
from dcmotor_id.identification.effects import SensorDelay

N, STOP, LATE = 3000, 2000, 3
DELAY = {'channel': 'speed', 'samples': LATE}


def _fit(structure, records, errors):
    """Return a fit whose simulation is each record's measurement plus ``errors``."""
    simulated = [{channel: getattr(rec, channel) + error for channel, error in errors.items()}
                 for rec in records]
    return Fit(structure, None, list(records), [STOP], simulated, ())


def _pair(seed=0):
    """
    Return the loop, the current fit and a candidate that undid a late speed sensor.

    The candidate's record is the current one with the speed sensor's delay undone
    (:class:`~dcmotor_id.identification.effects.SensorDelay`: its speed moved :data:`LATE`
    samples earlier, its last samples cut).  Both fits leave the same noise on every
    measured sample; the current fit's speed error holds a ripple of half its level besides,
    which the candidate removed.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(N) * 1e-3
    record = Record(t, np.sin(t), np.zeros(N), np.cos(t))
    noise = {'current': rng.standard_normal(N), 'speed': rng.standard_normal(N)}
    ripple = 0.5 * np.sqrt(2.0) * np.sin(2 * np.pi * 5.0 * t)
    current = _fit(Structure(), [record], {'current': noise['current'],
                                           'speed': noise['speed'] + ripple})
    candidate = _fit(Structure().plus(SensorDelay, DELAY), SensorDelay.transform([record], DELAY),
                     {'current': noise['current'][:N - LATE], 'speed': noise['speed'][LATE:]})
    loop = LoopState([record], weights={'current': 1.0, 'speed': 1.0})
    return loop, current, candidate


def test_the_delayed_channel_is_paired_by_measurement_the_others_by_instant():
    _, current, candidate = _pair()
    assert common_instants(current, candidate, 0, 'current') == (slice(STOP, N - LATE),) * 2
    assert common_instants(current, candidate, 0, 'speed') == (
        slice(STOP + LATE, N), slice(STOP, N - LATE))
    before, after = paired_heldout(current, candidate, 'current')
    np.testing.assert_array_equal(before, after)  # the same noise on the same samples


@pytest.mark.parametrize('test', [heldout_t, innovation_t])
def test_a_delay_candidate_is_judged_on_the_same_measured_samples(test):
    # Paired by the records' ends the current's samples met the other fit's three samples
    # later, paired by the instant the delayed speed did: t about 1.4 either way, where the
    # ripple's removal gives about 5.6.
    loop, current, candidate = _pair()
    t, effective = test(loop, current, candidate)
    assert t > 4.0
    assert effective > 900
