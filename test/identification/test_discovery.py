"""The discovery loop on simulated data with an effect present but not declared."""

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery import discover
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.identification.identify import identify
from dcmotor_id.simulation import (simulate_mechanical_effects, simulate_motor,
                                   simulate_motor_effects)
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

MOTOR = PAPER_MOTORS['paper2']
DT = 1e-3
DURATION_S = 6.0
NOISE = 0.005
#: Honest tolerances on the core parameters after the loop (0.5 % noise, 6 s at 1 kHz): about
#: three times the worst error seen over three noise seeds per effect.
TOLERANCE_PCT = {'Ra': 1.0, 'La': 5.0, 'CPhi': 1.0, 'J': 1.0, 'b': 1.0, 'Mc': 3.0}
SINE = {'kind': 'sine'}
#: Effect, true parameters, an excitation that shows it, and the parameter checks
#: (name -> relative tolerance, or None for an exact match).
CASES = {
    'load_torque': ({'torque_Nm': 0.5}, SINE, {'torque_Nm': 0.03}),
    'stribeck': ({'excess_Nm': 0.5, 'velocity_rad_s': 3.0}, {'kind': 'sine', 'amplitude_v': 20},
                 {'excess_Nm': 0.05, 'velocity_rad_s': 0.05}),
    'quadratic_drag': ({'coefficient_Nm_s2': 4e-4}, SINE, {'coefficient_Nm_s2': 0.05}),
    'brush_drop': ({'drop_V': 2.0}, SINE, {'drop_V': 0.03}),
    'current_offset': ({'offset_A': 1.0}, SINE, {'offset_A': 0.02}),
    'sensor_delay': ({'channel': 'speed', 'samples': 3},
                     {'kind': 'prbs', 'frequency_hz': 20, 'amplitude_v': 43},
                     {'channel': None, 'samples': None}),
    'resistance_drift': ({'rate_ohm_per_s': 0.04}, SINE, {'rate_ohm_per_s': 0.02}),
    'cogging': ({'amplitude_Nm': 0.5, 'cycles_per_rev': 6}, {'kind': 'sine', 'amplitude_v': 40},
                {'amplitude_Nm': 0.05, 'cycles_per_rev': None}),
    # in the standard vocabulary since its false-effect rate was measured (none on clean
    # records, bench/discovery_results.md; no more real records with a false effect)
    'viscous_asymmetry': ({'delta_Nm_s': 0.12}, SINE, {'delta_Nm_s': 0.05}),
}


def motor_records(effects=(), excitation=SINE, noise=NOISE, seed=0, extra_torque=None):
    spec = dict(excitation)
    kind = spec.pop('kind')
    t, voltage = make_excitation(kind, DURATION_S, DT, **spec)
    if extra_torque is not None:
        current, speed = simulate_motor(MOTOR, voltage, DT, extra_torque=extra_torque(t))
    else:
        current, speed, _ = simulate_motor_effects(MOTOR, voltage, DT, list(effects))
    rng = np.random.default_rng(seed)
    return [Record(t, add_sensor_noise(current, noise, rng), voltage,
                   add_sensor_noise(speed, noise, rng), source=kind)]


def check_core(parameters):
    for name, tolerance in TOLERANCE_PCT.items():
        truth = getattr(MOTOR, name)
        assert abs(parameters[name] - truth) / truth * 100 < tolerance, (name, parameters[name])


def check_errors_drop(found):
    before, after = found.error_before, found.error_after
    assert sum(after.values()) < 0.9 * sum(before.values())
    for key in ('current_nrmse_pct', 'speed_nrmse_pct'):  # and no channel gets worse
        assert after[key] < 1.02 * before[key]
    # The final model is at the noise level (0.5 % of each signal's spread) on held-out data.
    assert max(found.error_after.values()) < 0.65


@pytest.mark.parametrize('name', sorted(CASES))
def test_undeclared_effect_is_found(name):
    truth, excitation, checks = CASES[name]
    found = discover(motor_records([make_effect(name, **truth)], excitation))
    assert [effect.name for effect in found.effects] == [name]
    assert not found.unexplained
    check_errors_drop(found)
    check_core(found.estimate.parameters)
    fitted = found.effects_json()[0]['parameters']
    for key, tolerance in checks.items():
        if tolerance is None:
            assert fitted[key] == truth[key], key
        else:
            assert fitted[key] == pytest.approx(truth[key], rel=tolerance), key


def test_coulomb_asymmetry_is_found_as_its_equivalent():
    """
    Mc + d / Mc - d is exactly the model of a load torque d (|d| < Mc): a tie.

    The loop reports the earlier effect of the vocabulary (load_torque), lists
    coulomb_asymmetry as equivalent, and the friction levels come back to the truth.
    """
    found = discover(motor_records([make_effect('coulomb_asymmetry', delta_Nm=0.4)]))
    assert [effect.name for effect in found.effects] == ['load_torque']
    assert [item['name'] for item in found.steps[0]['equivalent']] == ['coulomb_asymmetry']
    check_errors_drop(found)
    check_core(found.estimate.parameters)
    load = found.effects[0].parameters['torque_Nm']
    mc = found.estimate.parameters['Mc']
    assert mc + load == pytest.approx(MOTOR.Mc + 0.4, rel=0.02)
    assert mc - load == pytest.approx(MOTOR.Mc - 0.4, rel=0.05)


@pytest.mark.parametrize('noise', [0.0, 0.005, 0.01])
def test_clean_data_adds_nothing(noise):
    found = discover(motor_records(noise=noise, seed=3))
    assert found.effects == []
    assert not found.unexplained
    assert found.error_before == found.error_after


def test_structure_outside_the_vocabulary_is_reported_not_forced():
    # A torque disturbance periodic in time (3.7 Hz vibration), not in the shaft angle.
    found = discover(motor_records(extra_torque=lambda t: 0.4 * np.sin(2 * np.pi * 3.7 * t)))
    assert found.effects == []
    assert found.unexplained
    evidence = found.evidence()
    assert any(item['ljung_box_p_value'] < 0.01 and item['predictable_fraction'] > 0.05
               for item in evidence.values())


def test_mechanical_only_load_torque():
    constant = 0.7
    t = np.arange(int(DURATION_S / DT)) * DT
    current = 6.0 * np.sin(2 * np.pi * 0.5 * t)
    held = np.append(0.5 * (current[:-1] + current[1:]), current[-1])
    speed, _ = simulate_mechanical_effects(MOTOR.J, MOTOR.b, MOTOR.Mc, constant * held, DT,
                                           [make_effect('load_torque', torque_Nm=0.4)])
    rng = np.random.default_rng(5)
    record = Record(t, current=current, speed=add_sensor_noise(speed, NOISE, rng))
    found = discover([record], torque_constant=constant)
    assert [effect.name for effect in found.effects] == ['load_torque']
    assert found.effects[0].parameters['torque_Nm'] == pytest.approx(0.4, rel=0.03)
    for name in ('J', 'b', 'Mc'):
        assert found.estimate.parameters[name] == pytest.approx(getattr(MOTOR, name),
                                                                rel=0.02)


def test_identify_reports_the_loop_in_the_json_contract():
    records = motor_records([make_effect('load_torque', torque_Nm=0.5)])
    result = identify(records).as_dict()
    assert result['effects'] == [{'name': 'load_torque',
                                  'parameters': {'torque_Nm': pytest.approx(0.5, rel=0.03)}}]
    assert result['unexplained'] is False
    for key in ('current_nrmse_pct', 'speed_nrmse_pct'):
        assert result['error_after'][key] < result['error_before'][key]
    assert result['parameters']['Mc'] == pytest.approx(MOTOR.Mc, rel=0.03)
    assert result['discovery']['steps'][0]['added']['name'] == 'load_torque'
    assert set(result) >= {'parameters', 'stderr', 'method', 'effects', 'error_before',
                           'error_after', 'unexplained', 'mode', 'initial_states',
                           'noise_std', 'sample_period_s', 'n_samples', 'records', 'units'}
    plain = identify(records, discover=False).as_dict()
    assert plain['effects'] == [] and plain['discovery'] is None
    assert plain['parameters']['Mc'] != pytest.approx(MOTOR.Mc, rel=0.03)  # biased by the load
    paper = identify(records, method='paper').as_dict()
    assert paper['effects'] == [] and 'refined' in paper['discovery']['skipped']


def test_two_records_one_per_direction_with_a_load_torque():
    # Issue 8: the screen ranked load_torque low, never refitted it, and J came back 17x too
    # large.  The screen now ranks; with a misfit far above the noise the top few are refitted.
    from dcmotor_id.simulation.lab_scenarios import directions_with_load

    scenario = directions_with_load(seed=2, sample_period_s=2e-3)
    result = identify(scenario.records)
    assert [effect['name'] for effect in result.effects][:1] == ['load_torque']
    load = result.effects[0]['parameters']['torque_Nm']
    assert load == pytest.approx(0.4, rel=0.05)
    for name in ('J', 'b', 'Mc', 'Ra', 'CPhi'):
        assert result.parameters[name] == pytest.approx(getattr(scenario.truth, name),
                                                        rel=0.03), name
    assert not result.not_identifiable


def test_friction_guard_never_fires_on_a_parameter_already_at_zero():
    from types import SimpleNamespace

    from dcmotor_id.identification.discovery import DiscoveryLoop
    from dcmotor_id.identification.discovery.refitting import problem

    t = np.arange(2000) * DT
    voltage = 100.0 * np.sin(2 * np.pi * t)
    current, speed = simulate_motor(MOTOR, voltage, DT)
    loop = DiscoveryLoop([Record(t, current=current, voltage=voltage, speed=speed)])
    effect = SimpleNamespace(problem=lambda values, records: None)
    structure = SimpleNamespace(effects=lambda values: [effect])

    def fit(values):
        return SimpleNamespace(values={**MOTOR.as_dict(), **values}, structure=structure,
                               records=loop.records)
    # Mc at 5e-193 "collapsing" further is no collapse (the 96 % gain rejected).
    assert problem(loop, fit({'Mc': 5e-193}), fit({'Mc': 1e-200})) is None
    # A real friction that collapses is still caught.
    assert 'collapses' in problem(loop, fit({'Mc': 1.0}), fit({'Mc': 1e-4}))


def test_an_early_sensor_is_not_accepted_as_a_negative_delay():
    # The speed sensor 3 samples ahead of the input: a negative delay would undo it, but no
    # sensor reports a signal before it happens (real HSM150 records drew -16 and -1500).
    record = motor_records([], {'kind': 'prbs', 'frequency_hz': 20, 'amplitude_v': 43})[0]
    early = record.slice(0, len(record) - 3).replace(speed=record.speed[3:])
    found = discover([early])
    assert 'sensor_delay' not in [effect.name for effect in found.effects]
    delays = [candidate for step in found.steps for candidate in step['candidates']
              if candidate['name'] == 'sensor_delay']
    assert delays and all(candidate['inner']['samples'] > 0 or
                          'not causal' in (candidate['rejected'] or '')
                          for candidate in delays)
    assert any(candidate['inner']['samples'] < 0 for candidate in delays)


def test_the_final_structure_must_beat_the_base_refitted_as_the_candidates_were():
    # A base fitted on the speed drifts on the position: any structure fitted on the position
    # beats it.  The final structure must beat the base refitted on the position (no effect).
    from types import SimpleNamespace

    from dcmotor_id.identification.discovery.judging import never_worse
    from dcmotor_id.identification.discovery.refitting import judging_reference

    base = SimpleNamespace(heldout_cost=50.0, info={})
    final = SimpleNamespace(heldout_cost=1.02)
    assert judging_reference(base) is base
    assert never_worse(base, final, 'explained')[0] is final
    base.info['null_refit'] = SimpleNamespace(heldout_cost=1.0)
    reference = judging_reference(base)
    assert reference is base.info['null_refit']
    kept, reason = never_worse(base, final, 'explained', reference)
    assert kept is base and 'did not lower the held-out error' in reason
