"""The Cramer-Rao bound of the output-error model (dcmotor_id.identification.estimators.fisher)."""

import numpy as np
import pytest

from dcmotor_id.core.model import MECHANICAL_NAMES, PAPER_MOTORS, PARAMETER_NAMES
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators.base import ExogenousTerm
from dcmotor_id.identification.estimators.fisher import cramer_rao_bound, fisher_information
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

MOTOR = PAPER_MOTORS['paper2']


def clean_record(kind='paper', duration_s=4.0, dt=1e-3):
    """Simulate a noise-free record of motor 2."""
    t, voltage = make_excitation(kind, duration_s, dt)
    current, speed = simulate_motor(MOTOR, voltage, dt)
    return Record(t, current, voltage, speed, source=kind)


def noise_of(record, level):
    """Noise standard deviations ``level * std`` per channel, as add_sensor_noise adds them."""
    return {channel: level * np.std(getattr(record, channel)) for channel in ('current', 'speed')}


def test_bound_scales_with_the_noise_and_has_every_parameter():
    record = clean_record()
    small = cramer_rao_bound([record], MOTOR, noise_of(record, 0.01))
    large = cramer_rao_bound([record], MOTOR, noise_of(record, 0.03))
    assert set(small) >= set(PARAMETER_NAMES + ('Ka', 'Ta'))
    for name in PARAMETER_NAMES + ('Ka', 'Ta'):
        assert 0 < small[name] < 0.01 * MOTOR.as_dict()[name]
        assert large[name] == pytest.approx(3.0 * small[name], rel=1e-9)


def test_two_identical_records_halve_the_variance():
    record = clean_record()
    one = cramer_rao_bound([record], MOTOR, noise_of(record, 0.01))
    two = cramer_rao_bound([record, record], MOTOR, noise_of(record, 0.01))
    for name in PARAMETER_NAMES:
        assert two[name] == pytest.approx(one[name] / np.sqrt(2.0), rel=1e-6)


def test_known_initial_states_tighten_the_bound():
    record = clean_record()
    noise = noise_of(record, 0.01)
    nuisance = cramer_rao_bound([record], MOTOR, noise)
    known = cramer_rao_bound([record], MOTOR, noise, include_initial_states=False)
    assert all(known[name] <= nuisance[name] * (1 + 1e-9) for name in PARAMETER_NAMES)
    assert 'x0[0].speed' in nuisance and 'x0[0].speed' not in known


def test_information_of_a_sensor_offset_is_n_over_sigma_squared():
    record = clean_record(duration_s=1.0)
    offset = ExogenousTerm('current_offset', 'current', (np.ones(len(record)),), scale=0.1)
    model = OutputErrorModel([record], terms=(offset,))
    values = {**MOTOR.as_dict(derived=False), 'current_offset': 0.0}
    sigma = {'current': 0.05, 'speed': 0.2}
    names, information = fisher_information(model, values, [np.zeros(2)], sigma)
    column = names.index('current_offset')
    # The offset adds 1 to every current sample and nothing to the speed.
    assert information[column, column] == pytest.approx(len(record) / 0.05 ** 2, rel=1e-6)


def test_per_record_noise_weights_each_record():
    record = clean_record()
    same = cramer_rao_bound([record, record], MOTOR, {'current': 0.1, 'speed': 0.5})
    listed = cramer_rao_bound([record, record], MOTOR,
                              {'current': [0.1, 0.1], 'speed': [0.5, 0.5]})
    noisier = cramer_rao_bound([record, record], MOTOR,
                               {'current': [0.1, 0.4], 'speed': [0.5, 2.0]})
    for name in PARAMETER_NAMES:
        assert listed[name] == pytest.approx(same[name], rel=1e-12)
        assert noisier[name] > same[name]


def test_refined_stderr_agrees_with_the_bound():
    # Two independent computations: the estimator's Gauss-Newton covariance at its estimate
    # (log parameters, noise estimated from the residual) and the Fisher information at the
    # truth (physical parameters, the true noise).
    record = clean_record()
    noise = noise_of(record, 0.01)
    bound = cramer_rao_bound([record], MOTOR, noise)
    rng = np.random.default_rng(11)
    noisy = record.replace(current=add_sensor_noise(record.current, 0.01, rng),
                           speed=add_sensor_noise(record.speed, 0.01, rng))
    estimate = RefinedEstimator().fit([noisy])
    for name in PARAMETER_NAMES:
        assert estimate.stderr[name] == pytest.approx(bound[name], rel=0.05), name


def test_mechanical_only_bound():
    record = clean_record()
    shaft = Record(record.time_s, current=record.current, speed=record.speed)
    bound = cramer_rao_bound([shaft], MOTOR.as_dict(), {'speed': 0.1},
                             torque_constant=MOTOR.CPhi)
    assert {'J', 'b', 'Mc'} <= set(bound) and 'Ra' not in bound
    assert all(0 < bound[name] < 0.01 * MOTOR.as_dict()[name] for name in MECHANICAL_NAMES)


def test_bad_noise_arguments_are_refused():
    record = clean_record(duration_s=1.0)
    with pytest.raises(ValueError, match='speed'):
        cramer_rao_bound([record], MOTOR, {'current': 0.1})
    with pytest.raises(ValueError, match='positive'):
        cramer_rao_bound([record], MOTOR, {'current': 0.1, 'speed': 0.0})
