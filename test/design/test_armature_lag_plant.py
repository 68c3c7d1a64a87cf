"""
A voltage-to-speed design's speed loop includes the identified armature lag (issue 31).

Paper motor 2's armature lag ``Ta = La/Ra = 10 ms`` puts a pole near 16 Hz into the voltage-to-
speed plant ``1/(Ta kA s^2 + (kA + Ta Ra b/CPhi) s + kV)``. A speed loop designed on the first-
order plant ``(kA + Ta Ra b/CPhi) s + kV`` stated 60 deg of phase margin but had 41 (8 Hz) and
26 deg (15 Hz) on the true motor, and overshot a step by 28 and 50 % (``bench/design_results.md``
measured 48-72 % with the static feedforward). The design's plant now holds the lag: the stated
margin and step overshoot are those of the true motor, and a note gives the overshoot of a
reference step with the static feedforward (the integral gives back what it gathered on the
rise: 28-41 % at the same margins).
"""

from dataclasses import replace
import re

import control
import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.design.control import design_controller
from dcmotor_id.design.export import statespace_dict
from dcmotor_id.design.loops import margins, motor_model
from dcmotor_id.design.plant import Motor, motor_from_result
from dcmotor_id.simulation import MotorStepper

DT = 1e-3
MOTORS = {'paper2': PAPER_MOTORS['paper2'],
          'paper2, CPhi 1.2': replace(PAPER_MOTORS['paper2'], CPhi=1.2)}
#: Percentage points the exact simulation's overshoot may exceed the stated one by. The
#: simulator is exact under the held voltage and, at a speed that keeps its sign, the Coulomb
#: friction is a constant torque the integral holds: the simulated step is the design's
#: sampled linear loop, up to the simulator's rounding (measured: below 0.01 point); 0.1 point
#: leaves room for that and nothing else (the first-order design misses by 19-44 points).
OVERSHOOT_SLACK_PCT = 0.1


def voltage_speed_result(motor):
    """Return the voltage-to-speed identify result of a motor at its true values."""
    ka = motor.Ra * motor.J / motor.CPhi
    gain = ka + motor.La * motor.b / motor.CPhi
    return {'mode': 'voltage_speed',
            'parameters': {'kS': motor.Ra * motor.Mc / motor.CPhi,
                           'kV': motor.CPhi + motor.Ra * motor.b / motor.CPhi, 'kA': ka},
            'stderr': {'kS': 0.01, 'kV': 1e-3, 'kA': 0.075 * ka},
            'combined': {'armature_time_constant_s': {'value': motor.La / motor.Ra,
                                                      'stderr': 1e-4},
                         'acceleration_gain': {'value': gain, 'stderr': 1e-3 * gain}}}


def true_open_loop(motor, made):
    """Return the designed Tustin PI times the true motor's sampled voltage-to-speed plant."""
    full = Motor(motor.as_dict(derived=False), {}, 'full')
    plant = control.c2d(motor_model(full)[1, 0], DT, method='zoh')  # u -> w, back-EMF in
    loop = made['speed_loop']
    pi = control.c2d(control.tf([loop['kp'], loop['ki']], [1.0, 0.0]), DT, method='tustin')
    return pi * plant


def simulated_overshoot_pct(motor, made, low=20.0, high=40.0, feedforward=False):
    """
    Return the overshoot [%] of the designed PI's speed step on the exact simulator.

    From the steady state at ``low``: the PI's integral holds its voltage, or (with the static
    feedforward ``kS sgn(w_ref) + kV w_ref`` added) starts at zero.
    """
    pi, ff = made['speed_loop']['discrete'], made['feedforward']
    i0 = (motor.b * low + motor.Mc) / motor.CPhi
    stepper = MotorStepper(motor, DT, (i0, low))
    static = ff['kS'] + ff['kV'] * high if feedforward else 0.0
    integral = 0.0 if feedforward else motor.Ra * i0 + motor.CPhi * low
    w, previous, peak = low, 0.0, low
    for _ in range(int(round(2.0 / DT))):
        error = high - w
        integral += pi['q0'] * error + pi['q1'] * previous
        previous = error
        _, w = stepper.step(static + integral)
        peak = max(peak, w)
    return 100.0 * (peak - high) / (high - low)


@pytest.mark.parametrize('name', MOTORS)
@pytest.mark.parametrize('bandwidth', [8.0, 15.0])
def test_the_stated_margin_and_overshoot_hold_on_the_true_motor(name, bandwidth):
    motor = MOTORS[name]
    made = design_controller(voltage_speed_result(motor), speed_bandwidth_hz=bandwidth,
                             sample_period_s=DT)
    stated = made['nominal']['speed']
    assert stated['bandwidth_hz'] == pytest.approx(bandwidth, rel=0.01)
    assert stated['phase_margin_deg'] == pytest.approx(60.0, abs=0.1)
    assert margins(true_open_loop(motor, made))['phase_margin_deg'] == pytest.approx(
        stated['phase_margin_deg'], abs=0.5)
    overshoot = simulated_overshoot_pct(motor, made)
    assert overshoot <= stated['step_overshoot_pct'] + OVERSHOOT_SLACK_PCT
    assert stated['step_overshoot_pct'] < 15.0  # a 60 deg loop, not the 28-50 % of before
    said = [re.search(r'by ([0-9.]+) % with the static feedforward', note)
            for note in made['notes']]
    figures = [float(found.group(1)) for found in said if found]
    assert len(figures) == 1
    assert simulated_overshoot_pct(motor, made, feedforward=True) == pytest.approx(
        figures[0], abs=0.06)  # the note's three digits


def test_a_bandwidth_beyond_the_lag_is_lowered_with_a_note():
    motor = MOTORS['paper2']
    made = design_controller(voltage_speed_result(motor), speed_bandwidth_hz=60.0,
                             sample_period_s=DT)
    reached = made['nominal']['speed']['bandwidth_hz']
    assert 10.0 < reached < 25.0 and made['requested']['speed_bandwidth_hz'] == 60.0
    said = [note for note in made['notes'] if note.startswith('--speed-bandwidth 60 Hz')]
    assert len(said) == 1 and f'{reached:.3g} Hz' in said[0]
    # the PI keeps its integral action: its zero a decade below the crossover
    crossover = 2 * np.pi * made['speed_loop']['design_crossover_hz']
    assert made['speed_loop']['ti_s'] * crossover == pytest.approx(10.0, rel=0.05)
    assert margins(true_open_loop(motor, made))['phase_margin_deg'] == pytest.approx(
        60.0, abs=0.5)
    # without the lag (the first-order plant) 60 Hz is met: no lowering, no note
    first_order = dict(voltage_speed_result(motor), combined={})
    plain = design_controller(first_order, speed_bandwidth_hz=60.0, sample_period_s=DT)
    assert plain['nominal']['speed']['bandwidth_hz'] == pytest.approx(60.0, rel=0.01)
    assert not any(note.startswith('--speed-bandwidth') for note in plain['notes'])


def test_the_exported_model_is_the_true_voltage_to_speed_plant():
    motor = MOTORS['paper2']
    exported = statespace_dict(motor_from_result(voltage_speed_result(motor)))
    assert exported['states'] == ['w', 'a'] and exported['units']['Ta'] == 's'
    model = control.ss(exported['A'], exported['B'], exported['C'], exported['D'])
    truth = motor_model(Motor(motor.as_dict(derived=False), {}, 'full'))[1, 0]
    assert np.sort_complex(model.poles()) == pytest.approx(np.sort_complex(truth.poles()),
                                                           rel=1e-9)
    assert float(model.dcgain()) == pytest.approx(float(truth.dcgain()), rel=1e-9)
