"""A speed derived from an encoder's position on fast motors at slow rates (issue 29)."""

import numpy as np
import pytest
from support import assert_near_truth

from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.records import Record
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline.floor import ramp_samples
from dcmotor_id.simulation.lab_scenarios import simulate_drive

#: Counts per revolution of the encoder.
COUNTS = 4096


def _encoder_record(motor, command, dt, seed, name):
    """Simulate the drive; log the current (0.5 % noise) and the encoder's angle."""
    rng = np.random.default_rng(seed)
    out = simulate_drive(motor, command, dt)
    stall = float(np.max(np.abs(command))) / motor.Ra
    current = out['current'] + rng.normal(0.0, 0.005 * stall, command.size)
    angle = np.floor(out['angle'] * COUNTS / (2 * np.pi)) * 2 * np.pi / COUNTS
    return Record(np.arange(command.size) * dt, current=current, voltage=command,
                  position=angle, source=name)


def test_a_spin_up_from_rest_read_by_an_encoder_is_no_amplifier_ramp():
    # A step from rest logged from the step on, 5 ms samples, mechanical time constant 23 ms:
    # the derived speed reads the spin-up's first samples smeared (30 rad/s at rest), and the
    # ramp check took that for an amplifier ramp, cut 30 samples and refused the steady rest.
    motor = MotorParameters(Ra=17.55, La=0.0387, CPhi=0.2011, J=5.33e-5, b=4.75e-5,
                            Mc=0.00292)
    record = _encoder_record(motor, np.full(200, 34.29), 0.005, 92, 'spin_up')
    records = prepare_records([record])
    assert not ramp_samples(records)[0].any()
    result = identify(records, discover=False)
    assert not any('did not reach the motor' in text for text in result.warnings)
    assert_near_truth(result.parameters, motor, Ra=0.05, CPhi=0.05, J=0.1)


def test_a_motion_faster_than_the_derived_speed_is_judged_over_the_sample_periods():
    # PRBS switching every 5 ms sample on a motor of mechanical time constant 10 ms: the speed
    # derived with the default low-pass (20 Hz) misses the motion (its simulation error was
    # 99 % and the answer was refused) while the fit on the position is right.
    motor = MotorParameters(Ra=1.068, La=5.91e-5, CPhi=0.05979, J=3.318e-5, b=1.617e-4,
                            Mc=0.02719)
    rng = np.random.default_rng(22)
    command = rng.choice([-21.2, 21.2], 800)
    record = _encoder_record(motor, command, 0.005, 22, 'fast_prbs')
    result = identify(prepare_records([record]), discover=False)
    said = [text for text in result.warnings if 'smoother than the motion' in text]
    assert len(said) == 1 and '--speed-cutoff' in said[0]
    assert_near_truth(result.parameters, motor, Ra=0.05, CPhi=0.05, J=0.1)


def test_an_encoder_angle_wrapped_at_a_turn_gives_the_answer_of_the_unwrapped_one():
    # An absolute encoder (or a continuous joint's angle) reads within one turn.
    motor = MotorParameters(Ra=17.55, La=0.0387, CPhi=0.2011, J=5.33e-5, b=4.75e-5,
                            Mc=0.00292)
    record = _encoder_record(motor, np.full(200, 34.29), 0.005, 92, 'wrapped')
    wrapped = record.replace(position=(record.position + np.pi) % (2 * np.pi) - np.pi)
    found = identify(prepare_records([wrapped]), discover=False)
    expected = identify(prepare_records([record]), discover=False)
    assert found.parameters == pytest.approx(expected.parameters, rel=1e-9)
    said = [text for text in found.warnings if 'wraps at a turn' in text]
    assert len(said) == 1 and 'unwrapped' in said[0]
