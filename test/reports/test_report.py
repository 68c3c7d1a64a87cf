"""The before/after report: an HTML page and its PNG plots, from the CLI and the API."""

import json
import os

from matplotlib.image import imread
import numpy as np

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.identification.identify import identify
from dcmotor_id.reports.identification import write_report
from dcmotor_id.simulation import simulate_motor_effects
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

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


def test_transients_are_the_largest_input_changes_where_they_happen():
    from dcmotor_id.reports.identification_plots import _transients

    rng = np.random.default_rng(0)
    values = rng.normal(0, 0.01, 5000)
    steps = {700: 2.0, 2500: -3.0, 4000: 1.0, 4990: 5.0}  # the last one: no window after it
    for index, size in steps.items():
        values[index:] += size
    # the step's first sample is where it happens; the one too near the end is left out
    assert _transients(values, 3, 200) == [700, 2500, 4000]
    assert _transients(values, 2, 200) == [700, 2500]
    # equal steps: the earliest ones; steps closer than a window count once
    values = np.zeros(3000)
    for index in (500, 550, 1500, 2200):
        values[index:] += 1.0
    assert _transients(values, 3, 200) == [500, 1500, 2200]
    assert _transients(np.zeros(100), 3, 200) == []  # shorter than a window


def test_report_of_several_records_without_discovery_draws_one_model(tmp_path):
    from dcmotor_id.reports.identification_plots import fit_series, input_series, plot_residuals

    records = [loaded_record(duration, [make_effect('load_torque', torque_Nm=0.2)])
               .replace(source=f'r{number}.csv')
               for number, duration in enumerate((0.6, 1.0))]
    result = identify(records, discover=False).as_dict()
    series, outputs = fit_series(None, records, result)
    assert [len(item['time']) for item in series] == [len(record) for record in records]
    assert all(item['before'] is item['after'] for item in series)  # no base/final pair
    page = write_report(str(tmp_path), result, None, records)
    text = open(page, encoding='utf-8').read()
    for name in ('fit.png', 'residuals.png', 'transients.png'):
        assert f'src="{name}"' in text
        check_png(os.path.join(tmp_path, name))
    # every record its own residual panels (never joined): one record, half the height
    name, inputs = input_series(series, records, None, result)
    plot_residuals(series[:1], outputs, str(tmp_path), name, inputs[:1], name='one.png',
                   sides=(('after', 'model'),))
    assert imread(os.path.join(tmp_path, 'residuals.png')).shape[0] > \
        1.7 * imread(os.path.join(tmp_path, 'one.png')).shape[0]


def test_validation_report_with_position_draws_every_figure(tmp_path):
    from dcmotor_id.identification.validate import model_from_dict, validate
    from dcmotor_id.reports.identification import write_validation_report

    t, voltage = make_excitation('paper', 3.0, DT)
    current, speed, position = simulate_motor_effects(PAPER_MOTORS['paper2'], voltage, DT, [])
    record = Record(t, current, voltage, speed, position=position, source='with_position.csv')
    result = identify([record], discover=False).as_dict()
    validation = validate(model_from_dict(result), [record])
    page = write_validation_report(str(tmp_path), validation)
    text = open(page, encoding='utf-8').read()
    for name in ('validation_fit.png', 'validation_transients.png',
                 'validation_residuals.png'):
        assert f'src="{name}"' in text
        check_png(os.path.join(tmp_path, name))


def test_parameter_table_flags_the_warnings_that_name_a_parameter():
    from dcmotor_id.reports.identification import _flags, _parameter_rows

    result = {'parameters': {'J': 93.0, 'b': 196.0, 'Mc': 21.0, 'La': 1e-5},
              'stderr': {'J': 0.5, 'b': 8.0, 'Mc': 0.8, 'La': 0.0},
              'units': {'J': 'kg m^2', 'b': 'N m s/rad', 'Mc': 'N m', 'La': 'H'},
              'warnings': ['b and Mc are correlated -0.999: determined by the data as a sum',
                           'the model misfits far above the sensor noise'],
              'not_identifiable': {'J': 'no acceleration in the record'},
              'upper_bounds': {'La': 1e-5}}
    flags = {row[0]: row[-1] for row in _parameter_rows(result)}
    assert 'see W1' in flags['b'] and 'see W1' in flags['Mc']  # not the b of 'by'
    assert 'not identifiable: no acceleration' in flags['J'] and 'W' not in flags['J']
    assert 'upper bound only' in flags['La']
    box = _flags(result)
    assert '<b>W1</b> b and Mc' in box and '<b>W2</b> the model misfits' in box
    assert '<b>J</b> not identifiable' in box


def test_the_structure_choice_is_said_whether_covered_or_not():
    from dcmotor_id.reports.identification import structure_parts

    result = {'discover': True, 'stderr': {'J': 0.5, 'b': 9.0}, 'structure_uncertainty': None}
    assert '--structure-bootstrap 20' in ''.join(structure_parts(result))
    assert structure_parts({**result, 'discover': False}) == []
    result['structure_uncertainty'] = {
        'resamples': 10, 'completed': 9, 'failed': 1, 'chosen_share': 0.6,
        'structures': [{'effects': ['quadratic_drag'], 'count': 6, 'share': 6 / 9},
                       {'effects': [], 'count': 3, 'share': 1 / 3}],
        'stderr_structure': {'J': 0.0, 'b': 8.0}, 'stderr_without_structure': {'J': 0.5, 'b': 4.0},
        'included_in_stderr': True}
    page = ''.join(structure_parts(result))
    assert '9 of 10 resamples identified (1 refused)' in page
    assert '<td>quadratic_drag</td><td>6</td>' in page and '<td>no effect</td><td>3</td>' in page
    assert '<td>b</td><td>4</td><td>8</td><td>9</td>' in page and '<td>J</td>' not in page
    skipped = {**result, 'structure_uncertainty': {'skipped': 'discovery is off'}}
    assert 'Not covered: discovery is off' in ''.join(structure_parts(skipped))


def test_the_zoom_is_where_the_base_and_final_models_differ_most(tmp_path):
    from dcmotor_id.reports.identification_plots import plot_fit, zoom_window

    t = np.arange(5000) * DT
    measured = {'current': np.sin(t), 'speed': 10 * np.cos(t)}
    after = {channel: values.copy() for channel, values in measured.items()}
    before = {channel: values.copy() for channel, values in measured.items()}
    before['speed'][3000:3060] += 0.5  # the effect acts here only
    before['current'] += 0.001  # a small offset everywhere weighs less than the bump
    item = {'time': t, 'stop': 3500, 'measured': measured, 'before': before, 'after': after}
    window = zoom_window(item, ['current', 'speed'])
    assert window.start <= 3000 and 3060 <= window.stop and window.stop - window.start == 100
    # the fit figure gets a zoom row per channel when the models differ, none when one model
    plot_fit([item], ['current', 'speed'], str(tmp_path), {'before': {}, 'after': {}})
    one = dict(item, before=after)
    plot_fit([one], ['current', 'speed'], str(tmp_path), {'before': {}, 'after': {}},
             name='one.png')
    assert imread(str(tmp_path / 'fit.png')).shape[0] > \
        1.6 * imread(str(tmp_path / 'one.png')).shape[0]


def test_the_report_says_from_which_units_the_input_was_converted(tmp_path):
    csv = tmp_path / 'run.csv'
    assert cli_main(['simulate', '--excitation', 'sine', '--duration', '3', '--sample-period',
                     '1e-3', '--noise', '0.005', '--out', str(csv)]) == 0
    header, *rows = csv.read_text().strip().split('\n')
    names = header.split(',')
    scaled = tmp_path / 'rpm_ma.csv'
    scale = {'speed': 30 / np.pi, 'current': 1000.0}
    lines = [header]
    for row in rows:
        values = [float(value) * scale.get(name, 1.0) for name, value in
                  zip(names, row.split(','))]
        lines.append(','.join(repr(value) for value in values))
    scaled.write_text('\n'.join(lines) + '\n')
    out, report = tmp_path / 'result.json', tmp_path / 'report'
    assert cli_main(['identify', str(scaled), '--speed-unit', 'rpm', '--current-unit', 'mA',
                     '--no-discover', '--json', str(out), '--report', str(report)]) == 0
    units = json.loads(out.read_text())['input_units']
    assert units['speed'] == {'given': 'rpm', 'si': 'rad/s', 'factor': np.pi / 30}
    assert units['current'] == {'given': 'mA', 'si': 'A', 'factor': 1e-3}
    page = (report / 'index.html').read_text(encoding='utf-8')
    assert ('converted on reading: current from mA to A, x 0.001; speed from rpm to rad/s, '
            'x 0.10472; read as given: voltage in V') in page
    # validate reads the same way and says so too
    checked = tmp_path / 'validation.json'
    assert cli_main(['validate', str(out), str(scaled), '--speed-unit', 'rpm', '--current-unit',
                     'mA', '--json', str(checked), '--report', str(tmp_path / 'val')]) == 0
    assert json.loads(checked.read_text())['input_units']['speed']['given'] == 'rpm'
    page = (tmp_path / 'val' / 'validation.html').read_text(encoding='utf-8')
    assert 'speed from rpm to rad/s, x 0.10472' in page
    # SI as given: said so
    assert cli_main(['identify', str(csv), '--no-discover', '--report',
                     str(tmp_path / 'si')]) == 0
    page = (tmp_path / 'si' / 'index.html').read_text(encoding='utf-8')
    assert 'the file gave voltage in V, current in A, speed in rad/s (SI, nothing converted)' \
        in page
