"""Levenberg-Marquardt's trials without sensitivities: the same search, fewer kernel passes."""

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators import least_squares
from dcmotor_id.identification.estimators.least_squares import FitError, FitProblem
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.identify import prepare_records
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation


def _reference(evaluate, z, max_evaluations, xtol=1e-8, ftol=1e-8, gtol=1e-8, current=None,
               damping=None):
    """Return the search as it ran before: a trial after an accepted step carried sensitivities."""
    nfev = 0
    if current is None:
        current = evaluate(z, True)
        nfev += 1
    if not np.isfinite(current.cost):
        raise FitError('non-finite residuals at the start')
    scale = np.maximum(np.diag(current.hessian), 0.0)
    mu = 1e-3 if damping is None else damping
    cheap = False
    while nfev < max(int(max_evaluations), 2):
        cost = current.cost
        scale = np.maximum(scale, np.diag(current.hessian))
        if least_squares._stationary(current, gtol):
            return z, current, nfev, True, mu
        step, predicted, small = least_squares._damped_step(current, z, mu, scale, xtol)
        trial = evaluate(z + step, not cheap)
        nfev += 1
        actual = cost - trial.cost if np.isfinite(trial.cost) else -np.inf
        ratio = actual / predicted if predicted > 0.0 else -1.0
        if ratio > 1e-4:
            z = z + step
            if cheap:
                trial = evaluate(z, True)
                nfev += 1
            current = trial
            cheap = False
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
            if (abs(actual) <= ftol * cost and predicted <= ftol * cost) or small:
                return z, current, nfev, True, mu
        else:
            cheap = True
            mu *= 10.0
            if small or mu > 1e16:
                return z, current, nfev, True, mu
    return z, current, nfev, False, mu


@pytest.fixture(scope='module')
def problem():
    """
    Return the output-error problem of a noisy 2 s record, started about 10 % off the truth.

    Its search rejects five steps that follow accepted ones (found by trying a few starts).
    """
    motor = PAPER_MOTORS['paper2']
    t, voltage = make_excitation('paper', 2.0, 1e-3)
    current, speed = simulate_motor(motor, voltage, 1e-3)
    rng = np.random.default_rng(3)
    records = prepare_records([Record(t, add_sensor_noise(current, 0.01, rng), voltage,
                                      add_sensor_noise(speed, 0.01, rng))])
    model = OutputErrorModel(records, None)
    start = {name: value * (0.9 if index % 2 else 1.0 / 0.9)
             for index, (name, value) in enumerate(motor.as_dict(derived=False).items())}
    return FitProblem(model, start, 'estimate', None, None, True)


def _logged(problem):
    """Return an evaluator that logs ``(point, with_sens)`` and the log."""
    evaluate, log = problem.evaluator(problem.first_noise()), []

    def logging(point, with_sens):
        log.append((point.copy(), with_sens))
        return evaluate(point, with_sens)
    return logging, log


@pytest.mark.parametrize('budget', [2, 3, 5, 8, 13, 17, 21, 100])
def test_the_search_takes_the_same_steps_and_budget_as_with_sensitivities_on_trials(
        problem, budget):
    new_evaluate, new_log = _logged(problem)
    old_evaluate, old_log = _logged(problem)
    new = least_squares.levenberg_marquardt(new_evaluate, problem.z0, budget)
    old = _reference(old_evaluate, problem.z0, budget)
    assert np.array_equal(new[0], old[0])
    assert new[1].cost == old[1].cost
    assert np.array_equal(new[1].hessian, old[1].hessian)
    assert np.array_equal(new[1].gradient, old[1].gradient)
    assert new[2:] == old[2:]
    # A sensitivity pass only where the search stands (the start and accepted points).
    sensitivity_points = [point for point, with_sens in new_log if with_sens]
    assert sum(with_sens for _, with_sens in old_log) >= len(sensitivity_points)
    accepted = [problem.z0] + [point for point, with_sens in old_log if with_sens]
    for point in sensitivity_points:
        assert any(np.array_equal(point, place) for place in accepted)


def test_rejected_trials_cost_no_sensitivity_pass(problem):
    new_evaluate, new_log = _logged(problem)
    old_evaluate, old_log = _logged(problem)
    least_squares.levenberg_marquardt(new_evaluate, problem.z0, 100)
    _reference(old_evaluate, problem.z0, 100)
    old_passes = sum(with_sens for _, with_sens in old_log)
    new_passes = sum(with_sens for _, with_sens in new_log)
    # The start and one pass per accepted step; before, also every rejected step that followed
    # an accepted one.
    assert new_passes < old_passes
