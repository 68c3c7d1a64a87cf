"""A costly candidate refit on many records is first tried on an excerpt of them (issue 19)."""

import dataclasses

import pytest

from dcmotor_id.identification.discovery import Candidate, DiscoveryLoop, Structure
from dcmotor_id.identification.discovery import probe, refitting
from dcmotor_id.identification.effects import LoadTorque, SensorDelay, Stribeck
from dcmotor_id.identification.identify import prepare_records
from dcmotor_id.simulation.lab_scenarios import servo_opposite_steps


@pytest.fixture(scope='module')
def fitted():
    """Four servo records (two per direction) and the base model fitted on them."""
    records = []
    for seed in (0, 1):
        scenario = servo_opposite_steps(seed=seed)
        records += prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    loop = DiscoveryLoop(records, scenario.torque_constant, initial_state='measured')
    return loop, refitting.fit_structure(loop, Structure())


def test_the_excerpt_is_evenly_spread_within_the_budget():
    assert probe.excerpt([14_000] * 12, 40_000) == [0, 11]
    assert probe.excerpt([14_000] * 12, 45_000) == [0, 6, 11]
    assert probe.excerpt([14_000] * 2, 40_000) is None  # within the budget: no excerpt
    assert probe.excerpt([300_000], 40_000) is None
    assert probe.excerpt([30_000] * 3, 40_000) is None  # no two records fit
    # At most a quarter of the samples: on four records a look that succeeds would add half
    # the cost of the refit (HSM150 runs of four records: 1.4 s more), so there is none.
    assert probe.excerpt([14_000] * 4, 40_000) is None
    assert probe.excerpt([14_000] * 8, 40_000) == [0, 7]


def _counting(monkeypatch, succeed_on_excerpt):
    """Replace the refit by a recorder of how many records each attempt had."""
    calls = []

    def attempt(loop, structure, start, initial, initial_states):
        calls.append(len(loop.records))
        assert len(initial_states) == len(loop.records)
        return 'fit' if succeed_on_excerpt and len(loop.records) < 4 else None
    monkeypatch.setattr(refitting, '_try_from', attempt)
    return calls


def test_a_costly_refit_failing_on_the_excerpt_is_not_run_on_all_records(fitted, monkeypatch):
    loop, current = fitted
    assert sum(current.stops) > 2 * 20_000
    monkeypatch.setattr(probe, 'PROBE_SAMPLES', 40_000)
    monkeypatch.setattr(probe, 'PROBE_SHARE', 0.75)  # four records: an excerpt of two or three
    calls = _counting(monkeypatch, succeed_on_excerpt=False)
    result = refitting.try_candidate(loop, current, Stribeck, {'velocity_rad_s': 5.0},
                                     {'stribeck.excess_Nm': 0.01})
    assert result is None
    size = len(probe.excerpt(current.stops))
    assert 2 <= size < 4
    assert calls == [size, size]  # both starts on the excerpt, none on all four records


def test_a_refit_that_succeeds_on_the_excerpt_runs_on_all_records(fitted, monkeypatch):
    loop, current = fitted
    monkeypatch.setattr(probe, 'PROBE_SAMPLES', 40_000)
    monkeypatch.setattr(probe, 'PROBE_SHARE', 0.75)  # four records: an excerpt of two or three
    calls = _counting(monkeypatch, succeed_on_excerpt=True)
    refitting.try_candidate(loop, current, Stribeck, {'velocity_rad_s': 5.0},
                            {'stribeck.excess_Nm': 0.01})
    size = len(probe.excerpt(current.stops))
    assert calls == [size, 4, 4]  # the excerpt, then both starts on all records as before


def test_cheap_refits_and_small_data_are_not_cut(fitted, monkeypatch):
    loop, current = fitted
    monkeypatch.setattr(probe, 'PROBE_SAMPLES', 40_000)
    monkeypatch.setattr(probe, 'PROBE_SHARE', 0.75)  # four records: an excerpt of two or three
    calls = _counting(monkeypatch, succeed_on_excerpt=False)
    refitting.try_candidate(loop, current, LoadTorque, {}, {})
    assert calls == [4]  # compiled sensitivities: no excerpt
    monkeypatch.setattr(probe, 'PROBE_SAMPLES', 10 ** 6)
    calls.clear()
    refitting.try_candidate(loop, current, Stribeck, {'velocity_rad_s': 5.0}, {})
    assert calls == [4]


def test_a_delay_screened_negative_is_rejected_without_a_refit(fitted, monkeypatch):
    loop, current = fitted
    calls = _counting(monkeypatch, succeed_on_excerpt=False)
    early = Candidate(SensorDelay, {'channel': 'speed', 'samples': -56}, {}, 0.004)
    judged = refitting.refit_candidate(loop, current, early)
    assert calls == [] and judged.fit is None
    assert 'negative delay (-56 samples)' in judged.problem and 'not refitted' in judged.problem
    late = Candidate(SensorDelay, {'channel': 'speed', 'samples': 3}, {}, 0.004)
    refitting.refit_candidate(loop, current, late)
    assert calls == [4]  # a late sensor is refitted as before


def test_the_loop_state_is_frozen_and_the_base_fit_teaches_a_new_one(fitted):
    loop, base = fitted
    with pytest.raises(dataclasses.FrozenInstanceError):
        loop.weights = {'speed': 1.0}
    # Fitting the base changed nothing of the loop: what it learned is a new state.
    assert loop.weights is None and loop.position_ar is None
    learned = refitting.taught(loop, base)
    assert learned.weights == {channel: max(base.estimate.info['noise_std'][channel], 1e-300)
                               for channel in loop.outputs}
    assert learned.position_ar == base.estimate.info['position_ar']
    assert learned.records == loop.records and learned.weights is not loop.weights
    # A loop that has its weights keeps them.
    assert refitting.taught(learned, base).weights == learned.weights
