"""Experiment design: D-optimal band and amplitude within limits (dcmotor_id.design.experiment)."""

import json

import numpy as np
import pytest

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS, PARAMETER_NAMES
from dcmotor_id.design.experiment import (candidate_bands, design_experiment, expected_stderr,
                                          load_prior, planned_record, read_plan)
from dcmotor_id.design.routines import Limits, Routine
from dcmotor_id.identification.estimators.fisher import cramer_rao_bound

MOTOR = PAPER_MOTORS['paper2']
NOISE = {'current': 0.01, 'speed': 0.02}


def test_expected_stderr_is_the_cramer_rao_bound():
    routine = Routine('prbs', 10.0, 3.0, frequency_hz=20.0)
    record = planned_record(routine, MOTOR, 200.0, 0.5, 1e-3)
    stderr, criterion = expected_stderr(record, MOTOR, NOISE)
    bound = cramer_rao_bound([record], MOTOR, NOISE)
    for name in PARAMETER_NAMES + ('Ka', 'Ta'):
        assert stderr[name] == pytest.approx(bound[name], rel=1e-6), name
    assert np.isfinite(criterion)
    # twice the amplitude: about twice the information per parameter (Coulomb friction aside)
    louder, _ = expected_stderr(planned_record(routine.replace(amplitude_v=20.0), MOTOR,
                                               200.0, 0.5, 1e-3), MOTOR, NOISE)
    assert louder['Ra'] < 0.7 * stderr['Ra']


@pytest.mark.slow
def test_the_plan_respects_the_limits_and_beats_every_other_candidate():
    limits = Limits(voltage_v=48.0, current_a=6.0, speed_rad_s=40.0)
    plan = design_experiment(MOTOR, limits, NOISE, duration_s=4.0)
    assert plan.peak_current_a <= 0.9 * limits.current_a
    assert plan.peak_speed_rad_s <= 0.9 * limits.speed_rad_s
    assert plan.routine.amplitude_v <= limits.voltage_v
    scored = [item['criterion'] for item in plan.candidates if 'criterion' in item]
    assert len(scored) >= 5 and plan.criterion == max(scored)
    # the current limit binds: the amplitude is pushed up to it
    assert plan.peak_current_a > 0.8 * limits.current_a
    record = planned_record(plan.routine, MOTOR, plan.rate_hz, plan.ramp_in_s, 1e-3)
    assert np.max(np.abs(record.current)) == pytest.approx(plan.peak_current_a)
    data = json.loads(json.dumps(plan.as_dict()))
    assert Routine.from_dict(data['routine']) == plan.routine
    assert set(data['expected_stderr']) == set(PARAMETER_NAMES + ('Ka', 'Ta'))
    assert 'expected stderr' in plan.describe()


def test_a_lower_limit_plans_a_smaller_amplitude_with_larger_bounds():
    loose = design_experiment(MOTOR, Limits(48.0, 10.0, 100.0), NOISE, duration_s=2.0,
                              kinds=('prbs',), parameters=('J', 'b', 'Mc'))
    tight = design_experiment(MOTOR, Limits(48.0, 3.0, 100.0), NOISE, duration_s=2.0,
                              kinds=('prbs',), parameters=('J', 'b', 'Mc'))
    assert tight.routine.amplitude_v < loose.routine.amplitude_v
    assert tight.expected_stderr['J'] > loose.expected_stderr['J']
    assert tight.parameters == ['J', 'b', 'Mc']


def test_impossible_limits_and_bad_arguments_are_refused():
    with pytest.raises(ValueError, match='limits'):
        design_experiment(MOTOR, Limits(48.0, 1e-4, 100.0), NOISE, duration_s=1.0,
                          kinds=('prbs',))
    with pytest.raises(ValueError):
        design_experiment(MOTOR, Limits(), NOISE, kinds=('chirp',))
    with pytest.raises(ValueError):
        design_experiment(MOTOR, Limits(), NOISE, parameters=('Ka',))


def test_bands_follow_the_motor():
    slow = candidate_bands(MOTOR.replace(J=MOTOR.J * 10), 200.0)
    fast = candidate_bands(MOTOR, 200.0)
    assert min(band[1] for band in slow) < min(band[1] for band in fast)
    assert all(band[1] <= 100.0 and band[2] <= 100.0 for band in fast)


def test_priors_from_names_results_and_datasheets(tmp_path):
    assert load_prior('paper1') == (PAPER_MOTORS['paper1'], None)
    result = tmp_path / 'result.json'
    result.write_text(json.dumps({'parameters': MOTOR.as_dict(),
                                  'noise_std': {'current': 0.03, 'speed': 0.05}}))
    assert load_prior(str(result)) == (MOTOR, {'current': 0.03, 'speed': 0.05})
    sheet = tmp_path / 'motor.yaml'
    sheet.write_text('\n'.join(f'{key}: {value}' for key, value in
                               MOTOR.as_dict(derived=False).items()))
    assert load_prior(str(sheet)) == (MOTOR, None)
    for text in ('[1, 2]', '{"Ra": 1.0}', 'not json'):
        (tmp_path / 'bad.json').write_text(text)
        with pytest.raises(InputDataError):
            load_prior(str(tmp_path / 'bad.json'))
    with pytest.raises(InputDataError):
        load_prior('no-such-motor')


def test_plan_command_prints_and_writes_the_plan(tmp_path, capsys):
    out = tmp_path / 'plan.json'
    code = cli_main(['plan', '--prior', 'paper2', '--duration', '2', '--kinds', 'prbs',
                     '--current-limit', '5', '--json', str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert 'plan: prbs' in printed and 'expected stderr' in printed and 'Mc' in printed
    plan = read_plan(str(out))
    assert plan['limits']['current_a'] == 5.0 and plan['peak_current_a'] <= 4.5
    assert cli_main(['plan', '--prior', str(tmp_path / 'missing.json')]) == 2
    assert cli_main(['plan', '--current-limit', '0.0001', '--duration', '1']) == 2
