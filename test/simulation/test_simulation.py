"""The exact hybrid simulator against an adaptive Runge-Kutta reference, and its stick-slip."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from dcmotor_id.core.model import PAPER_MOTORS, state_matrix
from dcmotor_id.simulation import MotorStepper, simulate_mechanical, simulate_motor, zoh_matrices
from dcmotor_id.simulation.excitation import make_excitation


def reference_simulation(params, voltage, dt, x0=(0.0, 0.0)):
    """Integrate sample by sample with DOP853, restarting at every zero of the speed."""
    p = params
    x = np.array(x0, dtype=float)
    out = [x.copy()]
    for u in voltage[:-1]:
        t = 0.0
        while t < dt * (1 - 1e-12):
            if x[1] == 0.0 and abs(p.CPhi * x[0]) <= p.Mc:
                def stuck(_, y, u=u):
                    return [(u - p.Ra * y[0]) / p.La]

                def breakaway(_, y):
                    return abs(p.CPhi * y[0]) - p.Mc
                breakaway.terminal = True
                sol = solve_ivp(stuck, (t, dt), [x[0]], method='DOP853', rtol=1e-12,
                                atol=1e-14, events=breakaway)
                x = np.array([sol.y[0, -1], 0.0])
                t = sol.t[-1]
                if sol.status != 1:
                    break
            sign = np.sign(x[1]) if x[1] != 0.0 else np.sign(p.CPhi * x[0])

            def slide(_, y, u=u, sign=sign):
                return [(u - p.Ra * y[0] - p.CPhi * y[1]) / p.La,
                        (p.CPhi * y[0] - p.b * y[1] - p.Mc * sign) / p.J]

            def reversal(time, y, start=t, sign=sign):
                return y[1] if time > start else sign
            reversal.terminal = True
            sol = solve_ivp(slide, (t, dt), x, method='DOP853', rtol=1e-12, atol=1e-14,
                            events=reversal)
            x = sol.y[:, -1].copy()
            t = sol.t[-1]
            if sol.status == 1:
                x[1] = 0.0
        out.append(x.copy())
    return np.array(out)


@pytest.mark.parametrize('motor', ['paper1', 'paper2'])
@pytest.mark.parametrize('kind', ['sawtooth', 'sine'])
def test_matches_reference_through_reversals(motor, kind):
    params = PAPER_MOTORS[motor]
    dt = 1e-3
    _, voltage = make_excitation(kind, 2.5, dt, frequency_hz=1.0)
    current, speed = simulate_motor(params, voltage, dt)
    reference = reference_simulation(params, voltage, dt)
    assert np.sum(np.diff(np.sign(speed)) != 0) >= 2  # the record does reverse
    assert np.max(np.abs(current - reference[:, 0])) < 1e-8 * np.std(reference[:, 0])
    assert np.max(np.abs(speed - reference[:, 1])) < 1e-8 * np.std(reference[:, 1])


def test_sticks_below_breakaway_and_moves_above():
    params = PAPER_MOTORS['paper2']
    dt = 1e-3
    # Stall torque CPhi*u/Ra below Mc: 2 V gives 0.875 N m < 1 N m, the shaft never moves.
    current, speed = simulate_motor(params, np.full(500, 2.0), dt)
    assert np.all(speed == 0.0)
    assert current[-1] == pytest.approx(2.0 / params.Ra, rel=1e-9)
    # 3 V gives 1.31 N m > Mc: it breaks away once the current exceeds Mc/CPhi.
    current, speed = simulate_motor(params, np.full(500, 3.0), dt)
    moving = np.flatnonzero(speed > 0)
    assert moving.size > 0
    first = moving[0]
    assert params.CPhi * current[first - 1] <= params.Mc < params.CPhi * current[first]


def test_steady_state_matches_closed_form():
    params = PAPER_MOTORS['paper1']
    u = 100.0
    _, speed = simulate_motor(params, np.full(20000, u), 1e-3)
    # u = Ra i + CPhi w and CPhi i = b w + Mc at steady state.
    p = params
    expected = (p.CPhi * u / p.Ra - p.Mc) / (p.b + p.CPhi ** 2 / p.Ra)
    assert speed[-1] == pytest.approx(expected, rel=1e-10)


def test_mechanical_matches_closed_form_and_sticks():
    dt = 1e-3
    torque = np.concatenate([np.full(1000, 2.0), np.full(1000, 0.5)])
    speed = simulate_mechanical(0.1, 0.5, 1.0, torque, dt)
    t = np.arange(1, 1001) * dt
    expected = (2.0 - 1.0) / 0.5 * (1 - np.exp(-0.5 / 0.1 * t))
    assert np.allclose(speed[1:1001], expected[:1000], rtol=1e-10, atol=1e-13)
    assert speed[-1] == 0.0  # 0.5 N m < Mc: it decelerates and sticks


def test_stepper_equals_batch():
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('sawtooth', 1.0, 1e-3)
    current, speed = simulate_motor(params, voltage, 1e-3)
    stepper = MotorStepper(params, 1e-3)
    stepped = np.array([stepper.step(u) for u in voltage])
    assert np.allclose(stepped[:-1, 0], current[1:], rtol=0, atol=1e-12 * np.ptp(current))
    assert np.allclose(stepped[:-1, 1], speed[1:], rtol=0, atol=1e-12 * np.ptp(speed))


@pytest.mark.parametrize('motor', ['paper1', 'paper2'])
def test_speed_touching_zero_inside_a_sample(motor):
    # A slight negative speed against a -43 V step: friction first drives the speed up to zero
    # (where the shaft sticks until the current breaks it away negative), but the sliding
    # solution runs through zero and back within the 2 ms sample: the same sign at both ends.
    params = PAPER_MOTORS[motor]
    dt = 2e-3
    _, voltage = make_excitation('sawtooth', 0.2, dt, amplitude_v=43.0, frequency_hz=1.0)
    reference = reference_simulation(params, voltage, dt, (0.0, -1e-6))
    current, speed = simulate_motor(params, voltage, dt, (0.0, -1e-6))
    assert np.max(np.abs(current - reference[:, 0])) < 1e-8 * np.std(reference[:, 0])
    assert np.max(np.abs(speed - reference[:, 1])) < 1e-8 * np.std(reference[:, 1])
    # The solution is continuous in the initial speed.
    _, from_rest = simulate_motor(params, voltage, dt)
    assert np.max(np.abs(speed[1:] - from_rest[1:])) < 1e-9


@pytest.mark.parametrize('motor', ['paper1', 'paper2'])
def test_zoh_matrices_match_the_block_exponential(motor):
    a_matrix = state_matrix(PAPER_MOTORS[motor])
    dt = 1e-3
    block = np.zeros((4, 4))
    block[:2, :2] = a_matrix
    block[:2, 2:] = np.eye(2)
    reference = expm(block * dt)
    ad, gamma = zoh_matrices(a_matrix, dt)
    assert np.allclose(ad, reference[:2, :2], rtol=1e-12, atol=1e-14)
    assert np.allclose(gamma, reference[:2, 2:], rtol=1e-12, atol=1e-16)
    ad1, gamma1 = zoh_matrices([[-0.3 / 0.03]], dt)
    assert ad1[0, 0] == pytest.approx(np.exp(-10.0 * dt), rel=1e-14)
    assert gamma1[0, 0] == pytest.approx(-np.expm1(-10.0 * dt) / 10.0, rel=1e-14)
