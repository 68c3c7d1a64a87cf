"""Standard errors that cover the choice of structure (issue 19): the noise bootstrap."""

from dataclasses import make_dataclass
import json
from unittest import mock

import numpy as np
import pytest

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.identify import identify
from dcmotor_id.identification.structure_uncertainty import (between_structures, covered,
                                                             quantisation_step, resample_channel,
                                                             resample_noise)
from dcmotor_id.signals.filters import noise_std
from dcmotor_id.simulation.lab_scenarios import small_motor_pwm_steps


@pytest.fixture(scope='module')
def marginal():
    """
    PWM steps, seed 2: the loop adds a quadratic drag that moves b by a third.

    A marginal choice under the acceptance rule ``heldout-t`` (the default rule,
    ``innovation-t``, turns that drag down: the record has none); the structure bootstrap is
    what is tested here, so the loops of this fixture are judged by ``heldout-t``.
    """
    original = LoopState.__init__

    def init(self, *args, **kwargs):
        kwargs.setdefault('acceptance', 'heldout-t')
        original(self, *args, **kwargs)

    records = small_motor_pwm_steps(seed=2).records
    with mock.patch.object(LoopState, '__init__', init):
        plain = identify(records, discover=False)
        found = identify(records, structure_bootstrap=8)
    return plain, found


def test_the_stated_error_covers_the_structure_choice_on_a_marginal_record(marginal):
    plain, found = marginal
    info = found.structure_uncertainty
    assert [effect['name'] for effect in found.effects] == ['quadratic_drag']
    # The choice is marginal: the resamples do not all choose the same structure.
    assert info['completed'] >= 6, info
    assert len(info['structures']) >= 2, info['structures']
    assert 0.0 < info['effect_frequency']['quadratic_drag'] < 1.0, info
    assert 0.0 < info['chosen_share'] < 1.0
    # The effect moves b far beyond the one-structure standard error; the reported one
    # covers the move.
    shift = abs(found.parameters['b'] - plain.parameters['b'])
    assert shift > 2.0 * info['stderr_without_structure']['b']
    assert info['stderr_structure']['b'] > 0.0
    assert found.stderr['b'] == pytest.approx(np.hypot(info['stderr_without_structure']['b'],
                                                       info['stderr_structure']['b']))
    assert shift < 1.5 * found.stderr['b'], (shift, found.stderr['b'])
    assert info['included_in_stderr'] is True
    # Said in the JSON (serialisable) and in the warnings.
    out = json.loads(json.dumps(found.as_dict()))
    assert out['structure_uncertainty']['resamples'] == 8
    assert any('structure_uncertainty' in text for text in found.warnings)
    assert not any('do not cover the choice of structure' in text for text in found.warnings)


def test_a_record_whose_structure_is_stable_keeps_its_standard_errors_bit_for_bit():
    records = small_motor_pwm_steps(seed=0).records
    plain = identify(records)
    found = identify(records, structure_bootstrap=3)
    info = found.structure_uncertainty
    assert info['structures'] == [{'effects': [], 'count': 3, 'share': 1.0}]
    assert info['included_in_stderr'] is False
    assert set(info['stderr_structure'].values()) == {0.0}
    np.testing.assert_array_equal(list(found.stderr.values()), list(plain.stderr.values()))
    assert found.parameters == plain.parameters
    assert plain.structure_uncertainty is None and 'structure_uncertainty' in plain.as_dict()


def test_without_discovery_there_is_no_choice_to_cover():
    records = small_motor_pwm_steps(seed=0).records
    found = identify(records, discover=False, structure_bootstrap=4)
    assert 'discovery is off' in found.structure_uncertainty['skipped']


@pytest.mark.parametrize('count', [1, -2, 2.5, 'ten', 10 ** 6])
def test_an_unusable_number_of_resamples_is_refused_with_what_to_do(count):
    with pytest.raises(InputDataError, match='--structure-bootstrap'):
        identify(small_motor_pwm_steps(seed=0).records, structure_bootstrap=count)


def test_between_structures_is_the_spread_of_the_structure_means():
    draws = [((), {'b': 1.0}), ((), {'b': 1.2}), (('drag',), {'b': 0.5}), (('drag',), {'b': 0.7})]
    part = between_structures(draws, ['b'])
    # Means 1.1 and 0.6 with equal shares: half their difference.
    assert part['b'] == pytest.approx(0.25)
    assert between_structures(draws[:2], ['b']) == {'b': 0.0}


def test_covered_adds_in_quadrature_and_only_where_the_part_is_nonzero():
    result = make_dataclass('Result', [('stderr', dict), ('combined', dict)])(
        {'J': 3.0, 'b': 0.1, 'Mc': 0.2, 'La': float('nan')},
        {'friction_torque_Nm': {'value': 1.0, 'stderr': 0.2}})
    out = covered(result, {'J': 4.0, 'b': 0.0, 'Mc': 0.15, 'La': 1.0})
    assert out.stderr['J'] == 5.0
    assert out.stderr['b'] == 0.1
    assert out.stderr['Mc'] == pytest.approx(0.25)
    assert out.combined['friction_torque_Nm']['stderr'] == pytest.approx(0.25)
    assert result.combined['friction_torque_Nm']['stderr'] == 0.2  # not changed in place
    assert np.isnan(out.stderr['La'])


def test_resampled_noise_has_the_measured_level_and_keeps_steps_and_grids():
    rng = np.random.default_rng(3)
    n = 4000
    signal = np.repeat([0.0, 2.0, 1.0, 3.0], n // 4)
    noisy = signal + rng.normal(0.0, 0.05, n)
    out = resample_channel(noisy, np.random.default_rng(4))
    assert noise_std(out) == pytest.approx(noise_std(noisy), rel=0.15)
    assert not np.allclose(out, noisy)
    # The steps stay where they were: the level of every plateau is kept.
    for level, part in zip([0.0, 2.0, 1.0, 3.0], np.split(out, 4)):
        assert abs(np.mean(part) - level) < 0.01
    # A commanded (noise-free) channel comes back unchanged; a quantised one stays on its grid.
    np.testing.assert_array_equal(resample_channel(signal, rng), signal)
    grid = np.round(noisy / 0.02) * 0.02
    assert quantisation_step(grid) == pytest.approx(0.02)
    again = resample_channel(grid, rng)
    assert quantisation_step(again) == pytest.approx(0.02)
    record = Record(np.arange(n) * 1e-3, current=noisy, voltage=signal, speed=grid)
    resampled = resample_noise(record, rng)
    np.testing.assert_array_equal(resampled.voltage, signal)
    assert resampled.position is None and not np.allclose(resampled.current, noisy)
