"""The recursive estimator on the exactly discretised neurons."""

import numpy as np
from scipy.linalg import expm

from dcmotor_id.excitation import make_excitation
from dcmotor_id.model import PAPER_MOTORS, relative_errors_pct, state_matrix
from dcmotor_id.online import OnlineEstimator, physical_from_discrete
from dcmotor_id.simulation import simulate_motor


def feed(estimator, voltage, current, speed, block=50):
    for start in range(0, voltage.size, block):
        part = slice(start, start + block)
        estimator.update(voltage[part], current[part], speed[part])


def test_exact_discretisation_maps_back_to_the_parameters():
    params = PAPER_MOTORS['paper1']
    dt = 1e-3
    a_matrix = state_matrix(params)
    phi = expm(a_matrix * dt)
    integral = np.linalg.solve(a_matrix, phi - np.eye(2))
    theta = np.zeros((4, 2))
    theta[:2, :] = (phi - np.eye(2)).T
    theta[2, :] = integral @ [1.0 / params.La, 0.0]
    theta[3, :] = integral @ [0.0, -params.Mc / params.J]
    values = physical_from_discrete(theta, dt)
    errors = relative_errors_pct(values, params)
    assert max(errors.values()) < 1e-6, errors


def test_noise_free_data_give_the_parameters_at_any_sample_period():
    params = PAPER_MOTORS['paper2']
    for dt, duration in ((1e-3, 12.0), (1e-4, 3.0)):
        _, voltage = make_excitation('paper', duration, dt)
        current, speed = simulate_motor(params, voltage, dt)
        estimator = OnlineEstimator(dt, memory_s=20.0)
        feed(estimator, voltage, current, speed, block=max(1, int(0.02 / dt)))
        estimate = estimator.estimate()
        errors = relative_errors_pct(estimate.parameters, params)
        assert max(errors.values()) < 0.1, (dt, errors)
        assert estimate.converged
        assert estimate.innovation_rms['current'] < 1e-3 * np.std(current)


def test_a_gap_declared_with_break_continuity_does_not_bias_the_estimate():
    params = PAPER_MOTORS['paper2']
    dt = 1e-3
    _, voltage = make_excitation('paper', 12.0, dt)
    current, speed = simulate_motor(params, voltage, dt)
    keep = np.ones(voltage.size, dtype=bool)
    keep[3000:3400] = False  # 0.4 s lost
    estimator = OnlineEstimator(dt, memory_s=20.0)
    feed(estimator, voltage[:3000], current[:3000], speed[:3000])
    estimator.break_continuity()
    feed(estimator, voltage[3400:], current[3400:], speed[3400:])
    errors = relative_errors_pct(estimator.estimate().parameters, params)
    assert max(errors.values()) < 0.1, errors


def test_noisy_data_converge_near_the_truth():
    params = PAPER_MOTORS['paper2']
    dt = 1e-3
    _, voltage = make_excitation('paper', 16.0, dt)
    current, speed = simulate_motor(params, voltage, dt)
    rng = np.random.default_rng(0)
    estimator = OnlineEstimator(dt, memory_s=20.0)
    feed(estimator, voltage, current + rng.normal(0, 0.01, current.size),
         speed + rng.normal(0, 0.02, speed.size))
    estimate = estimator.estimate()
    errors = relative_errors_pct(estimate.parameters, params)
    # equation error with noisy regressors is biased (documented); it stays small here
    assert max(errors[name] for name in ('Ra', 'La', 'CPhi', 'J')) < 2.0, errors
    assert 0.005 < estimate.innovation_rms['current'] < 0.05


def test_no_excitation_is_not_converged():
    dt = 1e-3
    estimator = OnlineEstimator(dt)
    zeros = np.zeros(5000)
    feed(estimator, zeros, zeros, zeros)
    estimate = estimator.estimate()
    assert not estimate.converged
    assert estimate.n_updates == 0
    assert all(np.isnan(value) for value in estimate.parameters.values())


def test_closed_form_logarithm_matches_scipy():
    from scipy.linalg import expm, logm

    from dcmotor_id.online import log2x2
    rng = np.random.default_rng(0)
    for _ in range(50):
        a_matrix = rng.normal(size=(2, 2)) - 2 * np.eye(2)
        phi = expm(a_matrix * 0.1)
        np.testing.assert_allclose(log2x2(phi), np.real(logm(phi)), atol=1e-10)
    assert log2x2(np.diag([1.0, -0.5])) is None
