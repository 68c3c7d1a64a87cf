"""Simulated classes of real recordings (issue 29): servo by PWM with its angle, SysId routine."""

import numpy as np
import pytest

from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline import floor as floor_module
from dcmotor_id.identification.pipeline.segments import idle_samples, split_tests, Tests
from dcmotor_id.simulation import lab_scenarios


def test_hobby_servo_by_pwm_with_its_angle_only_is_identified():
    scenario = lab_scenarios.hobby_servo_pwm_angle()
    result = identify(prepare_records(scenario.records))
    truth = scenario.truth
    assert result.parameters['Ra'] == pytest.approx(truth.Ra, rel=0.05)
    assert result.parameters['CPhi'] == pytest.approx(truth.CPhi, rel=0.05)
    assert result.parameters['J'] == pytest.approx(truth.J, rel=0.1)


@pytest.fixture(scope='module')
def routine():
    scenario, segment = lab_scenarios.sysid_routine()
    return scenario, segment, prepare_records(scenario.records)


def test_sysid_tests_are_found_between_the_braked_stretches(routine):
    scenario, segment, records = routine
    idle = idle_samples(records[0])
    assert idle is not None
    # Every test sample that drives the motor is kept (a ramp's first, at 0 V, may go), and
    # nearly every braked one left out.
    assert not idle[(segment > 0) & (np.asarray(records[0].voltage) != 0.0)].any()
    assert idle[segment == 0].mean() > 0.9
    tests = split_tests(records)
    assert len(tests.records) == 4
    assert [rec.source.split(' [')[0] for rec in tests.records] == ['sysid_routine'] * 4
    assert 'test 3: 16-18.98 s' in tests.note


def test_sysid_routine_is_identified_as_separate_tests(routine):
    scenario, _, records = routine
    result = identify(records)
    truth = scenario.truth
    for name in ('Ra', 'CPhi', 'J'):
        assert result.parameters[name] == pytest.approx(getattr(truth, name), rel=0.05), name
    assert any('fitted as 4 separate records' in text for text in result.warnings)
    assert len(result.sources) == 4


def test_without_the_tests_the_routine_was_refused(routine, monkeypatch):
    scenario, _, records = routine
    monkeypatch.setattr(floor_module, 'split_tests',
                        lambda records: Tests(tuple(records), ''))
    with pytest.raises(Exception, match='does not reproduce'):
        identify(records)


def test_a_record_standing_still_between_steps_is_left_whole():
    scenario = lab_scenarios.voltage_step_from_rest()
    record = prepare_records(scenario.records)[0]
    n = len(record)
    voltage = np.asarray(record.voltage, dtype=float).copy()
    current = np.asarray(record.current, dtype=float).copy()
    voltage[:20], current[:20] = 0.0, 0.0  # a motor at rest before its step
    still = record.replace(voltage=voltage, current=current,
                           speed=np.where(np.arange(n) < 20, 0.0, record.speed))
    assert idle_samples(still) is None
    assert split_tests([still]).note == ''
