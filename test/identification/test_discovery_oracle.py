"""The discovery benchmark's oracle: whether a record carries its effect (issue 29, round 9)."""

import os
import sys

import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.state import DEFAULT_ACCEPTANCE
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.simulation import simulate_motor_effects
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, 'bench'))
import discovery_oracle  # noqa: E402, I100  (bench/, beside bench_discovery.py)

DT = 1e-3


def _records(effect, seed=3):
    """Return paper motor 2 under a 60 V sawtooth with ``effect``, current and speed at 1 %."""
    motor = PAPER_MOTORS['paper2']
    rng = np.random.default_rng(seed)
    t, voltage = make_excitation('sawtooth', 6.0, DT, amplitude_v=60.0, seed=seed,
                                 frequency_hz=1.0)
    current, speed, _ = simulate_motor_effects(motor, voltage, DT, [effect])
    return motor, [Record(t, add_sensor_noise(current, 0.01, rng), voltage,
                          add_sensor_noise(speed, 0.01, rng), source='sawtooth')]


def test_the_oracle_shows_a_load_torque_the_record_carries():
    effect = make_effect('load_torque', torque_Nm=0.5)
    motor, records = _records(effect)
    found = discovery_oracle.oracle(records, motor, effect, DEFAULT_ACCEPTANCE)
    assert found['detectable'] and found['t'] > found['t_needed'] and not found['white']
    assert found['lr'] > found['lr_needed'] and found['gain_pct'] > 5.0
    assert discovery_oracle.verdict(found, [], ('load_torque',)) == '(b) screen or refit'
    assert discovery_oracle.verdict(found, ['load_torque'], ('load_torque',)) is None


def test_the_oracle_turns_down_an_effect_far_below_the_noise():
    # A load torque of 1e-4 Mc changes the outputs by far less than their noise: not in
    # the data, in the held-out part or in all of it.
    effect = make_effect('load_torque', torque_Nm=1e-4)
    motor, records = _records(effect)
    found = discovery_oracle.oracle(records, motor, effect, DEFAULT_ACCEPTANCE)
    assert not found['detectable'] and found['part'] < 0.05
    # and the loop does not judge at all: the base's residual is white (held-out part and
    # whole records)
    assert found['white']
    assert discovery_oracle.verdict(found, [], ('load_torque',)) == (
        '(a) below the noise in all the data; (e) the loop stopped: white residual')
    assert discovery_oracle.verdict(found, ['cogging'], ('load_torque',)) == (
        '(a) below the noise in all the data')


def test_the_true_start_of_a_cogging_is_its_sine_and_cosine_coefficients():
    effect = make_effect('cogging', amplitude_Nm=0.2, cycles_per_rev=4.0, phase_rad=0.5)
    inner, coefficients = discovery_oracle.true_start(PAPER_MOTORS['paper2'], effect)
    assert inner == {'cycles_per_rev': 4.0}
    fitted = type(effect).from_fit(coefficients, inner).parameters
    assert np.isclose(fitted['amplitude_Nm'], 0.2) and np.isclose(fitted['phase_rad'], 0.5)
