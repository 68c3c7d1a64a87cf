"""Several starts of the base fit when its misfit is large (issue 19), in the lab simulator."""

from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.checks import start as start_check
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline import further_starts as multistart
from dcmotor_id.identification.pipeline.further_starts import (ambiguity_warning,
                                                               ambiguous_starts,
                                                               different_basins, further_starts,
                                                               MAX_STARTS, NOT_CHOSEN_EARLIER,
                                                               several_starts, SIMILAR_BIC,
                                                               with_starts)
from dcmotor_id.identification.pipeline.state import Models
from dcmotor_id.simulation.lab_scenarios import (servo_collapsed_start, servo_opposite_steps,
                                                 servo_torque_steps)


@pytest.fixture(scope='module')
def collapsed():
    scenario = servo_collapsed_start()
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    base = RefinedEstimator().fit(records, torque_constant=scenario.torque_constant)
    return scenario, records, base


def test_a_further_start_escapes_the_basin_of_the_default_start(collapsed):
    scenario, records, base = collapsed
    truth = scenario.truth
    # The class: from the default start the base fit runs b to its bound (no gradient leads
    # back from there) and J to hundreds of times the truth.
    assert base.parameters['J'] > 100 * truth.J, base.parameters
    assert base.parameters['b'] < 1e-3 * truth.b, base.parameters
    best, account = several_starts(base, Models(records, scenario.torque_constant), Progress())
    assert account is not None and account['chosen'] != 'default', account
    scores = {entry['name']: entry['bic'] for entry in account['starts'] if 'bic' in entry}
    assert scores[account['chosen']] < scores['default'] - 10, scores
    # The base model lacks the offset, so J stays high; but b is found, J 10x nearer.
    assert best.parameters['J'] < base.parameters['J'] / 10, best.parameters
    assert best.parameters['b'] == pytest.approx(truth.b, rel=0.3), best.parameters
    names = [entry['name'] for entry in account['starts']]
    assert names[0] == 'default' and len(names) <= 1 + MAX_STARTS, names
    assert {'regression', 'regression, J x 0.333', 'regression, J x 3'} <= set(names), names
    assert account['cpu_s'] > 0.0


def test_the_json_names_the_starts_and_keeps_the_start_check(collapsed):
    scenario, records, _ = collapsed
    result = identify(records, torque_constant=scenario.torque_constant)
    check = result.as_dict()['start_check']
    assert {'evidence', 'doubts', 'chosen', 'bic'} <= set(check), check  # the existing keys
    assert check['starts_chosen'] != 'default', check
    assert check['starts'][0]['name'] == 'default', check
    assert all('start' in entry and ('bic' in entry or 'failed' in entry or 'skipped' in entry)
               for entry in check['starts']), check
    assert check['starts_reasons'][0].startswith('the misfit is'), check
    assert check['starts_cpu_s'] >= 0.0
    truth = scenario.truth
    assert abs(result.parameters['J'] / truth.J - 1) < 0.4, result.parameters
    assert abs(result.parameters['b'] / truth.b - 1) < 0.3, result.parameters


def test_a_sound_fit_gets_no_further_starts():
    scenario = servo_torque_steps()
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    base = RefinedEstimator().fit(records, torque_constant=scenario.torque_constant)
    best, account = several_starts(base, Models(records, scenario.torque_constant), Progress())
    assert account is None and best is base
    check = identify(records, torque_constant=scenario.torque_constant).as_dict()['start_check']
    assert check['chosen'] == 'first start' and 'starts' not in check, check


def test_no_spread_when_the_regression_start_leads_back_to_the_default_fit():
    # Without the offset in the model every start reaches J 40x with Mc at zero: one basin
    # (the second start, holding the offset, is what escapes it); the spread is not paid for.
    scenario = servo_opposite_steps(seed=0)
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    base = RefinedEstimator().fit(records, torque_constant=scenario.torque_constant)
    best, account = several_starts(base, Models(records, scenario.torque_constant), Progress())
    assert [entry['name'] for entry in account['starts']] == ['default', 'regression'], account
    assert account['chosen'] == 'default' and best is base, account
    assert not account['ambiguous']


def test_the_further_starts_respect_the_time_budget(collapsed):
    scenario, records, base = collapsed
    progress = Progress(max_time_s=1e-9)
    best, account = several_starts(base, Models(records, scenario.torque_constant), progress)
    assert best is base and account['chosen'] == 'default', account
    failed = [entry for entry in account['starts'] if 'failed' in entry]
    assert len(failed) == 1 and failed[0]['failed'].startswith('time budget'), account
    assert progress.deadline is not None  # given back as it was


def test_further_starts_without_evidence_spread_j_around_the_fit():
    fitted = {'J': 2e-4, 'b': 1e-4, 'Mc': 0.01}
    starts = further_starts(None, fitted, ['J', 'b', 'Mc'])
    assert [name for name, _ in starts] == ['fit, J x 0.333', 'fit, J x 3']
    assert starts[1][1] == {'J': pytest.approx(6e-4), 'b': 1e-4, 'Mc': 0.01}
    evidence = {'J': 1e-4, 'b': -1.0, 'Mc': 0.02, 'offset': 0.0}
    starts = further_starts(evidence, fitted, ['J', 'b', 'Mc'])
    assert starts[0] == ('regression', {'J': 1e-4, 'b': 0.0, 'Mc': 0.02})


def _fit(j, b, sj=1e-6, sb=1e-6):
    return SimpleNamespace(parameters={'J': j, 'b': b}, stderr={'J': sj, 'b': sb})


def test_different_basins_with_similar_scores_are_ambiguous():
    near, far = _fit(1.0e-4, 7e-5), _fit(1.5e-4, 7e-5)
    assert not different_basins(near, _fit(1.1e-4, 7e-5))  # 10 % apart: the same basin
    assert not different_basins(near, _fit(1.5e-4, 7e-5, sj=5e-5))  # within the errors
    assert different_basins(near, far)
    entries = [{'name': 'default', 'bic': 10.0, 'J': 1.0e-4, 'b': 7e-5},
               {'name': 'regression', 'bic': 10.0 + SIMILAR_BIC / 2, 'J': 1.5e-4, 'b': 7e-5},
               {'name': 'regression, J x 3', 'bic': 10.0 + 2 * SIMILAR_BIC, 'J': 3e-4,
                'b': 7e-5}]
    fits = [near, far, _fit(3e-4, 7e-5)]
    assert ambiguous_starts(fits, entries, 0) == ['regression']
    account = {'starts': entries, 'chosen': 'default', 'ambiguous': ['regression'],
               'reasons': [], 'cpu_s': 0.1}
    text = ambiguity_warning(account)
    assert 'ambiguous' in text and 'J = 0.00015' in text, text
    assert ambiguity_warning({**account, 'ambiguous': []}) is None
    check = with_starts({'doubts': ['x'], 'chosen': 'first start', 'bic': {}}, account)
    assert check['doubts'] == ['x'] and check['starts'] is entries
    assert with_starts(None, None) is None
    assert np.isclose(with_starts(None, account)['starts_cpu_s'], 0.1)


def _counting_fits(monkeypatch):
    """Count the further starts fitted (their names), by wrapping ``multistart._fit_from``."""
    fitted = []
    fit_from = multistart._fit_from

    def counted(*arguments):
        fitted.append(arguments[-1]['name'])
        return fit_from(*arguments)

    monkeypatch.setattr(multistart, '_fit_from', counted)
    return fitted


def test_a_later_run_of_one_identification_fits_only_the_start_the_first_chose(
        collapsed, monkeypatch):
    """
    The runs of one identification share the further starts (the position's two runs).

    The first run fits them all; a later one, given the first's account (the same records
    and regression), fits only the start the first chose and reaches the same base; without
    it every run fits them all again.
    """
    scenario, records, base = collapsed
    fitted = _counting_fits(monkeypatch)
    first_best, first = several_starts(base, Models(records, scenario.torque_constant),
                                       Progress())
    assert len(fitted) >= 2 and first['chosen'] != 'default', first
    fitted.clear()
    best, later = several_starts(base, Models(records, scenario.torque_constant), Progress(),
                                 earlier=first)
    assert fitted == [first['chosen']]
    assert later['chosen'] == first['chosen']
    assert best.parameters == first_best.parameters
    assert [entry['name'] for entry in later['starts']] == \
        [entry['name'] for entry in first['starts']]
    skipped = [entry for entry in later['starts'][1:] if entry['name'] != first['chosen']]
    assert skipped and all(entry['skipped'] == NOT_CHOSEN_EARLIER for entry in skipped)
    fitted.clear()
    several_starts(base, Models(records, scenario.torque_constant), Progress())
    assert len(fitted) >= 2  # a new identification


def test_a_later_run_whose_first_kept_its_default_fits_no_further_start(monkeypatch):
    """The first run's further starts led nowhere better: a later run does not fit them."""
    scenario = servo_opposite_steps(seed=0)
    records = prepare_records(scenario.records, torque_constant=scenario.torque_constant)
    base = RefinedEstimator().fit(records, torque_constant=scenario.torque_constant)
    fitted = _counting_fits(monkeypatch)
    _, first = several_starts(base, Models(records, scenario.torque_constant), Progress())
    assert fitted == ['regression']
    best, later = several_starts(base, Models(records, scenario.torque_constant), Progress(),
                                 earlier=first)
    assert fitted == ['regression'] and best is base
    assert later['chosen'] == 'default' and later['reasons'], later
    assert later['starts'][1] == {'name': 'regression', 'start': later['starts'][1]['start'],
                                  'skipped': NOT_CHOSEN_EARLIER, 'chosen': False}


def test_the_start_doubts_state_both_tests_in_one_place(collapsed, monkeypatch):
    """
    Further starts on the misfit or on J or b far from the regression; a second start on both.

    A second start (its own discovery loop) needs the misfit and, besides, initial states
    moved far or J or b far from the regression.
    """
    scenario, records, base = collapsed
    model = multistart.OutputErrorModel(records, scenario.torque_constant, ())
    parameters = base.parameters
    near = {'J': parameters['J'], 'b': parameters['b'], 'Mc': 0.0, 'offset': 0.0}
    far = {**near, 'J': 10.0 * parameters['J']}

    def doubts(ratio, moved, evidence):
        monkeypatch.setattr(start_check, 'misfit_ratio', lambda *_: ratio)
        monkeypatch.setattr(start_check, 'initial_state_warnings', lambda *_: moved)
        return start_check.start_doubts(base, records, model, evidence)

    high = 2.0 * start_check.MISFIT_FACTOR
    assert doubts(1.0, [], near) == start_check.StartDoubts([], [])
    assert doubts(1.0, ['moved'], far).further_starts[0].startswith('J = ')
    assert doubts(1.0, ['moved'], far).second_start == []
    misfit_only = doubts(high, [], near)
    assert misfit_only.further_starts[0].startswith('the misfit is') and \
        misfit_only.second_start == []
    moved = doubts(high, ['moved'], near).second_start
    assert moved[0].startswith('the misfit is') and 'initial state' in moved[1]
    both = doubts(high, [], far)
    assert both.further_starts == both.second_start and len(both.second_start) == 2


def test_a_run_measures_each_channels_noise_once(monkeypatch):
    # The checks around the fits (tests, start checks, identifiability, the training parts,
    # the effects' regressors, held-out errors) ask for the noise of the records' current
    # and speed about twenty times; the record measures each channel once (issue 29, speed).
    # A check on other records measures their own.
    from dcmotor_id.core import noise as core_noise
    from dcmotor_id.core.model import PAPER_MOTORS
    from dcmotor_id.core.records import Record
    from dcmotor_id.simulation import simulate_motor

    t = np.arange(4000) * 1e-3
    voltage = 60.0 * np.sign(np.sin(2 * np.pi * 1.5 * t)) + 20.0 * np.sin(2 * np.pi * 7 * t)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, 1e-3)
    rng = np.random.default_rng(1)
    records = prepare_records([Record(t, current + 0.01 * rng.standard_normal(t.size), voltage,
                                      speed + 0.1 * rng.standard_normal(t.size))])
    others = [records[0].slice(0, 2000)]
    whole, part = (core_noise.noise_level(records[0].speed),
                   core_noise.noise_level(records[0].speed[:2000]))
    measured = []
    std = core_noise.noise_std

    def counted(values):
        measured.append(next((name for name in ('current', 'speed') if np.array_equal(
            values, getattr(records[0], name))), 'other'))
        return std(values)

    monkeypatch.setattr(core_noise, 'noise_std', counted)
    identify(records, discover=True)
    assert sorted(name for name in measured if name != 'other') == ['current', 'speed']
    # The start checks pool the records' own levels: nothing measured again.
    first = start_check.pooled_noise(records, 'speed')
    assert start_check.pooled_noise(records, 'speed') == first == whole
    assert len(measured) == 2
    assert start_check.pooled_noise(others, 'speed') == part
    assert len(measured) == 3


def test_the_start_search_solves_each_admissible_regression_once(monkeypatch):
    """Issue 29 (speed): the free mechanical solve is the bounded one's when it is admissible."""
    from dcmotor_id.core.model import PAPER_MOTORS
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators import refined
    from dcmotor_id.simulation import simulate_motor
    t = np.arange(0.0, 4.0, 1e-3)
    voltage = 60.0 * np.sign(np.sin(2 * np.pi * 1.5 * t)) + 20.0 * np.sin(2 * np.pi * 7 * t)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, 1e-3)
    records = prepare_records([Record(t, current, voltage, speed)])
    solves = []
    original = np.linalg.lstsq
    monkeypatch.setattr(np.linalg, 'lstsq', lambda *a, **k: solves.append(1) or original(*a, **k))
    candidates = refined._svf_candidates(records, None)
    assert len(candidates) == 3  # admissible at every cut-off: one candidate each
    assert len(solves) == 2 * 3  # the mechanical and the electrical regression per cut-off
