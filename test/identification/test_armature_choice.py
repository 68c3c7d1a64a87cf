"""The armature's choice: the quasi-static equation unless the full one fits the current better."""

from functools import partial
from types import SimpleNamespace
import warnings

import numpy as np
import pytest

from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline import armature
from dcmotor_id.simulation.lab_scenarios import simulate_drive, step_levels

DT = 1e-3


def stairs_record(la_over_dt: float) -> tuple[MotorParameters, Record]:
    """Return a 12 V motor with La/Ra of ``la_over_dt`` samples on voltage stairs at 1 kHz."""
    ra, cphi, tau_m, volts = 2.0, 0.05, 0.05, 12.0
    motor = MotorParameters(Ra=ra, La=la_over_dt * DT * ra, CPhi=cphi, J=tau_m * cphi ** 2 / ra,
                            b=0.05 * cphi ** 2 / ra, Mc=0.01 * cphi * volts / ra)
    rng = np.random.default_rng(0)
    command = volts * np.asarray(step_levels([0.5, -1.0, 0.25, 0.75, -0.5, 1.0, -0.25, -0.75],
                                             0.2, DT))
    out = simulate_drive(motor, command, DT)
    current = out['current'] + rng.normal(0.0, 0.005 * volts / ra, command.size)
    speed = out['speed'] + rng.normal(0.0, 0.005 * volts / cphi, command.size)
    return motor, Record(np.arange(command.size) * DT, current=current, voltage=command,
                         speed=speed)


def identified(record: Record):
    """Identify without the discovery loop."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        return identify(prepare_records([record]), discover=False)


@pytest.mark.parametrize('choice', armature.ARMATURE_CHOICES)
def test_la_well_above_the_sample_period_keeps_the_full_equation(monkeypatch, choice):
    monkeypatch.setattr(armature, 'quasi_kept', partial(armature.quasi_kept, choice=choice))
    motor, record = stairs_record(4.0)
    result = identified(record)
    assert 'La' not in result.upper_bounds and 'La' not in result.not_identifiable
    assert result.parameters['La'] == pytest.approx(motor.La, rel=0.02)


@pytest.mark.parametrize('choice', armature.ARMATURE_CHOICES)
def test_la_far_below_the_sample_period_gets_the_quasi_static_equation(monkeypatch, choice):
    monkeypatch.setattr(armature, 'quasi_kept', partial(armature.quasi_kept, choice=choice))
    motor, record = stairs_record(0.02)
    result = identified(record)
    assert motor.La <= result.upper_bounds['La']
    assert 'upper bound' in result.not_identifiable['La']
    assert result.parameters['Ra'] == pytest.approx(motor.Ra, rel=0.01)


@pytest.mark.parametrize('choice, quasi_static', [('current-error-margin', True),
                                                  ('likelihood-ratio', False)])
def test_a_la_of_a_third_of_a_sample_is_resolved_by_the_ratio_not_by_the_margin(
        monkeypatch, choice, quasi_static):
    # La/Ra 0.3 samples: the quasi-static current error is within the margin (1.25 full +
    # 0.5 points), but the full equation fits the current significantly better.
    motor, record = stairs_record(0.3)
    seen = []
    original = armature.quasi_kept

    def spy(fit, refit, models, initial_state):
        seen.append((fit.errors['current_nrmse_pct'], refit[1]['current_nrmse_pct'],
                     armature.armature_likelihood_ratio(fit.estimate, refit[0], fit.models,
                                                        models)))
        return original(fit, refit, models, initial_state, choice)
    monkeypatch.setattr(armature, 'quasi_kept', spy)
    result = identified(record)
    (full, quasi, (ratio, needed)), = seen
    assert quasi <= 1.25 * full + 0.5 and ratio > needed
    assert ('La' in result.upper_bounds) == quasi_static
    assert 'below the sample period' in result.not_identifiable['La']
    if not quasi_static:
        assert result.parameters['La'] == pytest.approx(motor.La, rel=0.02)


def stub_models(current: np.ndarray, simulated: np.ndarray) -> SimpleNamespace:
    """Models whose current simulates to ``simulated`` (the speed far off, and not compared)."""
    rec = SimpleNamespace(current=current, speed=np.zeros_like(current))

    def simulate(values, index, state):
        return {'current': simulated, 'speed': np.full_like(current, 1e3 * values['k'])}
    return SimpleNamespace(measured=SimpleNamespace(records=[rec], outputs=('current', 'speed'),
                                                    simulate=simulate))


@pytest.mark.parametrize('repeat, worth, resolved', [(1, 1.0, True), (4, 2.0, False)])
def test_the_likelihood_ratio_counts_the_current_s_effective_samples(repeat, worth, resolved):
    # The quasi-static fit is off by a constant d: n ln(1 + d^2) = 20 on 10,000 white
    # samples; a residual alternating every 4 samples has a correlation time of 2 samples
    # (1 + 2 x its lag-1 autocorrelation 0.5): half of them.
    n = 10_000
    noise = np.repeat(np.tile([1.0, -1.0], n // (2 * repeat)), repeat)
    offset = np.sqrt(np.expm1(20.0 / n))
    full = Estimate('refined', {'k': 0.0}, {}, [(0.0, 0.0)])
    quasi = Estimate('refined', {'k': 1.0}, {}, [(0.0,)])
    ratio, needed = armature.armature_likelihood_ratio(
        full, quasi, stub_models(noise, np.zeros(n)), stub_models(noise, np.full(n, offset)))
    assert ratio == pytest.approx(20.0 / worth, rel=0.01)
    assert needed == pytest.approx(13.2, abs=0.1)  # chi-square, 2 degrees, 0.135 %
    assert (ratio > needed) == resolved
