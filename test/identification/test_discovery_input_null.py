"""An effect's coefficients against the input current's noise (``input-noise-null``, issue 29)."""

from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.input_null import input_noise_doubt
from dcmotor_id.identification.discovery.state import ACCEPTANCE_RULES
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

DT = 1e-3
STEP = 2 * np.pi / 4096


def _records(kind, seed, noise, effects=(), amplitude_v=43.0, **options):
    """Return the EMPS setting on paper motor 2: an encoder's angle, the current its input."""
    from dcmotor_id.identification.prepare import prepare_records
    from dcmotor_id.simulation import held_input, simulate_mechanical_effects, simulate_motor

    motor = PAPER_MOTORS['paper2']
    rng = np.random.default_rng(seed)
    t, voltage = make_excitation(kind, 6.0, DT, amplitude_v=amplitude_v, seed=seed, **options)
    current, _ = simulate_motor(motor, voltage, DT)
    _, angle = simulate_mechanical_effects(motor.J, motor.b, motor.Mc,
                                           motor.CPhi * held_input(current), DT, list(effects))
    return motor, prepare_records([Record(t, add_sensor_noise(current, noise, rng), None, None,
                                          np.round(angle / STEP) * STEP, source=kind)],
                                  torque_constant=motor.CPhi)


def _added(records, motor, rule):
    from dcmotor_id.identification.discovery import discover

    found = discover(records, motor.CPhi, criterion='position', acceptance=rule)
    return [effect.name for effect in found.effects]


def test_the_rule_is_one_of_the_loop_rules():
    assert 'input-noise-null' in ACCEPTANCE_RULES


@pytest.mark.parametrize('seed, false_effect', [(1, 'cogging'), (2, 'stribeck')])
def test_a_clean_record_with_a_noisy_input_gets_no_effect(seed, false_effect):
    # Clean records (no effect) whose logged current carries 0.5 % noise: the default rule
    # adds an effect whose held-out gain is the base's drift taken up; its coefficients are
    # within what the input's noise makes of them, and the rule turns it down.
    motor, records = _records('multisine', seed, 0.005)
    assert _added(records, motor, 'innovation-t-alone') == [false_effect]
    assert _added(records, motor, 'input-noise-null') == []


def test_a_load_torque_stands_out_of_the_input_noise():
    # A load torque of 0.5 Mc with 1 % noise on the input current: found by the rule.
    load = make_effect('load_torque', torque_Nm=0.5 * PAPER_MOTORS['paper2'].Mc)
    motor, records = _records('sine', 11, 0.01, [load], amplitude_v=60.0, frequency_hz=0.5)
    added = _added(records, motor, 'input-noise-null')
    assert added[:1] in (['load_torque'], ['coulomb_asymmetry'])


def test_no_doubt_where_the_current_is_not_an_input():
    # The current-speed loop fits the current, the voltage-speed loop's input is the voltage
    # (its values have no J): no input current's noise to judge against (the held-out test
    # alone decides there, as under the rule innovation-t-alone).
    fitted = SimpleNamespace(values={'J': 1e-3, 'b': 1e-4, 'Mc': 0.01, 'load_torque.Nm': 0.1})
    candidate = SimpleNamespace(name='load_torque', effect=SimpleNamespace(TRANSFORM=False),
                                fitted=fitted)
    assert input_noise_doubt(SimpleNamespace(mechanical_only=False), candidate, 0.00135) is None
    voltage_speed = SimpleNamespace(values={'kA': 0.1, 'kV': -2.0, 'kS': 0.3})
    candidate = SimpleNamespace(name='load_torque', effect=SimpleNamespace(TRANSFORM=False),
                                fitted=voltage_speed)
    assert input_noise_doubt(SimpleNamespace(mechanical_only=True), candidate, 0.00135) is None


def test_the_coefficient_test_has_the_held_out_test_s_size():
    from dcmotor_id.identification.discovery.input_null import ALPHA
    from dcmotor_id.identification.discovery.judging import HELDOUT_ALPHA

    assert ALPHA == HELDOUT_ALPHA
