"""Rules ``blocked-cv`` and ``blocked-cv-white``: every block of the records held out in turn."""

import numpy as np
import pytest

from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery import discover
from dcmotor_id.identification.discovery.crossval import fold_edges, FOLDS, training_pieces
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.simulation import simulate_motor_effects
from dcmotor_id.simulation.excitation import add_sensor_noise

#: The motor of ``test_discovery_whole_record.py`` (a draw of ``bench/bench_discovery.py``).
MOTOR = MotorParameters(Ra=2.01, La=0.016, CPhi=0.82, J=0.0298, b=0.244, Mc=0.97)
DT = 1e-3


def early_records(cogging, seed=0):
    """
    Return a record whose first 40 % turns slowly both ways and whose rest runs fast.

    6 V at 0.5 Hz for 2.4 s (the shaft below 2.6 rad/s), then 60 V with a 10 V, 0.9 Hz
    ripple (25-48 rad/s); current and speed with 1 % noise.  With ``cogging`` (0.1 N m, 8 per
    revolution) the ripple's torque moves the slow shaft and is filtered out at 40-60 Hz on
    the fast one: the loop's held-out end (the fast part) hardly shows it.
    """
    t = np.arange(6000) * DT
    slow = t < 2.4
    voltage = np.where(slow, 6.0 * np.sin(2 * np.pi * 0.5 * t),
                       60.0 + 10.0 * np.sin(2 * np.pi * 0.9 * (t - 2.4)))
    effects = [make_effect('cogging', amplitude_Nm=0.1, cycles_per_rev=8.0)] if cogging else []
    current, speed, _ = simulate_motor_effects(MOTOR, voltage, DT, effects)
    rng = np.random.default_rng(seed)
    return [Record(t, add_sensor_noise(current, 0.01, rng), voltage,
                   add_sensor_noise(speed, 0.01, rng), source='early')]


def added(result):
    """Return the names of the effects a loop added, in order."""
    return [step['added']['name'] for step in result.steps if step.get('added')]


def test_a_cogging_excited_only_early_is_found_by_blocked_cross_validation():
    cogged = early_records(True)
    default = discover(cogged)  # whole-record-white: judged on the held-out end
    assert added(default) == []
    cogging = [candidate for step in default.steps for candidate in step['candidates']
               if candidate['name'] == 'cogging' and candidate['refitted']]
    assert cogging and 'is not significant' in cogging[0]['rejected']
    assert cogging[0]['heldout_gain_pct'] < 1.0  # the fast held-out end hardly shows it
    result = discover(cogged, acceptance='blocked-cv-white')
    assert added(result) == ['cogging']
    step = result.steps[0]
    assert step['added']['parameters']['cycles_per_rev'] == 8.0
    evidence = step['cross_validation']
    assert evidence['folds'] == FOLDS and evidence['t'] > evidence['t_needed'] >= 3.0
    # Refitted on all the data, the ripple is the true one within 20 %.
    amplitude = np.hypot(result.estimate.parameters['cogging.sin_Nm'],
                         result.estimate.parameters['cogging.cos_Nm'])
    assert amplitude == pytest.approx(0.1, rel=0.2)


@pytest.mark.parametrize('rule', ['blocked-cv-white', 'blocked-cv'])
def test_the_same_record_clean_gets_no_effect_by_blocked_cross_validation(rule):
    assert added(discover(early_records(False), acceptance=rule)) == []


def test_every_sample_is_held_out_once_and_the_training_pieces_keep_the_gap():
    blocks = fold_edges(1003)
    assert len(blocks) == FOLDS and blocks[0][0] == 0 and blocks[-1][1] == 1003
    assert all(first == last for (_, first), (last, _) in zip(blocks[:-1], blocks[1:]))
    assert training_pieces(1003, blocks[2], 7) == [(0, blocks[2][0] - 7),
                                                   (blocks[2][1] + 7, 1003)]
    assert training_pieces(1003, blocks[0], 7) == [(blocks[0][1] + 7, 1003)]
