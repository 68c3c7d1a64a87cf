"""
Effect discovery on voltage and speed without a current (issue 31: "effects where they apply").

The effects that act on the shaft are searched on the voltage-to-speed model itself (with its
armature lag), in volts (a torque T as ``Ra T/CPhi``), and judged by the discovery loop's
held-out rule: a clean record gets none, a record with a load torque gets ``load_torque``
with its value (in volts) within its stated uncertainty; ``validate`` simulates the effect
and ``design --gravity-load`` takes it as kG (``bench/voltage_speed_results.md`` section 4
has the rates over seeds).
"""

from dataclasses import replace
import json

import numpy as np
import pytest
from schema_check import validate as validate_schema

from dcmotor_id.cli.main import main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.design.control import design_controller
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.formats.json_file import with_schema_version
from dcmotor_id.identification.discovery.loop import one_round
from dcmotor_id.identification.discovery.screening import SCREEN_SHARE
from dcmotor_id.identification.discovery.state import DEFAULT_ACCEPTANCE, LoopState, MIN_GAIN
from dcmotor_id.identification.discovery.structure import Candidate, Structure
from dcmotor_id.identification.discovery.voltage_speed import (fit_parts, refit,
                                                               VOLTAGE_SPEED_ROUND,
                                                               VOLTAGE_SPEED_VOCABULARY)
from dcmotor_id.identification.effects import make_effect, ViscousAsymmetry
from dcmotor_id.identification.estimators.voltage_speed import fit_voltage_speed
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.validate import model_from_dict, validate
from dcmotor_id.simulation import MotorEffects, simulate_motor_effects

DT = 1e-3
MOTOR = PAPER_MOTORS['paper2']


def sysid_voltage():
    """SysId-like routine: quasistatic ramps both ways, then dynamic steps both ways [V]."""
    t = np.arange(0.0, 3.0, DT)
    rest = np.zeros(300)
    return np.concatenate([6.0 * t, rest, -6.0 * t, rest, np.full(1500, 28.0), rest,
                           np.full(1500, -28.0)])


def effect_record(effects, seed=0):
    """Return a record of paper motor 2's speed (1 % noise) with true ``effects``, no current."""
    voltage = sysid_voltage()
    _, speed, _ = simulate_motor_effects(MOTOR, voltage, DT, effects)
    speed = speed + 0.01 * np.std(speed) * np.random.default_rng(seed).standard_normal(
        speed.size)
    return Record(np.arange(voltage.size) * DT, voltage=voltage, speed=speed, source='sim')


def true_combinations():
    """Return the true kS, kV of paper motor 2."""
    return {'kS': MOTOR.Ra * MOTOR.Mc / MOTOR.CPhi,
            'kV': MOTOR.CPhi + MOTOR.Ra * MOTOR.b / MOTOR.CPhi}


def test_a_clean_record_gets_no_effect():
    """
    The shaft's effects are screened on the voltage-to-speed model; none earns its place.

    None explains a share of the residual worth a refit: none is refitted (the costly part,
    a refit through the event-driven kernel, is skipped).
    """
    result = identify(prepare_records([effect_record([])]))
    assert result.effects == []
    discovery = result.discovery
    assert discovery['acceptance'] == DEFAULT_ACCEPTANCE
    screened = {candidate['name']: candidate for step in discovery['steps']
                for candidate in step['candidates']}
    assert {'load_torque', 'coulomb_asymmetry', 'viscous_asymmetry'} <= set(screened)
    assert not any(candidate['refitted'] for candidate in screened.values())
    assert all(candidate['screen_explained_pct'] < 100 * SCREEN_SHARE * MIN_GAIN
               for candidate in screened.values())
    assert all(step['added'] is None for step in discovery['steps'])
    assert not any('in volts' in text for text in result.warnings)


def test_a_round_refits_only_the_candidates_the_screen_supports():
    """
    A load torque: the round screens every absent effect and refits those the screen supports.

    The round is the loop's own (:func:`one_round`) with the voltage-to-speed steps; the
    refits are counted through its refit step.  The load torque (its screen: most of the
    residual) is refitted and chosen; the next round, nothing left to explain, refits none.
    """
    records = prepare_records([effect_record([make_effect('load_torque', torque_Nm=0.5)])])
    fitted = fit_voltage_speed(records)
    loop = LoopState(records, torque_constant=1.0, vocabulary=VOLTAGE_SPEED_VOCABULARY)
    base = fit_parts(loop, Structure(), fitted.theta, {}, fitted.states)
    loop = replace(loop, weights={'speed': base.estimate.info['noise_std']['speed']})
    refitted = []

    def counted(loop, current, candidate):
        refitted.append(candidate.name)
        return refit(loop, current, candidate)
    steps = replace(VOLTAGE_SPEED_ROUND, refit=counted)
    threshold = SCREEN_SHARE * loop.min_gain
    first = one_round(loop, base, {}, steps)
    assert first.chosen is not None and first.chosen.name == 'load_torque'
    assert first.report['added']['parameters']['torque_V'] == pytest.approx(
        0.5 * MOTOR.Ra / MOTOR.CPhi, rel=0.02)
    assert sorted(refitted) == sorted(candidate.name for candidate in first.candidates
                                      if candidate.screen_explained >= threshold)
    refitted.clear()
    second = one_round(loop, first.chosen.fitted, {}, steps)
    assert second.chosen is None and refitted == []
    assert {'coulomb_asymmetry', 'viscous_asymmetry'} <= {
        candidate.name for candidate in second.candidates}


def test_a_load_torque_is_found_in_volts_within_its_stated_uncertainty(tmp_path, capsys):
    """0.5 N m on paper motor 2: Ra T_L/CPhi = 1.143 V, found by identify on the CSV."""
    csv = str(tmp_path / 'loaded.csv')
    write_csv(csv, effect_record([make_effect('load_torque', torque_Nm=0.5)]))
    out = str(tmp_path / 'result.json')
    assert main(['identify', csv, '--quiet', '--json', out]) == 0
    assert 'load_torque' in capsys.readouterr().out
    result = json.loads(open(out, encoding='utf-8').read())
    validate_schema(with_schema_version(result), 'result')
    assert [effect['name'] for effect in result['effects']] == ['load_torque']
    value = result['effects'][0]['parameters']['torque_V']
    entry = result['combined']['load_torque.torque_V']
    assert entry['value'] == value and entry['unit'] == 'V' and entry['of'] == 'Ra T_L / CPhi'
    true = 0.5 * MOTOR.Ra / MOTOR.CPhi
    assert 0 < entry['stderr'] < 0.01 * true
    assert abs(value - true) < 3.0 * entry['stderr']
    assert result['discovery']['steps'][0]['added']['name'] == 'load_torque'
    for name, truth in true_combinations().items():
        assert result['parameters'][name] == pytest.approx(truth, rel=0.02), name
    assert any('needs the current' in text for text in result['warnings'])
    # validate simulates the effect: the speed within the noise; without it, far worse
    scores = validate(model_from_dict(result), prepare_records([effect_record(
        [make_effect('load_torque', torque_Nm=0.5)], seed=5)])).as_dict()['records'][0]
    assert scores['speed_nrmse_pct'] < 1.2
    bare = dict(result, effects=[], model=dict(result['model'], effects=[]))
    worse = validate(model_from_dict(bare), prepare_records([effect_record(
        [make_effect('load_torque', torque_Nm=0.5)], seed=5)])).as_dict()['records'][0]
    assert worse['speed_nrmse_pct'] > 3.0 * scores['speed_nrmse_pct']
    # design takes the load torque as gravity: kG in volts, the same on the output shaft
    made = design_controller(result, speed_bandwidth_hz=5.0, sample_period_s=DT,
                             gravity_load=True)
    assert made['feedforward']['kG'] == pytest.approx(value)
    assert made['feedforward']['units']['kG'] == 'V'
    assert any('effect load_torque' in note for note in made['notes'])


def test_a_voltage_speed_model_refuses_an_effect_that_needs_the_current():
    """validate: a brush drop (in the armature circuit) has no place in kS, kV, kA."""
    model = {'mode': 'voltage_speed', 'parameters': {'kS': 2.3, 'kV': 1.4, 'kA': 0.07},
             'effects': [{'name': 'brush_drop', 'parameters': {'drop_V': 0.5}}]}
    with pytest.raises(InputDataError, match='does not act in the voltage-to-speed model'):
        model_from_dict({'model': model})
    model['effects'] = [{'name': 'load_torque', 'parameters': {'torque_Nm': 0.5}}]
    with pytest.raises(InputDataError, match='unknown parameter.*torque_V'):
        model_from_dict({'model': model})


@pytest.mark.parametrize('lag', [None, (MOTOR.La / MOTOR.Ra, None)])
def test_the_effects_in_volts_are_the_motor_s_torques_times_ra_over_cphi(lag):
    """The model with effects in volts simulates paper motor 2 with its torques exactly."""
    from dcmotor_id.identification.estimators.voltage_speed_effects import (
        simulate_speed_effects)
    from dcmotor_id.simulation import combine_effects
    volts = MOTOR.Ra / MOTOR.CPhi
    torques = [make_effect('load_torque', torque_Nm=0.3),
               make_effect('coulomb_asymmetry', delta_Nm=0.2),
               make_effect('viscous_asymmetry', delta_Nm_s=0.05)]
    in_volts = [type(effect).from_voltage_speed(effect.describe_voltage_speed()['parameters'])
                for effect in [make_effect('load_torque', torque_Nm=0.3 * volts),
                               make_effect('coulomb_asymmetry', delta_Nm=0.2 * volts),
                               make_effect('viscous_asymmetry', delta_Nm_s=0.05 * volts)]]
    voltage = sysid_voltage()
    values = {'kS': MOTOR.Ra * MOTOR.Mc / MOTOR.CPhi, 'kA': MOTOR.Ra * MOTOR.J / MOTOR.CPhi,
              'kV': MOTOR.CPhi + MOTOR.Ra * MOTOR.b / MOTOR.CPhi}
    motor, tolerance = MOTOR, 1e-6
    if lag is None:  # the first-order model: the motor with a negligible armature lag
        motor, tolerance = replace(MOTOR, La=1e-6), 1e-4
    else:
        lag = (lag[0], values['kA'] + lag[0] * MOTOR.Ra * MOTOR.b / MOTOR.CPhi)
    _, truth, _ = simulate_motor_effects(motor, voltage, DT, torques, oversample=10)
    speed = simulate_speed_effects(values, voltage, DT, 0.0, lag, combine_effects(in_volts),
                                   0.0)
    assert np.max(np.abs(speed - truth)) < tolerance * np.max(np.abs(truth))


def test_a_candidate_whose_simulation_overflows_has_no_fit():
    # A QUBE-Servo 2 record (500 Hz, voltage and angle) ended in an internal error: one
    # candidate's simulation overflowed and scipy's trust region refused the Jacobian.
    from dcmotor_id.identification.estimators.voltage_speed_effects import (EffectModel,
                                                                            fit_effects)

    class Overflowing(EffectModel):
        def __call__(self, theta, record, initial):
            speed = super().__call__(theta, record, initial)
            return speed if theta[self.size] == 0.0 else np.full_like(speed, np.inf)

    record = prepare_records([effect_record([])])[0].slice(0, 2000)
    model = Overflowing(3, lambda coefficients: MotorEffects())
    truth = true_combinations()
    theta = np.array([truth['kS'], truth['kV'], 0.05, 0.0])
    assert fit_effects(model, [record], theta, ['load_torque.torque_V'], [[0.0]]) is None


def test_a_viscous_asymmetry_below_kv_is_admissible():
    """
    The refit judges a viscous asymmetry against kV, not against the fit's log kV.

    The fit holds log kV (here 0.33 for kV 1.39 V s/rad; negative for every kV below 1):
    judged against it, an asymmetry of 0.55 V s/rad (0.8 b) read "viscous friction would be
    negative" and was never added.
    """
    records = prepare_records([effect_record([make_effect('viscous_asymmetry',
                                                          delta_Nm_s=0.8 * MOTOR.b)])])
    fitted = fit_voltage_speed(records)
    loop = LoopState(records, torque_constant=1.0, vocabulary=VOLTAGE_SPEED_VOCABULARY)
    base = fit_parts(loop, Structure(), fitted.theta, {}, fitted.states)
    loop = replace(loop, weights={'speed': base.estimate.info['noise_std']['speed']})
    done = refit(loop, base, Candidate(ViscousAsymmetry, {}, {}, 0.0))
    assert done.fit is not None
    assert done.problem is None
