"""
The EMPS score's fits on simulated data: the position-output fit and the friction per record.

Fast: a short EMPS-like record simulated with known parameters (no measured data needed).
"""

import numpy as np
import pytest
# The study lives beside the package (studies/), importable from the repository root.
from studies.emps import (emps_model, friction_by_record, lagged_input,
                          position_output_fit)

from dcmotor_id.core.records import Record
from dcmotor_id.identification.validate import simulate

GTAU = 35.15
TRUTH = {'M': 92.0, 'Fv': 186.0, 'Fc': 22.5}
LOAD_N = 0.8
DELTA_N_S_M = -43.0
EFFECTS = [{'name': 'load_torque', 'parameters': {'torque_Nm': LOAD_N}},
           {'name': 'viscous_asymmetry', 'parameters': {'delta_Nm_s': DELTA_N_S_M}}]


def _record(lag_s=0.0, seconds=6.0):
    """Simulate the carriage from a force that drives it back and forth (1 kHz)."""
    dt = 1e-3
    time_s = np.arange(int(seconds / dt)) * dt
    force = 70.0 * np.sign(np.sin(2 * np.pi * time_s / 1.5)) + 15.0 * np.sin(
        2 * np.pi * time_s / 0.37)
    command = Record(time_s=time_s, current=force / GTAU, position=np.zeros_like(time_s),
                     speed=np.zeros_like(time_s), source='simulated')
    simulated = simulate(emps_model(TRUTH, GTAU, EFFECTS), lagged_input(command, lag_s),
                         [0.0])
    return command.replace(position=simulated['position'], speed=simulated['speed'])


def _effect(model, name):
    return next(e['parameters'] for e in model.effects if e['name'] == name)


def test_position_output_fit_recovers_the_asymmetric_friction():
    fit = position_output_fit(_record(), GTAU, ('load_torque', 'viscous_asymmetry'))
    p = fit.model.parameters
    assert p['J'] == pytest.approx(TRUTH['M'], rel=0.01)
    assert p['b'] == pytest.approx(TRUTH['Fv'], rel=0.01)
    assert p['Mc'] == pytest.approx(TRUTH['Fc'], rel=0.01)
    assert _effect(fit.model, 'viscous_asymmetry')['delta_Nm_s'] == pytest.approx(
        DELTA_N_S_M, rel=0.02)
    assert _effect(fit.model, 'load_torque')['torque_Nm'] == pytest.approx(LOAD_N, abs=0.1)
    assert fit.input_lag_s == 0.0
    assert fit.training_rmse_m < 1e-5


def test_position_output_fit_recovers_a_lag_of_the_force():
    lag = 0.005
    fit = position_output_fit(_record(lag), GTAU, ('load_torque', 'viscous_asymmetry'),
                              input_lag=True)
    assert fit.input_lag_s == pytest.approx(lag, rel=0.05)
    assert fit.model.parameters['J'] == pytest.approx(TRUTH['M'], rel=0.01)


def test_lagged_input_is_a_first_order_lag():
    time_s = np.arange(200) * 1e-3
    step = Record(time_s=time_s, current=np.where(time_s >= 0.05, 1.0, 0.0), source='step')
    lagged = lagged_input(step, 0.01).current
    assert lagged[49] == 0.0
    # one time constant after the step: 1 - exp(-1) (the input is held over each sample)
    assert lagged[50 + 10] == pytest.approx(1 - np.exp(-1), abs=1e-9)
    assert lagged_input(step, 0.0) is step


def test_friction_by_record_recovers_direction_dependent_friction():
    record = _record(seconds=12.0)
    friction = friction_by_record(record, GTAU)
    assert friction['M'] == pytest.approx(TRUTH['M'], rel=0.03)
    assert friction['Fv_pos'] == pytest.approx(TRUTH['Fv'] + DELTA_N_S_M, rel=0.05)
    assert friction['Fv_neg'] == pytest.approx(TRUTH['Fv'] - DELTA_N_S_M, rel=0.05)
    # the load torque shifts the two Coulomb levels: Fc + T forward, Fc - T backward
    assert friction['Fc_pos'] == pytest.approx(TRUTH['Fc'] + LOAD_N, rel=0.05)
    assert friction['Fc_neg'] == pytest.approx(TRUTH['Fc'] - LOAD_N, rel=0.05)
