"""The position error's model chosen against model-free evidence; the second start's criterion."""

from dataclasses import replace

import numpy as np
import pytest

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.progress import Progress
from dcmotor_id.identification.error_model.criterion import position_ar
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline.position_error import AGREEMENT_FACTOR, disagreement
from dcmotor_id.identification.pipeline.second_start import check_start
from dcmotor_id.identification.pipeline.state import Fit, Inputs, Models, RunOn
from dcmotor_id.identification.result import IdentificationResult
from dcmotor_id.simulation.lab_scenarios import ball_screw_sine

EVIDENCE = {'J': 1.0, 'b': 2.0, 'Mc': 0.5, 'offset': 0.0}


def test_disagreement_is_the_largest_factor_from_the_regression():
    """J, b and Mc against the regression; a friction pressed to zero is infinitely far."""
    assert disagreement({'J': 1.2, 'b': 2.0, 'Mc': 0.5}, EVIDENCE) == pytest.approx(np.log(1.2))
    assert disagreement({'J': 1.0, 'b': 1.0, 'Mc': 0.5}, EVIDENCE) == pytest.approx(np.log(2.0))
    assert disagreement({'J': 1.0, 'b': 2.0, 'Mc': 0.0}, EVIDENCE) == np.inf
    # A value the regression does not determine is not compared; no evidence, no doubt.
    assert disagreement({'J': 1.0, 'b': 2.0, 'Mc': 0.0}, {**EVIDENCE, 'Mc': -0.1}) == 0.0
    assert disagreement({'J': 9.0}, None) == 0.0


def test_the_white_error_model_never_takes_an_ar1_coefficient():
    """Under the ``white`` model (an argument, no scope) a drifting residual is still white."""
    drift = np.cumsum(np.random.default_rng(0).standard_normal(5_000))
    assert position_ar(drift, 0.01) > 0.9
    assert position_ar(drift, 0.01, 'white') == 0.0
    assert position_ar(drift, 0.01, 'adaptive') > 0.9
    with pytest.raises(ValueError, match='white'):
        position_ar(drift, 0.01, 'red')
    with pytest.raises(ValueError, match='white'):
        RefinedEstimator(position_error='red')


def test_the_estimator_s_position_error_model_decides_its_weights():
    """The refined estimator's ``position_error`` alone decides the AR(1) model of its fit."""
    scenario = ball_screw_sine()
    records = prepare_records(scenario.records, scenario.torque_constant)
    fits = {model: RefinedEstimator(criterion='position', position_error=model).fit(
        records, torque_constant=scenario.torque_constant) for model in ('white', 'adaptive')}
    assert not any(fits['white'].info['position_ar'])
    assert any(fits['adaptive'].info['position_ar'])


def _result(parameters, warnings=()):
    """Return a result whose records are the ball screw's (the regression's data)."""
    scenario = ball_screw_sine()
    records = prepare_records(scenario.records, scenario.torque_constant)
    return IdentificationResult(
        parameters=dict(parameters), stderr={}, method='refined', effects=[], error_before={},
        error_after={}, unexplained=False, mode='mechanical',
        torque_constant=scenario.torque_constant, initial_states=[], noise_std={},
        sample_period_s=records[0].sample_period_s, n_samples=len(records[0]), sources=[],
        units={}, discover=False, discovery=None, warnings=list(warnings),
        input_records=records, criterion='position')


@pytest.fixture(scope='module')
def agreeing():
    """Return a result close to the ball screw's truth (which the regression sees)."""
    truth = ball_screw_sine().truth
    return _result({'J': truth.J, 'b': truth.b, 'Mc': truth.Mc})


def _choose(monkeypatch, outcomes, white_base=None, reference=None):
    """
    Run the pipeline's choice of the position error's model over scripted runs.

    ``outcomes`` by model (``white``, ``adaptive``): the result of a whole run, or the
    refusal it raises.  ``white_base``: the white run's base parameters after its start
    check (then the white run stops there first and is finished from that state).
    ``reference``: a result whose records the runs share (default: the first of
    ``outcomes``).  Returns the result and the runs, in order (``white finished``: resumed).
    """
    from types import SimpleNamespace

    from dcmotor_id.identification.pipeline import run as pipeline
    from dcmotor_id.identification.pipeline.state import Fit, Inputs, Models, Request, RunOn

    reference = reference or next(value for value in outcomes.values()
                                  if isinstance(value, IdentificationResult))
    records, constant = reference.input_records, reference.torque_constant
    runs = []

    def outcome(model):
        found = outcomes[model]
        if isinstance(found, Exception):
            raise found
        return found

    def begin(request, on):
        runs.append(on.position_error)
        if on.position_error == 'white' and white_base is not None:
            inputs = Inputs(records, 'refined', constant, True, None, [], Progress(None),
                            'estimate', on, None)
            return pipeline.Begun(inputs, Fit(SimpleNamespace(parameters=white_base), {},
                                              Models(records, constant)))
        return outcome(on.position_error)

    def finish(begun):
        runs.append('white finished')
        return outcome('white')

    monkeypatch.setattr(pipeline, 'begin', begin)
    monkeypatch.setattr(pipeline, 'finish', finish)
    request = Request(records, 'refined', constant, True, None, None, Progress(None), 'estimate')
    assert RunOn('position').position_error == 'adaptive'
    return pipeline.on_the_position(request, 'position'), runs


def test_a_white_fit_that_agrees_runs_once(agreeing, monkeypatch):
    """The white result agrees with the regression: kept, the identification runs once."""
    result, runs = _choose(monkeypatch, {'white': agreeing})
    assert runs == ['white']
    assert result.position_error['model'] == 'white'
    assert result.position_error['disagreement']['white'] < AGREEMENT_FACTOR
    assert result.as_dict()['position_error']['evidence']['Mc'] > 0


def test_a_white_fit_that_bends_the_friction_runs_again_adaptive(agreeing, monkeypatch):
    """The white result's Coulomb friction at zero: the adaptive run, closer, is kept."""
    bent = replace(agreeing, parameters={**agreeing.parameters, 'Mc': 0.0})
    result, runs = _choose(monkeypatch, {'white': bent, 'adaptive': agreeing})
    assert runs == ['white', 'adaptive']
    assert result.position_error['model'] == 'adaptive'
    assert result.position_error['alternative']['Mc'] == 0.0
    assert result.position_error['disagreement']['white'] is None
    assert result.parameters['Mc'] == agreeing.parameters['Mc']
    # Both far from the evidence: the closer one, with a warning that says so.
    worse = replace(agreeing, parameters={**agreeing.parameters,
                                          'J': 5 * agreeing.parameters['J']})
    result, _ = _choose(monkeypatch, {'white': bent, 'adaptive': worse})
    assert result.position_error['model'] == 'adaptive'
    assert any('disagrees with the model-free regression' in text for text in result.warnings)
    # The adaptive run fails: the white result stays, accounted for.
    result, _ = _choose(monkeypatch, {'white': bent, 'adaptive': FitError('diverged')})
    assert result.position_error['model'] == 'white'
    assert result.position_error['adaptive'] == 'failed: diverged'


def test_a_white_fit_that_fails_falls_back_to_the_adaptive_model(agreeing, monkeypatch):
    """A white fit that diverges is not the end: the adaptive run's result, accounted for."""
    result, runs = _choose(monkeypatch, {'white': FitError('the output-error fit diverged'),
                                         'adaptive': agreeing})
    assert runs == ['white', 'adaptive']
    assert result.position_error['model'] == 'adaptive'
    assert 'diverged' in result.position_error['white']


def test_the_ball_screw_keeps_the_adaptive_error_model():
    """
    Friction along the travel: white bends the Coulomb friction, the drift's model does not.

    The identification on the position first weights it as white; the ball screw's white base
    fit already lies far from the regression, so the white run is left there and the
    adaptive (AR(1)) run, which agrees, is kept.
    """
    scenario = ball_screw_sine()
    records = prepare_records(scenario.records, scenario.torque_constant)
    result = identify(records, torque_constant=scenario.torque_constant)
    account = result.position_error
    assert account['model'] == 'adaptive'
    assert 'left after its base fit' in account['white']
    assert account['disagreement']['adaptive'] < AGREEMENT_FACTOR
    assert abs(result.parameters['Mc'] / scenario.truth.Mc - 1) < 0.15


def test_the_second_start_fits_the_run_s_criterion():
    """
    A first fit in a wrong basin on the position: the second start compares the position too.

    It used to fit the speed alone whatever the criterion (EMPS: the position criterion's
    result was then a speed fit, 9.4 mm on PULSES instead of 4.2 mm).
    """
    scenario = ball_screw_sine()
    constant = scenario.torque_constant
    records = prepare_records(scenario.records, constant)
    truth = scenario.truth
    fitted = RefinedEstimator(criterion='position', initial_state='measured').fit(
        records, torque_constant=constant)
    wrong = replace(fitted, parameters={**fitted.parameters, 'J': 20 * truth.J,
                                        'b': 20 * truth.b})
    inputs = Inputs(records, 'refined', constant, False, None, [], Progress(None), 'estimate',
                    RunOn('position'), None)
    models = Models(records, constant, criterion='position')
    _, estimate, _, check = check_start(inputs, Fit(wrong, {}, models))
    assert check['doubts'], check
    assert check['chosen'] != 'first start'
    # The position's initial state is part of the second start's fit.
    assert len(estimate.initial_states[0]) == 2
    assert estimate.parameters['J'] == pytest.approx(truth.J, rel=0.3)


def test_an_axis_driven_both_ways_with_an_offset_finds_its_effects():
    """
    Identify EMPS's class: a base with no fit on the position; the loop starts from the speed.

    Without its force offset the model's position runs away over the record: its fit on the
    position diverges or runs to a friction of 1e10 (the identification used to find no
    effect: 135 mm on the pulses).  The loop starts from the base fitted on the speed, finds
    the offset and the viscous asymmetry on the position, and the model follows a validation
    record within a millimetre.
    """
    from dcmotor_id.identification.discovery import DiscoveryLoop
    from dcmotor_id.identification.effects import EXTENDED_VOCABULARY
    from dcmotor_id.identification.validate import model_from_dict, validate_record
    from dcmotor_id.simulation.lab_scenarios import axis_both_ways

    scenario = axis_both_ways()
    constant = scenario.torque_constant
    records = prepare_records(scenario.records, constant)
    found = DiscoveryLoop(records, constant, vocabulary=EXTENDED_VOCABULARY,
                          criterion='position', position_error='white').run()
    assert 'base_from' in found.base.estimate.info
    assert set(found.final.structure.names()) == {'load_torque', 'viscous_asymmetry'}
    result = identify(records, torque_constant=constant, vocabulary=EXTENDED_VOCABULARY)
    assert result.criterion == 'position'
    effects = {effect['name']: effect['parameters'] for effect in result.effects}
    assert set(effects) == {'load_torque', 'viscous_asymmetry'}
    assert effects['load_torque']['torque_Nm'] == pytest.approx(-3.2, rel=0.1)
    assert effects['viscous_asymmetry']['delta_Nm_s'] == pytest.approx(-40.0, rel=0.1)
    for name in ('J', 'b', 'Mc'):
        assert result.parameters[name] == pytest.approx(getattr(scenario.truth, name), rel=0.05)
    validation = prepare_records(axis_both_ways(pulses=True).records, constant)[0]
    scores = validate_record(model_from_dict(result.as_dict()), validation).scores
    assert scores['position_rmse'] < 1e-3


def test_a_white_base_that_bends_the_friction_leaves_the_white_run_early(agreeing,
                                                                         monkeypatch):
    """
    The white run stops after its base fit when that contradicts the regression.

    The adaptive run comes first; it agrees, so the white run is never finished (the time of
    a whole identification saved).  When the adaptive run disagrees too, the white run is
    finished and the closer result kept.
    """
    bent = {**agreeing.parameters, 'Mc': 0.0}
    result, runs = _choose(monkeypatch, {'white': replace(agreeing, parameters=bent),
                                         'adaptive': agreeing}, white_base=bent)
    assert runs == ['white', 'adaptive']
    assert result.position_error['model'] == 'adaptive'
    assert 'left after its base fit' in result.position_error['white']
    far = replace(agreeing, parameters={**agreeing.parameters, 'J': 9 * agreeing.parameters['J']})
    result, runs = _choose(monkeypatch, {'white': replace(agreeing, parameters=bent),
                                         'adaptive': far}, white_base=bent)
    assert runs == ['white', 'adaptive', 'white finished']
    assert result.position_error['model'] == 'adaptive'  # J 9x is closer than Mc at zero
    assert result.position_error['alternative']['Mc'] == 0.0
    # A white base within the agreement: the white run goes on to its end, alone.
    result, runs = _choose(monkeypatch, {'white': agreeing}, white_base=agreeing.parameters)
    assert runs == ['white', 'white finished']
    assert result.position_error['model'] == 'white'


def test_a_white_run_that_fails_after_a_far_adaptive_one_keeps_the_adaptive(agreeing,
                                                                            monkeypatch):
    """White base far, adaptive far, the finished white run fails: the adaptive, warned."""
    bent = {**agreeing.parameters, 'Mc': 0.0}
    far = replace(agreeing, parameters={**agreeing.parameters, 'J': 9 * agreeing.parameters['J']})
    result, runs = _choose(monkeypatch, {'white': FitError('the output-error fit diverged'),
                                         'adaptive': far}, white_base=bent)
    assert runs == ['white', 'adaptive', 'white finished']
    assert result.position_error['model'] == 'adaptive'
    assert result.position_error['white'].startswith('failed')
    assert any('disagrees with the model-free regression' in text for text in result.warnings)
    # Both fail: the white run's refusal.
    with pytest.raises(FitError, match='diverged'):
        _choose(monkeypatch, {'white': FitError('the output-error fit diverged'),
                              'adaptive': FitError('no')}, white_base=bent, reference=agreeing)


def test_a_white_run_left_after_its_start_check_is_finished_from_there(monkeypatch):
    """
    Both error models far from the regression: the white run resumes where it was left.

    Its base fit and start check are not run again (two base fits in all, not three), the
    result is that of a white run from the start, and the status line names each run after
    the first.
    """
    from dcmotor_id.identification.pipeline import position_error, run as pipeline
    from dcmotor_id.identification.pipeline.state import Request, RunOn

    scenario = ball_screw_sine()
    records = prepare_records(scenario.records, scenario.torque_constant)
    # Every result is "far" (any disagreement at all): white left, adaptive far, white finished.
    monkeypatch.setattr(position_error, 'AGREEMENT_FACTOR', 1.0 + 1e-12)
    base_fits, chosen = [], []
    base_fit, closer = pipeline.base_fit, position_error._closer
    monkeypatch.setattr(pipeline, 'base_fit',
                        lambda inputs: base_fits.append(1) or base_fit(inputs))
    monkeypatch.setattr(position_error, '_closer',
                        lambda white, *rest: chosen.append(white) or closer(white, *rest))
    lines = []
    progress = Progress(None, callback=lines.append, delay_s=0.0)
    identify(records, torque_constant=scenario.torque_constant, progress=progress)
    assert len(base_fits) == 2
    direct = pipeline.identify_with(Request(records, 'refined', scenario.torque_constant, True,
                                            None, None, Progress(None), 'estimate'),
                                    RunOn('position', 'white'))
    assert chosen[0].parameters == direct.parameters
    assert chosen[0].effects == direct.effects
    runs = [position_error.ADAPTIVE_RUN, position_error.WHITE_RUN_RESUMED]
    named = [next(i for i, line in enumerate(lines) if name + ': ' in line) for name in runs]
    assert named == sorted(named)
    assert progress.run == ''


def test_the_elapsed_time_of_two_runs_is_the_later_one_s(agreeing, monkeypatch):
    """The runs share one Progress: the later result's elapsed time already counts both."""
    bent = replace(agreeing, parameters={**agreeing.parameters, 'Mc': 0.0}, elapsed_s=2.0)
    result, _ = _choose(monkeypatch, {'white': bent,
                                      'adaptive': replace(agreeing, elapsed_s=5.0)})
    assert result.elapsed_s == 5.0


def test_the_ball_screw_s_two_runs_fit_the_further_starts_and_the_regression_once(monkeypatch):
    """
    The white run and the AR(1) run share the records: what depends on them alone is done once.

    The white base misfits far above the noise (the preload's drift): the white run fits the
    further starts, and the AR(1) run fits again only the start it chose (none: the default
    was kept).  The model-free regression is computed once per run and passed on to the
    further starts, the start checks and the chooser.
    """
    from dcmotor_id.identification.checks import start as checks_start
    from dcmotor_id.identification.pipeline import further_starts as multistart
    from dcmotor_id.identification.pipeline import state as pipeline

    scenario = ball_screw_sine()
    records = prepare_records(scenario.records, scenario.torque_constant)
    fitted, regressions, fallbacks = [], [], []
    fit_from, evidence = multistart._fit_from, pipeline.regression_evidence
    monkeypatch.setattr(multistart, '_fit_from',
                        lambda *arguments: fitted.append(arguments[-1]['name'])
                        or fit_from(*arguments))
    monkeypatch.setattr(pipeline, 'regression_evidence',
                        lambda *arguments: regressions.append(1) or evidence(*arguments))
    monkeypatch.setattr(checks_start, 'regression_evidence',
                        lambda *arguments: fallbacks.append(1) or evidence(*arguments))
    result = identify(records, torque_constant=scenario.torque_constant)
    assert result.position_error['model'] == 'adaptive'
    starts = result.start_check['starts']
    assert result.start_check['starts_chosen'] == 'default'
    assert fitted == [entry['name'] for entry in starts[1:]][:1] == ['regression']
    assert starts[1]['skipped'] == multistart.NOT_CHOSEN_EARLIER
    assert len(regressions) == 2 and not fallbacks  # one a run; none computed again
