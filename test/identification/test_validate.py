"""``dcmotor-id validate``: open-loop simulation of an identified model on new records."""

import json

import numpy as np
import pytest

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.identification.identify import identify
from dcmotor_id.identification.validate import load_model, model_from_dict, validate
from dcmotor_id.simulation import simulate_motor_effects
from dcmotor_id.simulation.excitation import make_excitation

DT = 1e-3
EFFECTS = [make_effect('load_torque', torque_Nm=0.3), make_effect('stribeck', excess_Nm=0.4,
                                                                  velocity_rad_s=2.0)]


def simulated(kind, seed=0, duration_s=4.0, position=True, source=None):
    t, voltage = make_excitation(kind, duration_s, DT, amplitude_v=20.0, seed=seed)
    current, speed, angle = simulate_motor_effects(PAPER_MOTORS['paper2'], voltage, DT,
                                                   EFFECTS, initial_state=(0.0, 0.0))
    return Record(t, current=current, voltage=voltage, speed=speed,
                  position=angle if position else None, source=source or f'{kind}.csv')


def truth_model():
    params = PAPER_MOTORS['paper2']
    return model_from_dict({
        'mode': 'full', 'parameters': {name: getattr(params, name)
                                       for name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')},
        'effects': [effect.describe() for effect in EFFECTS], 'sample_period_s': DT})


def test_the_true_model_reproduces_noise_free_records():
    records = [simulated('prbs', 1), simulated('chirp', 2, position=False)]
    result = validate(truth_model(), records).as_dict()
    first, second = result['records']
    for item in (first, second):
        assert item['fit_pct']['current'] > 99.999 and item['fit_pct']['speed'] > 99.999
        assert item['current_nrmse_pct'] < 1e-3 and item['speed_nrmse_pct'] < 1e-3
    assert first['fit_pct']['position'] > 99.999 and first['position_rmse'] < 1e-6
    assert second['position_rmse'] is None and second['fit_pct']['position'] is None
    assert first['samples'] == 4000 and first['source'] == 'prbs.csv'


def test_identify_json_carries_the_model_and_validate_scores_other_records(tmp_path, capsys):
    train = str(tmp_path / 'train.csv')
    write_csv(train, simulated('sine', 0))
    for seed, kind in ((1, 'prbs'), (2, 'multisine')):
        write_csv(str(tmp_path / f'{kind}.csv'), simulated(kind, seed))
    model_json = str(tmp_path / 'model.json')
    assert cli_main(['identify', train, '--json', model_json]) == 0
    model = json.load(open(model_json, encoding='utf-8'))['model']
    assert model['mode'] == 'full' and model['sample_period_s'] == pytest.approx(DT)
    assert {effect['name'] for effect in model['effects']} >= {'load_torque'}
    out = str(tmp_path / 'validation.json')
    report = str(tmp_path / 'report')
    capsys.readouterr()
    assert cli_main(['validate', model_json, str(tmp_path / 'prbs.csv'),
                     str(tmp_path / 'multisine.csv'), '--json', out, '--report', report,
                     '--init-samples', '10']) == 0
    printed = capsys.readouterr().out
    assert 'prbs.csv' in printed and 'fit w %' in printed
    result = json.load(open(out, encoding='utf-8'))
    assert set(result) >= {'records', 'model'}
    for item in result['records']:
        assert set(item) == {'source', 'samples', 'current_nrmse_pct', 'speed_nrmse_pct',
                             'fit_pct', 'position_rmse'}
        assert set(item['fit_pct']) == {'current', 'speed', 'position'}
        assert item['fit_pct']['speed'] > 98.0 and item['fit_pct']['current'] > 98.0
    assert (tmp_path / 'report' / 'validation.html').is_file()
    assert (tmp_path / 'report' / 'validation_fit.png').is_file()


def test_mechanical_model_has_no_current_score():
    params = PAPER_MOTORS['paper2']
    record = simulated('sine', 0)
    model = model_from_dict({'mode': 'mechanical', 'torque_constant': params.CPhi,
                             'parameters': {'J': params.J, 'b': params.b, 'Mc': params.Mc},
                             'effects': [effect.describe() for effect in EFFECTS]})
    item = validate(model, [record]).as_dict()['records'][0]
    assert item['current_nrmse_pct'] is None and item['fit_pct']['current'] is None
    # the held current is the trapezoid of the samples: close, not exact
    assert item['fit_pct']['speed'] > 99.0


def test_sensor_delay_and_offset_are_simulated():
    delayed = [make_effect('sensor_delay', channel='speed', samples=3),
               make_effect('current_offset', offset_A=0.2)]
    t, voltage = make_excitation('prbs', 3.0, DT, amplitude_v=20.0, seed=4)
    current, speed, _ = simulate_motor_effects(PAPER_MOTORS['paper2'], voltage, DT, delayed)
    record = Record(t, current=current, voltage=voltage, speed=speed, source='d')
    params = PAPER_MOTORS['paper2']
    model = model_from_dict({'mode': 'full', 'parameters': params.as_dict()
                             if hasattr(params, 'as_dict') else
                             {n: getattr(params, n) for n in ('Ra', 'La', 'CPhi', 'J', 'b',
                                                              'Mc')},
                             'effects': [effect.describe() for effect in delayed],
                             'sample_period_s': DT})
    item = validate(model, [record]).as_dict()['records'][0]
    assert item['fit_pct']['speed'] > 99.99 and item['fit_pct']['current'] > 99.99


def delay_model(samples):
    params = PAPER_MOTORS['paper2']
    return {'mode': 'full', 'sample_period_s': DT,
            'parameters': {n: getattr(params, n) for n in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')},
            'effects': [{'name': 'sensor_delay',
                         'parameters': {'channel': 'speed', 'samples': samples}}]}


def test_a_sensor_delay_longer_than_the_initial_samples_is_simulated():
    # 50 samples late, beyond the 20 initial samples (it crashed in the initial-state fit)
    delayed = [make_effect('sensor_delay', channel='speed', samples=50)]
    t, voltage = make_excitation('prbs', 3.0, DT, amplitude_v=20.0, seed=4)
    current, speed, _ = simulate_motor_effects(PAPER_MOTORS['paper2'], voltage, DT, delayed)
    record = Record(t, current=current, voltage=voltage, speed=speed, source='d')
    item = validate(model_from_dict(delay_model(50)), [record]).as_dict()['records'][0]
    assert item['fit_pct']['speed'] > 99.99 and item['fit_pct']['current'] > 99.99


@pytest.mark.parametrize('samples, phrases', [
    (-1500, ('sensor_delay has samples=-1500:', 'not physical', 'remove that effect')),
    (-16, ('sensor_delay has samples=-16:', 'not physical', 'identify again')),
    (1000, ('delays the speed by 1000 samples', 'the 980 samples scored', 'longer record')),
    (5000, ('delays the speed by 5000 samples', 'remove or correct that effect')),
])
def test_a_negative_or_too_long_sensor_delay_is_refused_clearly(tmp_path, capsys, samples,
                                                                phrases):
    model = tmp_path / 'model.json'
    model.write_text(json.dumps(delay_model(samples)), encoding='utf-8')
    data = tmp_path / 'data.csv'
    write_csv(str(data), simulated('sine', 0, 1.0))
    assert cli_main(['validate', str(model), str(data)]) == 2
    err = capsys.readouterr().err
    assert all(phrase in err for phrase in phrases), err
    assert 'not finite' not in err


@pytest.mark.parametrize('content, phrase', [
    ('not json', 'not a JSON file'),
    ('{"parameters": {"Ra": -1}}', 'parameter Ra'),
    ('[1, 2]', 'not an identify result'),
])
def test_bad_model_files_are_refused(tmp_path, capsys, content, phrase):
    model = tmp_path / 'model.json'
    model.write_text(content, encoding='utf-8')
    data = tmp_path / 'data.csv'
    write_csv(str(data), simulated('sine', 0, 1.0))
    assert cli_main(['validate', str(model), str(data)]) == 2
    assert phrase in capsys.readouterr().err


def test_load_model_reads_an_old_result_without_the_model_block(tmp_path):
    params = PAPER_MOTORS['paper2']
    path = tmp_path / 'old.json'
    path.write_text(json.dumps({'mode': 'full', 'effects': [], 'sample_period_s': DT,
                                'parameters': {n: getattr(params, n) for n in
                                               ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')}}))
    model = load_model(str(path))
    assert model.parameters['Ra'] == pytest.approx(params.Ra) and not model.effects
    assert np.isclose(model.sample_period_s, DT)


def test_identify_result_model_block_round_trips():
    identified = identify([simulated('sine', 0)], discover=False)
    model = model_from_dict(identified.as_dict())
    assert model.parameters['Ra'] == pytest.approx(identified.parameters['Ra'])


@pytest.mark.parametrize('negated, named', [(('speed', 'position'), '--negate speed'),
                                            (('current',), '--negate current'),
                                            (None, '--negate voltage')])
def test_a_record_with_a_reversed_channel_is_said_to_be_reversed(negated, named):
    record = simulated('prbs', 3)
    if negated is None:  # the input reversed: the drive's outputs follow the true voltage
        reversed_record = record.replace(voltage=-record.voltage)
    else:
        reversed_record = record.replace(**{name: -getattr(record, name) for name in negated})
    assert not validate(truth_model(), [record]).warnings
    warnings = validate(truth_model(), [reversed_record]).warnings
    assert len(warnings) == 1 and 'sign flipped' in warnings[0] and named in warnings[0]
