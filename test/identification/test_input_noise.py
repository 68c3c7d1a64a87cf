"""A speed misfit that the measured current's own noise explains is said so (issue 19)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import lfilter

from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.input_noise import (input_noise_warning,
                                                          propagated_speed_rms)
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.simulation.lab_scenarios import servo_opposite_steps

PARAMETERS = {'J': 1.2e-4, 'b': 7e-5}
K = 0.0458


def _noise_record(sigma: float, n: int = 400_000, dt: float = 1e-3) -> Record:
    rng = np.random.default_rng(3)
    t = np.arange(n) * dt
    return Record(t, current=1.0 + rng.normal(0.0, sigma, n), speed=np.zeros(n))


def test_the_speed_rms_is_what_the_model_makes_of_white_current_noise():
    record = _noise_record(0.5)
    speed_rms, sigma = propagated_speed_rms(PARAMETERS, [record], K)
    assert sigma == pytest.approx(0.5, rel=0.01)
    a = np.exp(-PARAMETERS['b'] * 1e-3 / PARAMETERS['J'])
    wander = lfilter([0.0, (1 - a) / PARAMETERS['b']], [1.0, -a],
                     K * (record.current - 1.0))[50_000:]  # past the start-up
    assert speed_rms == pytest.approx(float(np.std(wander)), rel=0.05)
    assert 5.0 < speed_rms < 6.5  # the HSM150 servo's 0.5 A: 5-6.6 rad/s


def test_only_a_residual_near_that_figure_is_put_down_to_the_current():
    record = _noise_record(0.5, n=20_000)
    speed_rms, _ = propagated_speed_rms(PARAMETERS, [record], K)
    assert input_noise_warning(PARAMETERS, [record], K, 1.2 * speed_rms, 30.0)
    assert input_noise_warning(PARAMETERS, [record], K, 3.0 * speed_rms, 80.0) is None
    assert input_noise_warning(PARAMETERS, [record], None, speed_rms, 30.0) is None


def _misfit_warnings(current_noise_a: float, settling_nm: float) -> list[str]:
    scenario = servo_opposite_steps(seed=0, current_noise_a=current_noise_a,
                                    settling_nm=settling_nm)
    k = scenario.torque_constant
    result = identify(prepare_records(scenario.records[:1], torque_constant=k),
                      torque_constant=k)
    return [text for text in result.warnings if 'misfit' in text]


def test_a_servo_record_whose_misfit_is_its_current_noise_is_told_so():
    # The lab servo's current carries 0.45 A of white ripple noise that is no torque: the
    # residual is about 20 speed-noise levels, all of it that noise through the model.
    warnings = _misfit_warnings(0.45, 0.0)
    assert len(warnings) == 1
    assert "the measured current's own noise" in warnings[0]
    assert 'the model misfits far above' not in warnings[0]


def test_a_missing_effect_above_a_quiet_current_is_still_a_model_misfit():
    # A friction settling that the vocabulary lacks, with a tenth of the current noise.
    warnings = _misfit_warnings(0.045, 0.004)
    assert len(warnings) == 1 and 'the model misfits far above' in warnings[0]


def test_the_check_needs_a_current_and_positive_parameters():
    record = SimpleNamespace(current=None, sample_period_s=1e-3)
    assert propagated_speed_rms(PARAMETERS, [record], K) is None
    assert propagated_speed_rms({'J': 1.2e-4, 'b': 0.0}, [_noise_record(0.5, 100)], K) is None


def _servo_result(current_noise_a: float, settling_nm: float):
    scenario = servo_opposite_steps(seed=0, current_noise_a=current_noise_a,
                                    settling_nm=settling_nm)
    k = scenario.torque_constant
    return identify(prepare_records(scenario.records[:1], torque_constant=k),
                    torque_constant=k), scenario.truth


def test_the_standard_errors_cover_the_current_noise_when_it_is_the_misfit():
    # The lab servo's single record with 0.45 A of current noise: its fits scatter by some
    # 10 % in J (the HSM150 Monte Carlo: 8-16 %); the output-error standard errors, which
    # take the current as exact, said 1-2 %.  The refits with the noise added measure it.
    result, truth = _servo_result(0.45, 0.0)
    assert 'parametric bootstrap of the input' in result.uncertainty_method
    spread = result.estimate.info['input_noise_spread']
    assert spread['refits'] >= 4 and spread['current_noise_A'] == pytest.approx(0.45, rel=0.1)
    assert result.stderr['J'] == pytest.approx(max(spread['J'], result.stderr_model['J']))
    assert result.stderr['J'] / result.parameters['J'] > 0.04
    assert result.stderr['b'] / result.parameters['b'] > 0.02
    assert abs(result.parameters['J'] - truth.J) < 3 * result.stderr['J']


def test_a_model_misfit_above_a_quiet_current_keeps_its_standard_errors():
    result, _ = _servo_result(0.045, 0.004)
    assert 'bootstrap' not in result.uncertainty_method
    assert 'input_noise_spread' not in result.estimate.info
