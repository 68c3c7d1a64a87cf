"""Analytic output sensitivities (simulation.sensitivity) against central finite differences."""

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators.base import ExogenousTerm, StateTerm
from dcmotor_id.identification.estimators.normal_equations import NormalEquations
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.estimators.uncertainty import block_edges
from dcmotor_id.simulation import simulate_mechanical, simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

MOTOR = PAPER_MOTORS['paper2']
DT = 1e-3


def record_of(kind, duration_s, amplitude_v=None, frequency_hz=None, x0=(0.0, 0.0)):
    """Simulate a noise-free record of motor 2 (the data only matter through the input here)."""
    t, voltage = make_excitation(kind, duration_s, DT, amplitude_v=amplitude_v,
                                 frequency_hz=frequency_hz)
    current, speed = simulate_motor(MOTOR, voltage, DT, x0)
    return Record(t, current, voltage, speed, source=kind)


def events(speed):
    """Return (reversals, samples at rest) of a simulated speed."""
    signs = np.sign(speed)
    moving = signs[signs != 0]
    return int(np.sum(moving[1:] != moving[:-1])), int(np.sum(speed == 0.0))


def finite_differences(model, values, state, names):
    """Central differences of every output w.r.t. every parameter and initial state."""
    columns = []
    n_state = len(model.outputs)
    for position, name in enumerate(list(names) + [f'x{c}' for c in range(n_state)]):
        if name in values:
            step = 1e-6 * max(abs(values[name]), 1e-3)
        else:
            step = 1e-6 * max(abs(state[position - len(names)]), 1.0)

        def run(sign, name=name, position=position, step=step):
            moved, start = dict(values), np.array(state, dtype=float)
            if name in moved:
                moved[name] += sign * step
            else:
                start[position - len(names)] += sign * step
            out = model.simulate(moved, 0, start)
            return np.column_stack([out[channel] for channel in model.outputs])
        columns.append((run(1.0) - run(-1.0)) / (2.0 * step))
    return np.stack(columns, axis=2)


def assert_sensitivities_match(model, values, state, tolerance=2e-5):
    equations = NormalEquations(model)
    assert NormalEquations.supports(model)
    result = equations.record(values, 0, state, np.ones(len(model.outputs)), store=True)
    simulated = model.simulate(values, 0, state)
    for position, channel in enumerate(model.outputs):
        offset = simulated[channel] - result.trajectory[:, position, 0]
        # The states are those of the simulator, bit for bit (up to the output terms).
        assert np.ptp(offset) < 1e-12 * max(1.0, np.max(np.abs(simulated[channel])))
    numeric = finite_differences(model, values, state, equations.names)
    analytic = result.trajectory[:, :, 1:].copy()
    for term in model.terms:
        if term.channel in ('current', 'speed'):
            column = equations.names.index(term.name)
            analytic[:, model.outputs.index(term.channel), column] += term.regressors[0]
    for column in range(numeric.shape[2]):
        for channel in range(numeric.shape[1]):
            reference = numeric[:, channel, column]
            scale = max(np.max(np.abs(reference)), 1e-12)
            error = np.max(np.abs(analytic[:, channel, column] - reference)) / scale
            assert error < tolerance, (column, channel, error)


@pytest.mark.parametrize('kind, amplitude, frequency, x0', [
    # Initial speeds off zero: at rest and stuck, the outputs are not differentiable in w0.
    ('paper', None, None, (0.3, -0.2)),          # reversals of the paper's excitation
    ('sine', 4.0, 2.0, (0.2, 0.5)),             # stick phases around every reversal
    ('prbs', 3.0, 20.0, (0.0, 1.0)),            # many short reversals and sticks
    ('sawtooth', 3.0, 1.0, (0.0, -0.3)),        # slow ramps through the stick band
])
def test_full_motor_sensitivities_through_reversals_and_sticks(kind, amplitude, frequency, x0):
    record = record_of(kind, 3.0, amplitude, frequency, x0)
    reversals, at_rest = events(record.speed)
    if kind != 'paper':
        assert reversals >= 3 and at_rest >= 10
    model = OutputErrorModel([record])
    assert_sensitivities_match(model, MOTOR.as_dict(derived=False), np.array(x0))


def test_linear_and_friction_terms():
    record = record_of('sine', 3.0, 8.0, 1.0)
    n = len(record)
    ramp = np.linspace(-1.0, 1.0, n)
    terms = (ExogenousTerm('load', 'torque', (np.ones(n),), scale=0.1, initial=0.2),
             ExogenousTerm('volts', 'voltage', (ramp,), scale=0.1, initial=0.3),
             ExogenousTerm('offset', 'current', (np.ones(n),), scale=0.1, initial=0.05),
             StateTerm('asym', 'state', (np.ones(n),), scale=0.1, initial=0.1,
                       field='coulomb_delta_Nm'))
    model = OutputErrorModel([record], terms=terms)
    values = {**MOTOR.as_dict(derived=False), 'load': 0.2, 'volts': 0.3, 'offset': 0.05,
              'asym': 0.1}
    assert_sensitivities_match(model, values, np.array([0.1, 0.4]))


def test_mechanical_only_sensitivities():
    t, voltage = make_excitation('sine', 3.0, DT, amplitude_v=5.0, frequency_hz=2.0)
    current, _ = simulate_motor(MOTOR, voltage, DT)
    held = np.append(0.5 * (current[:-1] + current[1:]), current[-1])
    speed = simulate_mechanical(MOTOR.J, MOTOR.b, MOTOR.Mc, MOTOR.CPhi * held, DT)
    assert events(speed)[1] > 10
    model = OutputErrorModel([Record(t, current, None, speed)], torque_constant=MOTOR.CPhi)
    assert_sensitivities_match(model, {'J': MOTOR.J, 'b': MOTOR.b, 'Mc': MOTOR.Mc},
                               np.array([0.5]))


def test_accumulated_sums_are_those_of_the_jacobian():
    record = record_of('prbs', 2.0, 3.0, 20.0)
    rng = np.random.default_rng(1)
    noisy = Record(record.time_s, record.current + 0.01 * rng.standard_normal(len(record)),
                   record.voltage, record.speed + 0.1 * rng.standard_normal(len(record)))
    model = OutputErrorModel([noisy])
    equations = NormalEquations(model)
    values = MOTOR.replace(Ra=1.7).as_dict(derived=False)
    weights = np.array([1 / 0.01, 1 / 0.1])
    result = equations.record(values, 0, [0.0, 0.0], weights, store=True)
    rows = (result.trajectory[:, :, 1:] * weights[None, :, None])
    residual = (result.trajectory[:, :, 0] - np.column_stack([noisy.current, noisy.speed])) \
        * weights
    jac = rows.reshape(-1, rows.shape[2])
    r = residual.reshape(-1)
    assert result.cost == pytest.approx(float(r @ r), rel=1e-12)
    np.testing.assert_allclose(result.hessian, jac.T @ jac, rtol=1e-10, atol=0)
    np.testing.assert_allclose(result.gradient, jac.T @ r, rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(jac.T @ r)))
    edges = block_edges(len(noisy))
    assert result.blocks.shape[0] >= 32
    per_sample = np.einsum('kcj,kc->kj', rows, residual)
    blocks = np.add.reduceat(per_sample, edges[:-1], axis=0)
    np.testing.assert_allclose(result.blocks, blocks, rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(blocks)))
    np.testing.assert_allclose(result.blocks.sum(axis=0), result.gradient, rtol=1e-9,
                               atol=1e-12 * np.max(np.abs(blocks)))
    cost_only = equations.record(values, 0, [0.0, 0.0], weights, with_sens=False)
    assert cost_only.cost == result.cost


def test_variants_outside_the_kernel_are_refused():
    record = record_of('sine', 1.0, 8.0, 1.0)
    n = len(record)
    stribeck = StateTerm('stribeck', 'state', (np.ones(n),), scale=0.1,
                         field='stribeck_excess_Nm', fixed=(('stribeck_velocity_rad_s', 1.0),))
    assert not NormalEquations.supports(OutputErrorModel([record], terms=(stribeck,)))
    assert NormalEquations.supports(OutputErrorModel([record]))


@pytest.mark.parametrize('rho', [0.0, 0.7])
@pytest.mark.parametrize('states', [1, 2])
def test_position_kernel_equals_the_integral_of_the_stored_speed(rho, states):
    """
    The position's normal equations in one pass are those of the integral and its whitening.

    The reference is the integral of the speed and of its sensitivities
    (:func:`~dcmotor_id.identification.error_model.criterion.integrate_speed`), whitened
    (:func:`~dcmotor_id.identification.error_model.criterion.whiten`) and multiplied out as
    matrices.
    """
    from dcmotor_id.identification.error_model.criterion import integrate_speed, whiten
    from dcmotor_id.simulation.compiled import kernel

    rng = np.random.default_rng(3)
    n_samples, m, weight, p0 = 5_000, 5, 3.0, 0.25
    trajectory = np.cumsum(rng.standard_normal((n_samples, states, m + 1)), axis=0)
    measured = integrate_speed(trajectory[:, -1, 0], DT, p0) + rng.standard_normal(n_samples)
    edges = block_edges(n_samples)
    error = whiten(integrate_speed(trajectory[:, -1, 0], DT, p0) - measured, rho)
    rows = np.empty((n_samples, m + 1))
    rows[:, :m] = integrate_speed(trajectory[:, -1, 1:], DT, 0.0)
    rows[:, m] = 1.0
    rows = whiten(rows, rho) * weight
    residual = error * weight
    hessian, gradient, blocks, total, cost = kernel('position_kernel')(
        trajectory, DT, p0, measured, rho, weight, True, edges)
    assert total == pytest.approx(error @ error, rel=1e-12)
    assert cost == pytest.approx(residual @ residual, rel=1e-12)
    np.testing.assert_allclose(hessian, rows.T @ rows, rtol=1e-10)
    np.testing.assert_allclose(gradient, rows.T @ residual, rtol=1e-9,
                               atol=1e-12 * np.abs(rows).sum() * np.abs(residual).max())
    np.testing.assert_allclose(blocks, np.add.reduceat(rows * residual[:, None], edges[:-1],
                                                       axis=0),
                               rtol=1e-9, atol=1e-12 * np.abs(rows * residual[:, None]).sum())
    # Without the sensitivities: the sums only.
    hessian, gradient, blocks, total_only, cost_only = kernel('position_kernel')(
        trajectory, DT, p0, measured, rho, weight, False, edges)
    assert (total_only, cost_only) == (total, cost)
    assert not hessian.any() and not gradient.any() and not blocks.any()
