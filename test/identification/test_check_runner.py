"""The pipeline runs its before-fit record checks and its answer's checks from the registry."""

import numpy as np
import pytest

from dcmotor_id.core import checks as registry
from dcmotor_id.core.checks import Check, registered
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.answer import answer_warnings, FinalFit
from dcmotor_id.identification.identify import identify
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation


@pytest.fixture(scope='module')
def record():
    """One short noisy record of the paper's second motor (a quick base fit)."""
    t, voltage = make_excitation('paper', 1.0, 1e-3)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, 1e-3, (0.0, 0.0))
    rng = np.random.default_rng(0)
    return Record(t, add_sensor_noise(current, 0.01, rng), voltage,
                  add_sensor_noise(speed, 0.01, rng), source='paper')


def test_the_answer_s_checks_run_in_their_written_order():
    assert [check.name for check in registered('after_fit', 'answer')] == [
        'plausibility', 'units', 'useful', 'correlated_pairs', 'initial_states', 'misfit']


def test_a_new_check_is_one_function_and_one_registration(monkeypatch, record):
    looked_at = []

    def answer_check(fit):
        looked_at.append(fit)
        return ['the new check of the answer ran']

    monkeypatch.setitem(registry._REGISTRY, 'new_answer_check',
                        Check('new_answer_check', 'after_fit', 'answer', answer_check, 'a test'))
    monkeypatch.setitem(registry._REGISTRY, 'new_record_check',
                        Check('new_record_check', 'before_fit', 'record',
                              lambda rec: f'the new record check saw {rec.source}', 'a test'))
    result = identify([record], discover=False)
    assert 'the new record check saw paper' in result.warnings
    assert 'the new check of the answer ran' in result.warnings
    (fit,) = looked_at
    assert isinstance(fit, FinalFit)
    assert fit.estimate.parameters['J'] == pytest.approx(result.parameters['J'])
    assert set(fit.residual_rms) == {'current', 'speed'}


def test_the_runner_gives_every_check_s_warnings_in_order(monkeypatch):
    monkeypatch.setattr(registry, '_REGISTRY', {
        'one': Check('one', 'after_fit', 'answer', lambda fit: ['first'], 'a test'),
        'other_time': Check('other_time', 'after_fit', 'fit', lambda fit: ['never'], 'a test'),
        'two': Check('two', 'after_fit', 'answer', lambda fit: ['second', 'third'], 'a test')})
    assert answer_warnings(None) == ('first', 'second', 'third')  # type: ignore[arg-type]
