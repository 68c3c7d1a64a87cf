"""Failure classes of real laboratory records (issue 19), reproduced in the lab simulator."""

from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.noise import noise_level
from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.identifiability import initial_state_warnings
from dcmotor_id.identification.checks.start import (correlation_time, offset_supported,
                                                    regression_evidence)
from dcmotor_id.identification.discovery import DiscoveryLoop, excited_stop, Structure
from dcmotor_id.identification.discovery.judging import unearned
from dcmotor_id.identification.discovery.state import DEFAULT_ACCEPTANCE
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline.second_start import _choose
from dcmotor_id.identification.validate import (model_from_dict, operating_range, range_warnings,
                                                validate)
from dcmotor_id.simulation.lab_scenarios import servo_opposite_steps, servo_torque_steps


@pytest.fixture(scope='module')
def opposite():
    scenario = servo_opposite_steps(seed=0)
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    return scenario, records


@pytest.fixture(scope='module')
def opposite_result(opposite):
    scenario, records = opposite
    return identify(records, torque_constant=scenario.torque_constant)


@pytest.mark.slow
def test_opposite_directions_with_an_offset_find_the_right_basin(opposite, opposite_result):
    # HSM150 class: without the offset the fit with free initial states settled at J 50x,
    # the initial speeds moved by the misfit, and the screen from there never found the load.
    scenario, _ = opposite
    truth = scenario.truth
    parameters = opposite_result.parameters
    assert abs(parameters['J'] / truth.J - 1) < 0.15, parameters
    assert abs(parameters['b'] / truth.b - 1) < 0.15, parameters
    assert abs(parameters['Mc'] / truth.Mc - 1) < 0.15, parameters
    effects = {effect['name']: effect['parameters'] for effect in opposite_result.effects}
    assert list(effects) == ['load_torque'], effects  # nothing fitted to the noise
    assert effects['load_torque']['torque_Nm'] == pytest.approx(0.007, rel=0.2)
    check = opposite_result.as_dict()['start_check']
    assert check['doubts'] and check['chosen'].startswith('second start'), check
    assert any('model-free evidence' in text for text in opposite_result.warnings)


def test_a_pinned_base_without_the_offset_does_not_hide_it():
    # HSM150 pos_0.065_3 + neg_0.045_3: the base model without the offset has no sound basin
    # at all, pinned or not (J 10-20x, Mc 0), and a friction that settles after each start
    # (the speed creeps up for seconds) makes the screen from there miss the load torque on
    # the held-out part.  The second start holds the offset the regression sees from its
    # pinned fit on; without it the result was J 16x, b 1.8x, Mc 0 and no load torque.
    scenario = servo_opposite_steps(seed=0, levels=((1.15, 1.39), (0.835, 0.931)),
                                    offset_nm=0.008, current_noise_a=0.5, settling_nm=0.004)
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    evidence = regression_evidence(records, scenario.torque_constant)
    assert offset_supported(evidence), evidence
    result = identify(records, torque_constant=scenario.torque_constant)
    truth, parameters = scenario.truth, result.parameters
    # The settling friction, which the model lacks, slows the rise: J reads 25 % high.
    assert abs(parameters['J'] / truth.J - 1) < 0.4, parameters
    assert abs(parameters['b'] / truth.b - 1) < 0.15, parameters
    assert abs(parameters['Mc'] / truth.Mc - 1) < 0.15, parameters
    effects = {effect['name']: effect['parameters'] for effect in result.effects}
    assert effects['load_torque']['torque_Nm'] == pytest.approx(0.008, rel=0.2), effects
    check = result.as_dict()['start_check']
    assert check['chosen'].startswith('second start'), check
    assert check['second_start']['effects'][0] == 'load_torque', check
    assert check['seeded'] == ['load_torque'], check
    assert any('holding from the start the torque offset' in text for text in result.warnings)


def test_no_offset_is_seen_in_one_direction_or_without_one():
    scenario = servo_opposite_steps(seed=0, offset_nm=0.0)
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    assert not offset_supported(regression_evidence(records, scenario.torque_constant))
    assert not offset_supported(regression_evidence(records[:1], scenario.torque_constant))


def test_the_model_free_regression_sees_the_offset(opposite):
    scenario, records = opposite
    evidence = regression_evidence(records, scenario.torque_constant)
    assert evidence is not None
    assert evidence['offset'] == pytest.approx(0.007, rel=0.3)
    assert evidence['Mc'] == pytest.approx(scenario.truth.Mc, rel=0.2)
    assert evidence['J'] == pytest.approx(scenario.truth.J, rel=0.5)


@pytest.mark.slow
def test_heldout_segment_has_excitation_and_whole_record_normalisation(opposite_result):
    errors = opposite_result.as_dict()['errors']
    assert errors['heldout_normalisation'] == 'standard deviation of the whole record'
    assert 'excitation' in errors['heldout_choice']
    for item in errors['records']:
        segment, = item['heldout_segments']
        # The response to the step at 10 s (time constant J/b = 1.7 s) is held out from 12 s,
        # not only the steady tail (the last 30 % of the samples start at 14 s).
        assert segment['start_s'] < 12.5 and segment['end_s'] > 19.0, segment
        assert segment['end_sample'] == item['samples']
        held = item['after']['heldout']
        # Whole-record spread: the training-part fit extrapolated to the steady level reads
        # 20-30 % here (the current noise, integrated by the shaft, moves the speed by about
        # 5 rad/s), not the 500-6,000 % of a steady tail normalised by its own spread.
        assert held['speed_nrmse_pct'] < 40.0, held
        assert held['speed_nrmse_pct'] < item['heldout_constant']['speed_nrmse_pct']
    assert errors['worse_than_constant'] == []
    assert opposite_result.error_after['speed_nrmse_pct'] < 40.0


def test_the_held_out_part_of_a_step_with_a_steady_tail_contains_the_step():
    t = np.arange(20000) * 1e-3
    speed = np.where(t < 10.0, 100 * (1 - np.exp(-t / 2.0)),
                     100 + 50 * (1 - np.exp(-(t - 10.0) / 2.0)))
    rng = np.random.default_rng(0)
    record = Record(t, current=np.ones_like(t), speed=speed + rng.normal(0, 0.2, t.shape))
    stop = excited_stop(record, 0.3)
    # Samples alone would hold out 14-20 s, a tail with little left to judge; the last 30 % of
    # the excitation starts right after the step, and the training part keeps 60 % of the
    # samples (part of the second level to fit on).
    assert stop == 12000, stop
    flat = Record(t, current=np.ones_like(t), speed=np.where(t < 1.0, 100 * t, 100.0)
                  + rng.normal(0, 0.2, t.shape))
    assert excited_stop(flat, 0.3) == 12000  # all excitation early: the least training part


def test_a_quantised_speed_has_a_noise_floor():
    speed = np.round(np.linspace(0, 100, 5000) / 0.628) * 0.628
    assert noise_level(speed) == pytest.approx(0.628 / np.sqrt(12), rel=0.01)
    record = Record(np.arange(5000) * 1e-3, current=np.ones(5000), speed=speed, source='q')
    state = SimpleNamespace(initial_states=[(30.0,)])
    text, = initial_state_warnings(state, [record], ('speed',))
    # 30 rad/s at a rounding noise of 0.18 rad/s: about 165 noise levels, not 1e13.
    assert ' 165 noise levels' in text, text


def _fit(residuals, stop):
    """Return a stand-in for a Fit: one speed record whose simulation misses by ``residuals``."""
    record = SimpleNamespace(speed=np.zeros(residuals.shape[0]))
    fit = SimpleNamespace(stops=[stop], records=[record], simulated=[{'speed': residuals}],
                          fitted=None, values={'Mc': 1.0}, terms=(), structure=Structure())
    fit.channel_residual = lambda channel, part: (residuals[stop:] if part == 'heldout'
                                                  else residuals[:stop])
    return fit


def _loop(acceptance=DEFAULT_ACCEPTANCE):
    # Mechanical-only (a torque constant): the speed is the one output.
    return DiscoveryLoop([], 1.0, weights={'speed': 1.0}, min_gain=0.05, acceptance=acceptance)


def test_a_gain_carried_by_one_block_does_not_earn_an_effect():
    rng = np.random.default_rng(0)
    n, stop = 16000, 8000
    current = _fit(rng.normal(0, 1, n), stop)
    lucky = current.simulated[0]['speed'].copy()
    lucky[stop:stop + 1000] *= 0.2   # one block much better...
    lucky[stop + 1000:] *= 1.02      # ... the others a little worse: 9 % better overall
    spread = current.simulated[0]['speed'] * 0.9  # every block 19 % better
    loop = _loop()
    for residual, earned in ((lucky, False), (spread, True)):
        fitted = _fit(residual, stop)
        gain = 1 - np.mean(residual[stop:] ** 2) / np.mean(current.simulated[0]['speed'][stop:]
                                                           ** 2)
        assert gain > 0.05
        candidate = SimpleNamespace(name='load_torque', fitted=fitted, gain=gain, effect=None)
        reason = unearned(loop, current, candidate)
        assert (reason is None) == earned, reason


def test_a_cogging_ripple_above_the_coulomb_friction_needs_more_evidence_by_the_former_rule():
    rng = np.random.default_rng(1)
    n, stop = 16000, 8000
    current = _fit(rng.normal(0, 1, n), stop)
    better = current.simulated[0]['speed'] * 0.96  # 8 % gain, consistent over blocks
    fitted = _fit(better, stop)
    fitted.values = {'Mc': 0.01, 'cogging.sin_Nm': 0.03, 'cogging.cos_Nm': 0.0}
    gain = 1 - 0.96 ** 2
    loop = _loop('noise-level')
    candidate = SimpleNamespace(name='cogging', fitted=fitted, gain=gain, effect=None)
    reason = unearned(loop, current, candidate)
    assert reason is not None and 'larger than the Coulomb friction' in reason
    fitted.values = {'Mc': 0.05, 'cogging.sin_Nm': 0.03, 'cogging.cos_Nm': 0.0}
    assert unearned(loop, current, SimpleNamespace(name='cogging', fitted=fitted, gain=gain,
                                                   effect=None)) is None


def test_a_cogging_ripple_of_any_size_is_judged_by_its_significance_alone():
    # The held-out t on effective samples has no size rule (issue 29): a consistent 8 % gain
    # earns the ripple whatever its size against the Coulomb friction.
    rng = np.random.default_rng(1)
    n, stop = 16000, 8000
    current = _fit(rng.normal(0, 1, n), stop)
    fitted = _fit(current.simulated[0]['speed'] * 0.96, stop)
    fitted.values = {'Mc': 0.01, 'cogging.sin_Nm': 0.03, 'cogging.cos_Nm': 0.0}
    candidate = SimpleNamespace(name='cogging', fitted=fitted, gain=1 - 0.96 ** 2, effect=None)
    # The default's held-out test is innovation-t-alone's (without a least gain since round
    # 10; the loop's stop asks the whole records too since round 11); its coefficient test
    # asks the input current's noise of a fit of the output-error mechanical model (J, b, Mc),
    # not here.
    assert DEFAULT_ACCEPTANCE == 'whole-record-white'
    assert unearned(_loop(), current, candidate) is None
    # White noise traded for other white noise: a gain of 1 % that is chance.
    noise = _fit(rng.normal(0, 0.995, n), stop)
    chance = SimpleNamespace(name='cogging', fitted=noise, gain=0.06, effect=None)
    assert 'not significant' in unearned(_loop(), current, chance)


def test_validate_warns_outside_the_operating_range(opposite):
    scenario, records = opposite
    forward, back = records
    model = model_from_dict({'model': {
        'mode': 'mechanical', 'torque_constant': scenario.torque_constant,
        'parameters': {'J': 1.2e-4, 'b': 7e-5, 'Mc': 0.034}, 'effects': [],
        'sample_period_s': 1e-3, 'operating_range': operating_range([forward])}})
    assert validate(model, [forward]).warnings == []
    warnings = validate(model, [back]).warnings
    assert any('negative direction, which the model never saw' in text for text in warnings)
    fast = forward.replace(speed=forward.speed * 3.0, current=forward.current * 3.0)
    texts = range_warnings(operating_range([forward]), fast)
    assert any('of its speed lies beyond the range' in text for text in texts), texts
    assert any('of its current lies beyond the range' in text for text in texts), texts


def test_the_identify_result_carries_its_operating_range():
    scenario = servo_torque_steps(seed=0)
    result = identify(scenario.records, torque_constant=scenario.torque_constant,
                      discover=False).as_dict()
    seen = result['model']['operating_range']
    assert seen['directions'] == ['positive']
    assert seen['speed_rad_s'][1] > 0 and seen['current_A'][1] > 0


class _DecayModel:
    """A stand-in output-error model: a speed step whose initial speed decays with tau."""

    outputs = ('speed',)
    torque_constant = 1.0

    def __init__(self, time_s):
        self.time_s = time_s

    def simulate(self, values, index, state):
        decay = np.exp(-self.time_s / values['tau'])
        return {'speed': values['level'] * (1.0 - decay) + float(state[0]) * decay}


def _stand_in(level, tau, start):
    return Estimate('stand-in', {'level': level, 'tau': tau, 'J': 1.0, 'b': 1.0}, {}, [(start,)],
                    {'noise_std': {'speed': 0.2}})


def test_a_free_initial_speed_absorbing_a_slow_misfit_does_not_win_the_start_check():
    # HSM150 idf_neg_0.045_1: the free initial speed moved by 32 noise levels absorbs a slow
    # wander; counted as 20,000 independent samples its 7 % lower residual won the BIC, and J
    # read +20 % where the pinned fit reads +10 %.
    rng = np.random.default_rng(3)
    t = np.arange(20000) * 1e-3
    wander = 4.0 * np.sin(2 * np.pi * t / 8.0 + 0.3)
    speed = 100.0 * (1 - np.exp(-t / 1.5)) + wander + rng.normal(0, 0.2, t.shape)
    record = Record(t, current=np.ones_like(t), speed=speed, source='wander')
    model = _DecayModel(t)
    pinned = _stand_in(100.0, 1.5, 0.0)
    moved = _stand_in(100.0, 1.5, 6.0)  # the start moved to follow the wander's first swing
    residual = {name: speed - model.simulate(fit.parameters, 0, fit.initial_states[0])['speed']
                for name, fit in (('pinned', pinned), ('moved', moved))}
    assert np.mean(residual['moved'] ** 2) < 0.97 * np.mean(residual['pinned'] ** 2)
    assert correlation_time(residual['pinned']) > 500  # the wander: seconds of samples
    assert correlation_time(rng.normal(size=20000)) < 1.5
    second = SimpleNamespace(pinned_final=pinned, records=[record], model=model, freed=None,
                             structure=Structure())
    check = {}
    assert _choose(check, moved, [record], model, second) == \
        'second start, initial states pinned', check
    assert check['effective_samples'] < 100
