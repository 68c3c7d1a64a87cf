"""Output error on the position (issue 20): criterion, sensitivities, accuracy, held-out choice."""

import json

from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.cli.main import main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.identification.discovery import (DiscoveryLoop, heldout_gain_noise, never_worse,
                                                 Structure)
from dcmotor_id.identification.error_model.criterion import (fitted_outputs, integrate_speed,
                                                             resolve_criterion)
from dcmotor_id.identification.estimators.normal_equations import NormalEquations
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

MOTOR = PAPER_MOTORS['paper2']
NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')


def encoder_record(duration_s=4.0, dt=1e-3, counts_per_rev=4096, current_noise=0.01, seed=0,
                   kind='paper'):
    """Simulate a motor-2 record with a quantised encoder position and no speed column."""
    t, voltage = make_excitation(kind, duration_s, dt)
    current, speed = simulate_motor(MOTOR, voltage, dt, (0.0, 0.0))
    rng = np.random.default_rng(seed)
    lsb = 2 * np.pi / counts_per_rev
    position = np.round(integrate_speed(speed, dt, 0.3) / lsb) * lsb
    current = current + current_noise * np.std(current) * rng.standard_normal(t.shape[0])
    return Record(t, current, voltage, None, position, source='encoder')


def test_auto_criterion_follows_the_channels():
    derived = prepare_records([encoder_record(1.0)])[0]
    assert derived.speed_derived
    assert resolve_criterion([derived]) == 'position'
    measured = derived.replace(speed_derived=False)
    assert resolve_criterion([measured]) == 'speed'
    assert resolve_criterion([measured], 'both') == 'both'
    assert resolve_criterion([measured.replace(position=None)]) == 'speed'
    with pytest.raises(InputDataError, match='--criterion position needs a position'):
        resolve_criterion([measured.replace(position=None)], 'position')
    with pytest.raises(InputDataError, match='unknown criterion'):
        resolve_criterion([measured], 'angle')
    assert fitted_outputs(True, 'position') == ('position',)
    assert fitted_outputs(False, 'both') == ('current', 'speed', 'position')


@pytest.mark.parametrize('mechanical', [False, True])
@pytest.mark.parametrize('criterion', ['position', 'both'])
def test_position_sensitivities_match_finite_differences(mechanical, criterion):
    """The normal equations with the position equal those of a finite-difference Jacobian."""
    rec = prepare_records([encoder_record(2.0, kind='prbs')])[0]
    model = OutputErrorModel([rec], MOTOR.CPhi if mechanical else None, criterion=criterion)
    equations = NormalEquations(model)
    assert NormalEquations.supports(model)
    values = {name: 1.02 * getattr(MOTOR, name) for name in model.base_names}
    state = np.array([float(getattr(rec, channel)[0]) + 0.05 for channel in model.states])
    weights = np.array([1.0 / np.std(getattr(rec, channel)) for channel in model.outputs])
    result = equations.record(values, 0, state, weights)

    def residual(vector):
        moved = dict(zip(equations.names, vector[:len(equations.names)]))
        out = model.simulate(moved, 0, vector[len(equations.names):])
        return np.concatenate([(out[channel] - getattr(rec, channel)) * weight
                               for channel, weight in zip(model.outputs, weights)])
    point = np.array([values[name] for name in equations.names] + list(state))
    r0 = residual(point)
    jac = np.empty((r0.shape[0], point.shape[0]))
    for column in range(point.shape[0]):
        step = 1e-6 * max(abs(point[column]), 1e-3)
        up, down = point.copy(), point.copy()
        up[column] += step
        down[column] -= step
        jac[:, column] = (residual(up) - residual(down)) / (2 * step)
    assert result.cost == pytest.approx(float(r0 @ r0), rel=1e-10)
    hessian, gradient = jac.T @ jac, jac.T @ r0
    assert np.max(np.abs(result.hessian - hessian)) < 1e-6 * np.max(np.abs(hessian))
    assert np.max(np.abs(result.gradient - gradient)) < 1e-6 * np.max(np.abs(gradient))


def test_position_only_record_is_identified_accurately():
    """A quantised 4096-count encoder, no speed column: the position criterion within 0.5 %."""
    position, speed = [], []
    for seed in range(4):
        records = prepare_records([encoder_record(seed=seed)])
        result = identify(records, discover=False)
        assert result.criterion == 'position'
        assert result.as_dict()['criterion'] == 'position'
        errors = [result.parameters[name] / getattr(MOTOR, name) - 1 for name in NAMES]
        assert max(np.abs(errors)) < 5e-3, errors
        position.append(errors[3:])
        derived = identify(records, discover=False, criterion='speed')
        assert derived.criterion == 'speed'
        speed.append([derived.parameters[name] / getattr(MOTOR, name) - 1
                      for name in NAMES[3:]])
    # J, b, Mc (what the encoder measures): at least as accurate as the fit of the derived
    # speed, root mean square over the seeds.
    assert np.sqrt(np.mean(np.square(position))) <= np.sqrt(np.mean(np.square(speed)))


def test_identify_prepares_a_record_without_a_speed_itself():
    """A position-only record handed to identify as read: it was a bare numpy ValueError."""
    record = encoder_record(duration_s=2.0)
    direct = identify([record], discover=False)
    prepared = identify(prepare_records([record]), discover=False)
    assert direct.parameters == prepared.parameters


def test_cli_criterion_option_and_json_key(tmp_path, capsys):
    rec = encoder_record(2.0)
    path = str(tmp_path / 'encoder.csv')
    write_csv(path, rec)
    out = str(tmp_path / 'out.json')
    assert main(['identify', path, '--no-discover', '--json', out, '--quiet']) == 0
    with open(out, encoding='utf-8') as stream:
        assert json.load(stream)['criterion'] == 'position'
    assert 'criterion: position' in capsys.readouterr().out
    assert main(['identify', path, '--no-discover', '--json', out, '--quiet',
                 '--criterion', 'speed']) == 0
    with open(out, encoding='utf-8') as stream:
        assert json.load(stream)['criterion'] == 'speed'
    no_position = str(tmp_path / 'speed.csv')
    t, voltage = make_excitation('paper', 2.0, 1e-3)
    current, speed = simulate_motor(MOTOR, voltage, 1e-3, (0.0, 0.0))
    write_csv(no_position, Record(t, current, voltage, speed))
    capsys.readouterr()
    assert main(['identify', no_position, '--no-discover', '--criterion', 'position',
                 '--quiet']) == 2
    assert 'needs a position channel' in capsys.readouterr().err
    with pytest.raises(SystemExit) as raised:
        main(['identify', no_position, '--criterion', 'angle'])
    assert raised.value.code == 2


def test_gain_below_its_held_out_noise_is_not_a_gain():
    """Two fits whose held-out errors differ by noise alone: the noise exceeds the gain."""
    rng = np.random.default_rng(1)
    n = 4000

    def fit_with(residual):
        fitted = Structure()
        return type('F', (), {
            'channel_residual': lambda self, channel, part: residual,
            'heldout_cost': float(np.mean(residual ** 2)), 'structure': fitted,
            'stops': [0], 'simulated': [{'position': residual}],
            'records': [SimpleNamespace(position=np.zeros(n))]})()
    before = fit_with(rng.standard_normal(n))
    after = fit_with(before.channel_residual('position', 'heldout')
                     + 0.05 * rng.standard_normal(n))
    noise = heldout_gain_noise(before, after, ('position',), {'position': 1.0})
    gain = 1.0 - after.heldout_cost / before.heldout_cost
    assert abs(gain) < noise
    better = fit_with(0.5 * before.channel_residual('position', 'heldout'))
    noise = heldout_gain_noise(before, better, ('position',), {'position': 1.0})
    assert 1.0 - better.heldout_cost / before.heldout_cost > noise


def test_discovery_never_ends_worse_than_its_base_on_held_out():
    """The loop on a position-only record: the final held-out error is at most the base's."""
    records = prepare_records([encoder_record(3.0, kind='prbs', seed=3)])
    found = DiscoveryLoop(records, criterion='position').run()
    assert found.final.heldout_cost <= found.base.heldout_cost
    for step in found.steps:
        for candidate in step['candidates']:
            assert {'heldout_gain_pct', 'heldout_gain_noise_pct',
                    'insample_gain_pct'} <= set(candidate)
    worse = type('F', (), {'heldout_cost': 2.0})()
    base = type('F', (), {'heldout_cost': 1.0})()
    kept, reason = never_worse(base, worse, 'stopped')
    assert kept is base and 'base model' in reason
    assert never_worse(base, base, 'stopped') == (base, 'stopped')


def test_loop_finds_a_load_on_position_only_data_and_reports_its_gains(tmp_path):
    """A constant load the base model lacks drifts the position; the loop finds it."""
    from dcmotor_id.reports.identification import write_report
    from dcmotor_id.simulation import MotorEffects, simulate_motor_effects

    dt = 1e-3
    t, voltage = make_excitation('prbs', 3.0, dt, amplitude_v=60)
    current, speed, angle = simulate_motor_effects(
        MOTOR, voltage, dt, MotorEffects(load_torque_Nm=0.3), (0.0, 0.0),
        initial_angle_rad=0.2)
    rng = np.random.default_rng(5)
    lsb = 2 * np.pi / 4096
    rec = Record(t, current + 0.01 * np.std(current) * rng.standard_normal(t.shape[0]),
                 voltage, None, np.round(angle / lsb) * lsb, source='load')
    result = identify(prepare_records([rec]))
    assert result.criterion == 'position'
    first = [effect['name'] for effect in result.effects][:1]
    assert first in (['load_torque'], ['coulomb_asymmetry'])
    found = result.discovery_result
    assert found is not None and found.final.heldout_cost <= found.base.heldout_cost
    added = found.steps[0]['added']['name']
    decided = next(candidate for candidate in found.steps[0]['candidates']
                   if candidate['name'] == added)
    assert decided['heldout_gain_pct'] > decided['heldout_gain_noise_pct']
    assert decided['insample_gain_pct'] > 0
    page = write_report(str(tmp_path / 'report'), result.as_dict(), found, [rec])
    with open(page, encoding='utf-8') as stream:
        text = stream.read()
    assert 'in-sample gain' in text and 'held-out noise' in text
    assert 'criterion position' in text


def test_a_base_fit_with_effects_that_needs_more_evaluations_is_retried(monkeypatch):
    """
    A base fit holding effects (the start check's seeded base) is retried like the bare one.

    Only the discovery loop's candidate refits, on fewer evaluations, keep their bound: on
    EMPS a rounding difference left the seeded base of the second start a few evaluations
    short, and the second start was dropped (16.3 mm on PULSES against 4.15).
    """
    from dcmotor_id.core.errors import FitError
    from dcmotor_id.identification.discovery.structure import Structure
    from dcmotor_id.identification.effects.load_torque import LoadTorque
    from dcmotor_id.identification.estimators.refined import RefinedEstimator
    from dcmotor_id.simulation import MotorEffects, simulate_motor_effects

    dt = 1e-3
    t, voltage = make_excitation('prbs', 3.0, dt, amplitude_v=60)
    current, _, angle = simulate_motor_effects(
        MOTOR, voltage, dt, MotorEffects(load_torque_Nm=0.3), (0.0, 0.0), initial_angle_rad=0.2)
    lsb = 2 * np.pi / 4096
    rec = prepare_records([Record(t, current, voltage, None, np.round(angle / lsb) * lsb)])[0]
    structure = Structure([(LoadTorque, {})])
    records = structure.transformed([rec])
    start = {**MOTOR.as_dict(), 'J': 2 * MOTOR.J, 'b': 0.5 * MOTOR.b}
    terms = structure.terms(records, start, None)
    evaluations = []
    original = RefinedEstimator._fit

    def counted(self, *arguments, **options):
        evaluations.append(options.get('max_nfev', arguments[4] if len(arguments) > 4 else None))
        return original(self, *arguments, **options)

    monkeypatch.setattr(RefinedEstimator, '_fit', counted)
    # this fit needs 11 to 15 evaluations: a base fit given 4 is retried with 4x as many
    base = RefinedEstimator(max_nfev=4, initial=start, criterion='position',
                            initial_state='measured')
    estimate = base.fit(records, terms=terms)
    assert evaluations == [None, 16]
    assert estimate.parameters['J'] == pytest.approx(MOTOR.J, rel=0.05)
    evaluations.clear()
    candidate = RefinedEstimator(max_nfev=4, initial=start, criterion='position',
                                 initial_state='measured', retry=False)
    with pytest.raises(FitError, match='did not converge'):  # a candidate keeps its bound
        candidate.fit(records, terms=terms)
    assert evaluations == [None]
