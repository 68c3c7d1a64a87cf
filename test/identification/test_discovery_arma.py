"""The ARMA(1, 2) error model of the held-out innovations (rule ``innovation-arma``, issue 29)."""

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.arma import arma_filter, fit_arma, polynomial
from dcmotor_id.identification.discovery.judging import residual_ar, residual_arma
from dcmotor_id.identification.discovery.state import ACCEPTANCE_RULES
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation


def _lag1(x):
    x = x - np.mean(x)
    return float(x[1:] @ x[:-1] / (x @ x))


def _input_noise_increments(seed, n=6000, tau=30.0):
    """Increments of a position error: a speed error (an input's noise, low-passed) + rounding."""
    rng = np.random.default_rng(seed)
    decay = np.exp(-1.0 / tau)
    speed = np.zeros(n)
    kicks = rng.normal(0.0, 1.0, n)
    for k in range(1, n):
        speed[k] = decay * speed[k - 1] + kicks[k]
    rounding = rng.normal(0.0, 12.0, n)
    return speed + np.diff(np.r_[0.0, rounding]), decay


@pytest.mark.parametrize('partials', [[0.5], [0.99, -0.9], [-0.998, 0.998], [0.3, 0.2, -0.1]])
def test_the_moving_average_polynomial_is_invertible(partials):
    roots = np.roots(polynomial(partials)[::-1])
    assert np.all(np.abs(roots) > 1.0), roots


@pytest.mark.parametrize('seed', range(3))
def test_the_increments_of_an_integrated_input_noise_are_whitened(seed):
    # An AR(1) error model of the position leaves the increments: a lag-1 correlation near
    # -0.5 (the rounding's increments) over a speed error that lasts 30 samples.  The
    # ARMA(1, 2) model finds the speed error's decay and leaves white innovations.
    increments, decay = _input_noise_increments(seed)
    assert _lag1(increments) < -0.3
    phi, theta = fit_arma([increments])
    innovations = arma_filter(increments, phi, theta)[50:]
    assert abs(_lag1(innovations)) < 0.05
    assert phi == pytest.approx(decay, abs=0.03)
    assert np.var(innovations) < 0.95 * np.var(increments)


def test_a_white_residual_keeps_its_innovations():
    rng = np.random.default_rng(4)
    white = rng.normal(0.0, 1.0, 4000)
    phi, theta = fit_arma([white])
    innovations = arma_filter(white, phi, theta)
    assert np.var(innovations[10:]) == pytest.approx(np.var(white[10:]), rel=0.02)
    assert abs(_lag1(innovations)) < 0.05


class _Fit:
    """A stand-in for a Fit: one position record whose simulation misses by ``error``."""

    def __init__(self, error, stop):
        self.records = [Record(np.arange(error.shape[0]) * 1e-3, np.zeros(error.shape[0]),
                               None, None, np.zeros(error.shape[0]), source='stand-in')]
        self.simulated = [{'position': error}]
        self.stops = [stop]


def test_without_arma_the_error_model_is_the_ar1_one():
    increments, _ = _input_noise_increments(5)
    error = np.cumsum(increments)
    rho, phi, theta, variance = residual_arma(_Fit(error, 4200), 'position', arma=False)
    assert (rho, variance) == residual_ar(_Fit(error, 4200), 'position')
    assert phi == 0.0 and list(theta) == [1.0]
    arma = residual_arma(_Fit(error, 4200), 'position')
    assert arma[1] > 0.8 and arma[3] < variance


def test_the_rule_is_one_of_the_loop_rules():
    assert 'innovation-arma' in ACCEPTANCE_RULES


def test_a_load_torque_is_found_by_the_rule_with_a_noisy_input_current():
    # The EMPS setting with the input current logged with 1 % noise, a load torque of
    # 0.5 Mc: the ARMA innovations keep it (held-out t well above 3).
    from dcmotor_id.identification.discovery import discover
    from dcmotor_id.identification.prepare import prepare_records
    from dcmotor_id.simulation import held_input, simulate_mechanical_effects, simulate_motor

    dt, step = 1e-3, 2 * np.pi / 4096
    motor = PAPER_MOTORS['paper2']
    rng = np.random.default_rng(11)
    t, voltage = make_excitation('sine', 6.0, dt, amplitude_v=60.0, seed=11, frequency_hz=0.5)
    current, _ = simulate_motor(motor, voltage, dt)
    _, angle = simulate_mechanical_effects(
        motor.J, motor.b, motor.Mc, motor.CPhi * held_input(current), dt,
        [make_effect('load_torque', torque_Nm=0.5 * motor.Mc)])
    records = prepare_records([Record(t, add_sensor_noise(current, 0.01, rng), None, None,
                                      np.round(angle / step) * step, source='sine')],
                              torque_constant=motor.CPhi)
    found = discover(records, motor.CPhi, criterion='position', acceptance='innovation-arma')
    assert [effect.name for effect in found.effects][:1] in (['load_torque'],
                                                             ['coulomb_asymmetry'])
