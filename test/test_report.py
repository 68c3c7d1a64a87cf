"""The before/after report: an HTML page and its PNG plots, from the CLI and the API."""

import json
import os

from matplotlib.image import imread
import numpy as np

from dcmotor_id.cli import main as cli_main
from dcmotor_id.effects import make_effect
from dcmotor_id.excitation import add_sensor_noise, make_excitation
from dcmotor_id.identify import identify
from dcmotor_id.model import PAPER_MOTORS
from dcmotor_id.records import Record
from dcmotor_id.report import write_report
from dcmotor_id.simulation import simulate_motor_effects

DT = 1e-3


def loaded_record(duration_s=5.0, effects=None):
    t, voltage = make_excitation('sine', duration_s, DT)
    effects = effects or [make_effect('load_torque', torque_Nm=0.5)]
    current, speed, _ = simulate_motor_effects(PAPER_MOTORS['paper2'], voltage, DT, effects)
    rng = np.random.default_rng(2)
    return Record(t, add_sensor_noise(current, 0.005, rng), voltage,
                  add_sensor_noise(speed, 0.005, rng), source='loaded.csv')


def check_png(path, min_width=500):
    image = imread(path)
    assert image.ndim == 3 and image.shape[1] >= min_width
    assert np.ptp(image[..., :3]) > 0.5  # not blank


def test_report_with_effects(tmp_path):
    identified = identify([loaded_record()])
    page = write_report(str(tmp_path), identified.as_dict(), identified.discovery_result)
    text = open(page, encoding='utf-8').read()
    for name in ('fit.png', 'residuals.png', 'steps.png'):
        assert f'src="{name}"' in text
        check_png(os.path.join(tmp_path, name))
    assert 'Effects found: <b>load_torque</b>' in text
    assert 'torque_Nm' in text and '95 % interval' in text and 'Ljung-Box' in text
    for name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc'):
        assert f'<td>{name}</td>' in text
    assert 'tie with the added effect' in text  # coulomb_asymmetry, the same model here


def test_report_without_discovery(tmp_path):
    record = loaded_record(3.0)
    result = identify([record], discover=False).as_dict()
    page = write_report(str(tmp_path), result, None, [record])
    text = open(page, encoding='utf-8').read()
    assert 'No effect search' in text and 'steps.png' not in text
    check_png(os.path.join(tmp_path, 'fit.png'))
    check_png(os.path.join(tmp_path, 'residuals.png'))


def test_cli_simulate_with_effect_and_identify_with_report(tmp_path, capsys):
    csv = str(tmp_path / 'drift.csv')
    assert cli_main(['simulate', '--excitation', 'sine', '--duration', '5',
                     '--sample-period', '1e-3', '--noise', '0.005',
                     '--effect', 'resistance_drift:rate_ohm_per_s=0.05', '--out', csv]) == 0
    out = str(tmp_path / 'result.json')
    report = str(tmp_path / 'report')
    assert cli_main(['identify', csv, '--json', out, '--report', report]) == 0
    printed = capsys.readouterr().out
    assert 'effect resistance_drift' in printed and 'report:' in printed
    result = json.load(open(out, encoding='utf-8'))
    assert [effect['name'] for effect in result['effects']] == ['resistance_drift']
    assert os.path.isfile(os.path.join(report, 'index.html'))
    check_png(os.path.join(report, 'fit.png'))


def test_cli_rejects_a_bad_effect(tmp_path, capsys):
    code = cli_main(['simulate', '--effect', 'backlash:gap=1', '--out',
                     str(tmp_path / 'x.csv')])
    assert code == 2
    assert 'unknown effect' in capsys.readouterr().err
