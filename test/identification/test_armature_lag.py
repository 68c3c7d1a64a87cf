"""The current's profile over La/Ra on the raw samples (checks/armature_lag.py)."""

import numpy as np

from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.armature_lag import _lagged, lag_profile
from dcmotor_id.simulation.lab_scenarios import simulate_drive


def _prbs_record(motor, dt, seed=0, samples=3000):
    rng = np.random.default_rng(seed)
    command = np.repeat(rng.choice([-6.0, 6.0], samples // 40 + 1), 40)[:samples]
    out = simulate_drive(motor, command, dt)
    current = out['current'] + rng.normal(0.0, 0.005 * 12.0 / motor.Ra, samples)
    speed = out['speed'] + rng.normal(0.0, 0.005 * 12.0 / motor.CPhi, samples)
    return Record(np.arange(samples) * dt, current=current, voltage=command, speed=speed,
                  source='prbs')


def test_a_time_constant_of_a_few_samples_is_kept_and_one_far_slower_is_rejected():
    dt = 1e-3
    motor = MotorParameters(Ra=2.0, La=6e-3, CPhi=0.05, J=2e-4, b=1e-5, Mc=0.01)
    tau = motor.La / motor.Ra  # three samples
    record = _prbs_record(motor, dt)
    mask = [np.zeros(len(record), dtype=bool)]
    kept = lag_profile([record], mask, tau)
    assert kept is not None and not kept.claimed_too_slow
    assert kept.upper_s > tau
    slow = lag_profile([record], mask, 10.0 * tau)
    assert slow is not None and slow.claimed_too_slow
    assert tau < slow.upper_s < 10.0 * tau


def test_an_armature_settled_within_a_sample_rejects_a_time_constant_of_many():
    dt = 0.02
    motor = MotorParameters(Ra=0.5, La=1.5e-3, CPhi=0.006, J=5e-7, b=1.5e-5, Mc=8e-3)
    record = _prbs_record(motor, dt, samples=600)
    mask = [np.zeros(len(record), dtype=bool)]
    assert lag_profile([record], mask, 20.0 * dt).claimed_too_slow
    assert not lag_profile([record], mask, motor.La / motor.Ra).claimed_too_slow


def test_the_blocked_recursion_is_the_first_order_filter():
    rng = np.random.default_rng(1)
    signal = rng.normal(size=500)
    for a in (0.0, np.exp(-16.0), 0.5, 0.999):  # blocks of 37 samples to one block
        expected = np.zeros(500)
        for k in range(499):
            expected[k + 1] = a * expected[k] + signal[k]
        np.testing.assert_allclose(_lagged(signal, a), expected, rtol=1e-9, atol=1e-12)
