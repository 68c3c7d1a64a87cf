"""The online estimators: the window output-error refits, the old RLS, the schedule."""

from concurrent.futures import Future

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.stats import norm

from dcmotor_id.core.model import PAPER_MOTORS, PARAMETER_NAMES, relative_errors_pct, state_matrix
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation
from dcmotor_id.streaming.online import (disagreement, INTERVAL_SIGMAS, LOAD_TORQUE,
                                         make_estimator, parse_schedule, physical_from_discrete,
                                         RefitOutcome, RlsEstimator, simulate_scheduled,
                                         simultaneous_sigmas, WindowEstimator)


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
        estimator = RlsEstimator(dt, memory_s=20.0)
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
    estimator = RlsEstimator(dt, memory_s=20.0)
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
    estimator = RlsEstimator(dt, memory_s=20.0)
    feed(estimator, voltage, current + rng.normal(0, 0.01, current.size),
         speed + rng.normal(0, 0.02, speed.size))
    estimate = estimator.estimate()
    errors = relative_errors_pct(estimate.parameters, params)
    # equation error with noisy regressors is biased (documented); it stays small here
    assert max(errors[name] for name in ('Ra', 'La', 'CPhi', 'J')) < 2.0, errors
    assert 0.005 < estimate.innovation_rms['current'] < 0.05


def test_no_excitation_is_not_converged():
    dt = 1e-3
    estimator = RlsEstimator(dt)
    zeros = np.zeros(5000)
    feed(estimator, zeros, zeros, zeros)
    estimate = estimator.estimate()
    assert not estimate.converged
    assert estimate.n_updates == 0
    assert all(np.isnan(value) for value in estimate.parameters.values())


def test_closed_form_logarithm_matches_scipy():
    from scipy.linalg import expm, logm

    from dcmotor_id.streaming.online import log2x2
    rng = np.random.default_rng(0)
    for _ in range(50):
        a_matrix = rng.normal(size=(2, 2)) - 2 * np.eye(2)
        phi = expm(a_matrix * 0.1)
        np.testing.assert_allclose(log2x2(phi), np.real(logm(phi)), atol=1e-10)
    assert log2x2(np.diag([1.0, -0.5])) is None


# --------------------------------------------------------------------------- window estimator


def paper2_data(duration_s, dt=1e-3, kind='paper'):
    _, voltage = make_excitation(kind, duration_s, dt)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, dt)
    return voltage, current, speed


def test_window_estimator_is_exact_without_noise_at_any_sample_period():
    params = PAPER_MOTORS['paper2']
    for dt, duration in ((1e-3, 10.0), (1e-4, 2.0)):
        voltage, current, speed = paper2_data(duration, dt)
        estimator = WindowEstimator(dt, window_s=duration, refit_interval_s=duration,
                                    cpu_budget=1.0)
        feed(estimator, voltage, current, speed, block=max(1, int(0.02 / dt)))
        estimate = estimator.estimate()
        errors = relative_errors_pct(estimate.parameters, params)
        assert max(errors.values()) < 1e-4, (dt, errors)
        assert estimate.converged and estimate.method == 'window'
        assert estimate.time_s == pytest.approx(duration)
        assert estimate.effects[LOAD_TORQUE] == pytest.approx(0.0, abs=1e-8)


def test_window_estimator_is_unbiased_at_1_percent_noise_with_honest_stderr():
    """Monte Carlo: mean error within its standard error, spread close to the reported one."""
    params = PAPER_MOTORS['paper2']
    voltage, current, speed = paper2_data(10.0)
    values, stderrs = [], []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        estimator = WindowEstimator(1e-3, window_s=10.0, refit_interval_s=10.0,
                                    cpu_budget=1.0)
        feed(estimator, voltage, add_sensor_noise(current, 0.01, rng),
             add_sensor_noise(speed, 0.01, rng), block=500)
        estimate = estimator.estimate()
        assert estimate.converged, estimate.status
        values.append([estimate.parameters[name] for name in PARAMETER_NAMES])
        stderrs.append([estimate.stderr[name] for name in PARAMETER_NAMES])
    values, stderrs = np.array(values), np.array(stderrs)
    truth = params.as_array()
    reported = stderrs.mean(axis=0)
    # each estimate within 4 reported sigma; the mean within 4 sigma of the mean
    assert np.all(np.abs(values - truth) < 4 * stderrs), (values - truth) / stderrs
    assert np.all(np.abs(values.mean(axis=0) - truth) < 4 * reported / np.sqrt(len(values)))
    # the spread of 8 draws is known to about +-25 %: the reported stderr within a factor 2
    ratio = reported / values.std(axis=0, ddof=1)
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio
    # and the goals of the issue: Ra, CPhi, J, b within 2 %, La, Mc within 5 %
    errors = np.abs(values - truth) / truth * 100
    assert errors[:, [0, 2, 3, 4]].max() < 2.0 and errors[:, [1, 5]].max() < 5.0


def test_window_estimator_tracks_a_step_quickly_by_restarting_its_window():
    params = PAPER_MOTORS['paper2']
    schedule = parse_schedule('b:+50%:step:24')
    _, voltage = make_excitation('paper', 40.0, 1e-3)
    current, speed = simulate_scheduled(params, schedule, voltage, 1e-3)
    rng = np.random.default_rng(0)
    estimator = WindowEstimator(1e-3, window_s=20.0, refit_interval_s=2.0, cpu_budget=1.0)
    feed(estimator, voltage, add_sensor_noise(current, 0.01, rng),
         add_sensor_noise(speed, 0.01, rng), block=500)
    estimate = estimator.estimate()
    assert estimate.converged, estimate.status
    # 16 s after the step a plain 20 s window would still mix old and new b
    assert estimate.parameters['b'] == pytest.approx(1.5 * params.b, rel=0.02)
    assert estimator.n_restarts >= 1 and estimate.window_s < 20.0


def test_the_published_interval_is_simultaneous_for_the_six_parameters():
    assert simultaneous_sigmas(1) == pytest.approx(3.0)
    assert INTERVAL_SIGMAS == pytest.approx(simultaneous_sigmas(6))
    # six independent intervals all hold as often as one 3-sigma interval
    one = 1.0 - 2.0 * norm.sf(3.0)
    assert (1.0 - 2.0 * norm.sf(INTERVAL_SIGMAS)) ** 6 == pytest.approx(one, rel=1e-12)
    assert 3.4 < INTERVAL_SIGMAS < 3.6
    voltage, current, speed = paper2_data(4.0)
    estimator = WindowEstimator(1e-3, window_s=4.0, refit_interval_s=4.0, cpu_budget=1.0)
    feed(estimator, voltage, current, speed)
    estimate = estimator.estimate()
    assert estimate.interval['Ra'] == pytest.approx(INTERVAL_SIGMAS * estimate.stderr['Ra'])


def outcome(end_s, window_s, ra, ra_stderr):
    values = dict.fromkeys(PARAMETER_NAMES, 1.0)
    errors = dict.fromkeys(PARAMETER_NAMES, 0.01)
    values['Ra'], errors['Ra'] = ra, ra_stderr
    return RefitOutcome(end_s, window_s, values, errors)


def test_disagreement_uses_the_correlation_of_overlapping_windows():
    # a grown window (10 s of 20 s shared): the difference has variance s_a^2 - s_b^2
    ratios = disagreement(outcome(10.0, 10.0, 1.0, 0.02 * np.sqrt(2.0)),
                          outcome(20.0, 20.0, 1.03, 0.02))
    assert ratios['Ra'] == pytest.approx(0.03 / 0.02, rel=1e-3)
    assert ratios['La'] == 0.0
    # windows of 20 s shifted by 2 s: variance 2 s^2 (1 - 18 / 20)
    ratios = disagreement(outcome(20.0, 20.0, 1.0, 0.02), outcome(22.0, 20.0, 1.01, 0.02))
    assert ratios['Ra'] == pytest.approx(0.01 / (0.02 * np.sqrt(0.2)), rel=1e-3)
    # disjoint windows: independent
    ratios = disagreement(outcome(10.0, 5.0, 1.0, 0.03), outcome(20.0, 5.0, 1.05, 0.04))
    assert ratios['Ra'] == pytest.approx(1.0, rel=1e-3)


def test_converged_is_false_while_the_motor_drifts_and_true_when_it_is_steady():
    """The last refits must agree within their errors: a ramp is not converged, steady is."""
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('paper', 40.0, 1e-3)
    rng = np.random.default_rng(3)
    for text, drifting in (('', False), ('Ra:+10%:ramp:16:40', True)):
        current, speed = simulate_scheduled(params, parse_schedule(text), voltage, 1e-3)
        estimator = WindowEstimator(1e-3, window_s=10.0, refit_interval_s=2.0, cpu_budget=1.0)
        estimates = []
        noisy_current = add_sensor_noise(current, 0.01, rng)
        noisy_speed = add_sensor_noise(speed, 0.01, rng)
        for start in range(0, voltage.size, 2000):
            part = slice(start, start + 2000)
            estimator.update(voltage[part], noisy_current[part], noisy_speed[part])
            estimates.append(estimator.estimate())
        late = [e for e in estimates if e.time_s >= 24.0]
        if drifting:
            assert not any(e.converged for e in late), [(e.time_s, e.status) for e in late]
            assert any('drifting' in e.status for e in late), [e.status for e in late]
        else:
            # the agreement uses uniform information per second, which a paper excitation
            # only roughly has: a rare refit (1-2 % on 10 s windows) is flagged needlessly
            flagged = [e.status for e in estimates if not e.converged]
            assert len(flagged) <= 1 and all('drifting' in text for text in flagged), flagged


def test_window_estimator_estimates_a_load_torque():
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('paper', 10.0, 1e-3)
    current, speed = simulate_scheduled(params, parse_schedule('load_torque:+0.3:step:0'),
                                        voltage, 1e-3)
    estimator = WindowEstimator(1e-3, window_s=10.0, refit_interval_s=10.0, cpu_budget=1.0)
    feed(estimator, voltage, current, speed, block=500)
    estimate = estimator.estimate()
    assert estimate.effects[LOAD_TORQUE] == pytest.approx(0.3, rel=1e-4)
    assert estimate.parameters['Mc'] == pytest.approx(params.Mc, rel=1e-4)


def test_the_window_grows_from_the_start_up_to_window_s():
    voltage, current, speed = paper2_data(6.0)
    estimator = WindowEstimator(1e-3, window_s=4.0, refit_interval_s=1.0, cpu_budget=1.0)
    lengths = []
    for start in range(0, voltage.size, 1000):
        part = slice(start, start + 1000)
        estimator.update(voltage[part], current[part], speed[part])
        lengths.append(estimator.estimate().window_s)
    assert lengths[1:] == pytest.approx([2.0, 3.0, 4.0, 4.0, 4.0])
    assert np.isnan(lengths[0])  # less than min_window_s (2 s): no fit yet


def test_window_estimator_survives_gaps_nan_and_bad_data():
    params = PAPER_MOTORS['paper2']
    voltage, current, speed = paper2_data(8.0)
    current = current.copy()
    current[3000:3010] = np.nan  # non-finite samples are a gap
    estimator = WindowEstimator(1e-3, window_s=8.0, refit_interval_s=8.0, cpu_budget=1.0)
    feed(estimator, voltage[:5000], current[:5000], speed[:5000])
    estimator.break_continuity()
    feed(estimator, voltage[5400:], current[5400:], speed[5400:])
    estimator.flush()
    errors = relative_errors_pct(estimator.estimate().parameters, params)
    assert max(errors.values()) < 1e-3, errors
    with pytest.raises(ValueError):
        estimator.update([1.0, 2.0], [1.0], [1.0, 2.0])
    # data that are no motor: the fit fails, the estimator says so and carries on
    junk = WindowEstimator(1e-3, window_s=2.0, refit_interval_s=2.0, min_window_s=1.0,
                           cpu_budget=1.0)
    junk.update(np.zeros(3000), np.ones(3000), -np.ones(3000))
    estimate = junk.estimate()
    assert not estimate.converged and estimate.status
    assert all(np.isnan(value) for value in estimate.parameters.values())


def test_window_estimator_reports_a_failing_worker_and_carries_on():
    voltage, current, speed = paper2_data(6.0)

    def broken(job):
        raise RuntimeError('worker gone')
    estimator = WindowEstimator(1e-3, window_s=4.0, refit_interval_s=2.0, submit=broken)
    feed(estimator, voltage[:3000], current[:3000], speed[:3000])
    assert 'worker gone' in estimator.estimate().status
    assert estimator.n_failures == 1

    def failing(job):
        future = Future()
        future.set_exception(MemoryError('out of memory'))
        return future
    estimator.submit = failing
    feed(estimator, voltage[3000:], current[3000:], speed[3000:])
    estimate = estimator.estimate()
    assert 'out of memory' in estimate.status and not estimate.converged

    def inline(job):
        future = Future()
        from dcmotor_id.streaming.online import refit_window
        future.set_result(refit_window(job))
        return future
    estimator.submit = inline
    feed(estimator, voltage, current, speed)
    assert estimator.estimate().converged


def test_the_refits_respect_the_cpu_budget():
    voltage, current, speed = paper2_data(30.0)
    estimator = WindowEstimator(1e-3, refit_interval_s=0.5, cpu_budget=0.05)
    feed(estimator, voltage, current, speed, block=200)
    assert estimator.cpu_s <= 0.05 * 30.0 + estimator._last_cpu_s + 0.1


def test_make_estimator_builds_both_methods():
    assert isinstance(make_estimator('window', 1e-3, window_s=5.0, memory_s=3.0),
                      WindowEstimator)
    assert isinstance(make_estimator('rls', 1e-3, window_s=5.0, memory_s=3.0), RlsEstimator)
    with pytest.raises(ValueError):
        make_estimator('kalman', 1e-3)


@pytest.mark.slow
def test_refits_in_a_process_of_their_own():
    from dcmotor_id.streaming.online import RefitProcess
    voltage, current, speed = paper2_data(4.0)
    process = RefitProcess()
    try:
        estimator = WindowEstimator(1e-3, window_s=4.0, refit_interval_s=4.0, submit=process)
        feed(estimator, voltage, current, speed)
        estimator.wait(timeout_s=120.0)
        assert estimator.estimate().converged
    finally:
        process.shutdown()


# --------------------------------------------------------------------------- schedule
def test_schedule_parses_and_applies_changes():
    params = PAPER_MOTORS['paper2']
    schedule = parse_schedule('Ra:+25%:ramp:10:70; b:+50%:step:30;load_torque:+0.3:step:5')
    motor, load = schedule.at(params, 40.0)
    assert motor.Ra == pytest.approx(params.Ra * 1.125) and motor.b == pytest.approx(0.45)
    assert load == pytest.approx(0.3) and motor.J == params.J
    motor, load = schedule.at(params, 0.0)
    assert motor == params and load == 0.0
    assert not parse_schedule('') and not parse_schedule(' ; ')
    for bad in ('Rx:+1%:step:1', 'Ra:+1%:jump:1', 'Ra:+1%:ramp:5', 'load_torque:+5%:step:1',
                'Ra:+1%:ramp:5:2', 'Ra:abc:step:1', 'Ra:+1%'):
        with pytest.raises(ValueError, match='schedule entry'):
            parse_schedule(bad)


def test_scheduled_simulation_without_changes_is_the_plain_one():
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('paper', 2.0, 1e-3)
    plain = simulate_motor(params, voltage, 1e-3)
    scheduled = simulate_scheduled(params, parse_schedule(''), voltage, 1e-3)
    np.testing.assert_allclose(scheduled[0], plain[0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(scheduled[1], plain[1], rtol=1e-9, atol=1e-9)
