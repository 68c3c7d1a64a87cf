"""Reading recordings as they come: mapping, units, duty, gear, MATLAB, checks, odd files."""

import math

import numpy as np
import pytest
from scipy.io import savemat

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.formats import csv as csv_format, read_record
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.formats.mapping import ReadOptions
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.simulation import lab_scenarios, simulate_motor_effects
from dcmotor_id.simulation.excitation import make_excitation

DT = 1e-3
COUNTS = 4096


@pytest.fixture(scope='module')
def si_record():
    t, voltage = make_excitation('sine', 3.0, DT, amplitude_v=20.0)
    current, speed, angle = simulate_motor_effects(PAPER_MOTORS['paper2'], voltage, DT, [])
    return Record(t, current=current, voltage=voltage, speed=speed, position=angle,
                  source='si')


def write_table(path, names, columns):
    table = np.column_stack(columns)
    np.savetxt(path, table, delimiter=',', header=','.join(names), comments='', fmt='%.17g')


def test_units_and_mapping_round_trip(tmp_path, si_record):
    r = si_record
    path = str(tmp_path / 'lab.csv')
    write_table(path, ['time', 'm0_voltage', 'i_mA', 'n_rpm', 'enc', 'other'],
                [r.time_s, r.voltage, r.current * 1e3, r.speed * 60 / (2 * math.pi),
                 r.position * COUNTS / (2 * math.pi), np.zeros(len(r))])
    options = ReadOptions(columns={'t': 'time', 'voltage': 'm0_voltage', 'current': 'i_mA',
                                   'speed': 'n_rpm', 'position': 'enc'},
                          current_unit='mA', speed_unit='rpm', position_counts_per_rev=COUNTS)
    read = read_record(path, options=options)
    for name in ('time_s', 'voltage', 'current', 'speed', 'position'):
        np.testing.assert_allclose(getattr(read, name), getattr(r, name), rtol=1e-12,
                                   atol=1e-12)
    si = identify(prepare_records([r]), discover=False).parameters
    mapped = identify(prepare_records([read]), discover=False).parameters
    for name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc'):
        assert mapped[name] == pytest.approx(si[name], rel=1e-6)


@pytest.mark.parametrize('unit, factor', [('rps', 1 / (2 * math.pi)),
                                          ('deg/s', 180 / math.pi), ('rad/s', 1.0)])
def test_speed_units(tmp_path, si_record, unit, factor):
    r = si_record
    path = str(tmp_path / 's.csv')
    write_table(path, ['t', 'voltage', 'current', 'speed'],
                [r.time_s, r.voltage, r.current, r.speed * factor])
    read = read_record(path, options=ReadOptions(speed_unit=unit))
    np.testing.assert_allclose(read.speed, r.speed, rtol=1e-12, atol=1e-12)


def test_speed_as_pulses_per_sample_and_degrees(tmp_path, si_record):
    r = si_record
    path = str(tmp_path / 'p.csv')
    write_table(path, ['t', 'voltage', 'current', 'speed', 'position'],
                [r.time_s, r.voltage, r.current, r.speed * DT * 500 / (2 * math.pi),
                 np.degrees(r.position)])
    read = read_record(path, options=ReadOptions(speed_counts_per_rev=500,
                                                 position_unit='deg'))
    np.testing.assert_allclose(read.speed, r.speed, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(read.position, r.position, rtol=1e-12, atol=1e-12)


def test_gear_ratio_reports_both_shafts(tmp_path, si_record, capsys):
    r = si_record
    path = str(tmp_path / 'g.csv')
    write_table(path, ['t', 'voltage', 'current', 'speed'],
                [r.time_s, r.voltage, r.current, r.speed / 5.0])
    out = str(tmp_path / 'g.json')
    assert cli_main(['identify', path, '--gear-ratio', '5', '--no-discover', '--json', out]) == 0
    import json
    result = json.load(open(out, encoding='utf-8'))
    truth = PAPER_MOTORS['paper2']
    assert result['parameters']['J'] == pytest.approx(truth.J, rel=1e-6)
    assert result['output_shaft']['J'] == pytest.approx(truth.J * 25, rel=1e-6)
    assert result['output_shaft']['Mc'] == pytest.approx(truth.Mc * 5, rel=1e-6)
    assert 'output shaft' in capsys.readouterr().out


def test_voltage_from_duty(tmp_path, si_record):
    r = si_record
    bus = 48.0
    path = str(tmp_path / 'd.csv')
    write_table(path, ['t', 'pwm', 'current', 'speed'],
                [r.time_s, r.voltage / bus, r.current, r.speed])
    options = ReadOptions(columns={'duty': 'pwm'}, bus_voltage=bus)
    np.testing.assert_allclose(read_record(path, options=options).voltage, r.voltage,
                               rtol=1e-12, atol=1e-12)
    path = str(tmp_path / 'dir.csv')
    write_table(path, ['t', 'duty', 'dir', 'current', 'speed'],
                [r.time_s, np.abs(r.voltage) / bus, (r.voltage >= 0).astype(float), r.current,
                 r.speed])
    options = ReadOptions(columns={'direction': 'dir'}, bus_voltage=bus)
    np.testing.assert_allclose(read_record(path, options=options).voltage, r.voltage,
                               rtol=1e-12, atol=1e-12)


def test_duty_out_of_range_is_refused(tmp_path, si_record, capsys):
    r = si_record
    path = str(tmp_path / 'd.csv')
    write_table(path, ['t', 'duty', 'current', 'speed'], [r.time_s, r.voltage, r.current,
                                                          r.speed])
    assert cli_main(['identify', path, '--voltage-from-duty', '24']) == 2
    assert 'duty column must lie in [-1, 1]' in capsys.readouterr().err


def test_an_8_bit_pwm_duty_with_a_direction_pin_is_read_with_its_full_scale(
        tmp_path, si_record, capsys):
    r = si_record
    bus = 48.0
    path = str(tmp_path / 'arduino.csv')
    register = np.round(np.abs(r.voltage) / bus * 255)  # analogWrite 0..255, a direction pin
    write_table(path, ['t', 'duty', 'dir', 'current', 'speed'],
                [r.time_s, register, (r.voltage >= 0).astype(float), r.current, r.speed])
    args = ['identify', path, '--voltage-from-duty', '48', '--column', 'direction=dir',
            '--no-discover']
    assert cli_main(args) == 2
    assert 'give --duty-full-scale 255' in capsys.readouterr().err
    options = ReadOptions(columns={'direction': 'dir'}, bus_voltage=bus, duty_full_scale=255)
    voltage = read_record(path, options=options).voltage
    np.testing.assert_allclose(voltage, np.sign(r.voltage) * register / 255 * bus, atol=1e-12)
    assert np.max(np.abs(voltage - r.voltage)) <= bus / 255


def test_mapped_column_missing_is_named(tmp_path, si_record, capsys):
    path = str(tmp_path / 'x.csv')
    write_csv(path, si_record)
    assert cli_main(['identify', path, '--column', 'voltage=m0_voltage']) == 2
    assert "no column 'm0_voltage'" in capsys.readouterr().err


def test_mat_v5_variables_and_matrix_columns(tmp_path, si_record):
    r = si_record
    path = str(tmp_path / 'rec.mat')
    data = np.column_stack([r.time_s, r.voltage, r.current, r.speed])
    savemat(path, {'data': data, 'theta': r.position[:, None]})
    options = ReadOptions(columns={'t': 'data:1', 'voltage': 'data:2', 'current': 'data:3',
                                   'speed': 'data:4', 'position': 'theta'})
    read = read_record(path, options=options)
    np.testing.assert_array_equal(read.current, r.current)
    np.testing.assert_array_equal(read.position, r.position)
    savemat(path, {'t': r.time_s, 'voltage': r.voltage, 'current': r.current,
                   'speed': r.speed})
    np.testing.assert_array_equal(read_record(path).speed, r.speed)


def test_mat_errors_name_the_variables(tmp_path, si_record, capsys):
    path = str(tmp_path / 'rec.mat')
    savemat(path, {'data': np.zeros((200, 3))})
    assert cli_main(['identify', path]) == 2
    error = capsys.readouterr().err
    assert "no variable 't'" in error and 'the file has data' in error
    assert cli_main(['identify', path, '--column', 't=data:9']) == 2
    assert '3 column(s)' in capsys.readouterr().err


def test_mat_variables_named_like_the_channels_get_the_options_that_map_them(
        tmp_path, si_record, capsys):
    r = si_record
    path = str(tmp_path / 'sim.mat')
    savemat(path, {'tout': r.time_s, 'Va': r.voltage, 'Ia': r.current, 'omega': r.speed})
    assert cli_main(['identify', path]) == 2
    error = capsys.readouterr().err
    assert ('--column t=tout --column voltage=Va --column current=Ia --column speed=omega'
            in error)


def test_mat_simulink_struct_array_elements_are_mapped_one_based(tmp_path, si_record, capsys):
    r = si_record
    path = str(tmp_path / 'scope.mat')
    signals = np.zeros((3,), dtype=[('values', 'O'), ('label', 'O')])
    for number, values in enumerate((r.voltage, r.current, r.speed)):
        signals[number] = (values[:, None], f'signal {number + 1}')
    savemat(path, {'ScopeData': {'time': r.time_s[:, None], 'signals': signals}})
    options = ReadOptions(columns={'t': 'ScopeData.time',
                                   'voltage': 'ScopeData.signals(1).values',
                                   'current': 'ScopeData.signals(2).values',
                                   'speed': 'ScopeData.signals(3).values'})
    read = read_record(path, options=options)
    np.testing.assert_array_equal(read.current, r.current)
    np.testing.assert_array_equal(read.speed, r.speed)
    assert cli_main(['identify', path]) == 2  # the listing names the elements' fields
    assert 'ScopeData.signals(2).values' in capsys.readouterr().err
    for spec, phrase in (('ScopeData.signals.values', 'pick its element'),
                         ('ScopeData.signals(4).values', '3 element(s)')):
        assert cli_main(['identify', path, '--column', 't=ScopeData.time',
                         '--column', f'voltage={spec}']) == 2
        assert phrase in capsys.readouterr().err


def test_mat_v73_through_h5py(tmp_path, si_record):
    h5py = pytest.importorskip('h5py')
    r = si_record
    path = str(tmp_path / 'v73.mat')
    with h5py.File(path, 'w', userblock_size=512) as handle:
        # MATLAB writes column-major: a 4 x N dataset is an N x 4 matrix in MATLAB
        handle['data'] = np.vstack([r.time_s, r.voltage, r.current, r.speed])
    options = ReadOptions(columns={'t': 'data:1', 'voltage': 'data:2', 'current': 'data:3',
                                   'speed': 'data:4'})
    np.testing.assert_array_equal(read_record(path, options=options).voltage, r.voltage)


def test_pwm_sampled_current_is_named(tmp_path, capsys):
    record = lab_scenarios.pwm_sampled_current(lab_scenarios.small_motor_low_rate().records[0])
    path = str(tmp_path / 'pwm.csv')
    write_csv(path, record)
    assert cli_main(['identify', path]) == 2
    error = capsys.readouterr().err
    assert "channel 'current'" in error and 'PWM' in error and 'Traceback' not in error


def test_coarse_speed_is_named(tmp_path, capsys):
    truth = lab_scenarios.HOBBY_MOTOR
    t = np.arange(4000) * DT
    command = 2.0 * np.sin(2 * np.pi * 0.5 * t)
    drive = lab_scenarios.simulate_drive(truth, command, DT)
    speed = lab_scenarios.encoder_speed(drive['angle'], DT, 48)
    path = str(tmp_path / 'enc.csv')
    write_csv(path, Record(t, current=drive['current'], voltage=command, speed=speed))
    assert cli_main(['identify', path]) == 2
    error = capsys.readouterr().err
    assert "channel 'speed'" in error and 'quantised' in error


def test_command_voltage_is_named(tmp_path, capsys):
    scenario = lab_scenarios.coloured_disturbance()
    record = scenario.records[0]
    path = str(tmp_path / 'cmd.csv')
    write_csv(path, record.replace(voltage=np.full(len(record), 24.0)))
    assert cli_main(['identify', path]) == 2
    error = capsys.readouterr().err
    assert "channel 'voltage'" in error and 'command' in error


@pytest.mark.parametrize('content, phrase', [
    (bytes(range(256)) * 40, 'not a CSV text file'),
    ('t,voltage,current,speed\n0,1,2,3\n'.encode('utf-16-le'), 'UTF-16'),
    (b't,voltage,current,speed\n0,1,2,3\n\xe9\xff\xfe\n', 'not UTF-8'),
])
def test_garbage_files_give_a_message(tmp_path, capsys, content, phrase):
    path = tmp_path / 'bad.csv'
    path.write_bytes(content)
    assert cli_main(['identify', str(path)]) == 2
    error = capsys.readouterr().err
    assert phrase in error and 'Traceback' not in error


def test_utf16_with_byte_order_mark_is_read(tmp_path, si_record):
    r = si_record
    lines = ['t,voltage,current,speed'] + [f'{a:.17g},{b:.17g},{c:.17g},{d:.17g}' for a, b, c, d in
                                           zip(r.time_s, r.voltage, r.current, r.speed)]
    path = tmp_path / 'u16.csv'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-16')
    np.testing.assert_array_equal(read_record(str(path)).speed, r.speed)


def test_blocks_join_exactly_and_bad_cells_are_located(tmp_path, si_record, monkeypatch):
    monkeypatch.setattr(csv_format, 'BLOCK_ROWS', 7)
    path = str(tmp_path / 'b.csv')
    write_csv(path, si_record)
    read = read_record(path)
    np.testing.assert_array_equal(read.current, si_record.current)
    text = open(path, encoding='utf-8').read().splitlines()
    text[51] = text[51].replace(',', ',x', 1)
    open(path, 'w', encoding='utf-8').write('\n'.join(text) + '\n')
    with pytest.raises(Exception, match='line 52'):
        read_record(path)


def test_a_row_with_more_fields_than_the_header_is_refused_naming_its_line(tmp_path,
                                                                           si_record):
    # Two lines run together (a logger's lost newline) give a row whose cells shift into
    # the wrong columns: numpy's parser reads only the chosen columns and took it as data.
    path = str(tmp_path / 'run_together.csv')
    write_csv(path, si_record)
    text = open(path, encoding='utf-8').read().splitlines()
    width = len(text[0].split(','))
    text[30] = text[30] + ',' + text[31]
    open(path, 'w', encoding='utf-8').write('\n'.join(text) + '\n')
    with pytest.raises(InputDataError, match=f'line 31 has {2 * width} fields and the header '
                                             f'{width}:'):
        read_record(path)


def test_separators_at_the_end_of_every_row_are_no_field(tmp_path, si_record):
    path = str(tmp_path / 'trailing.csv')
    write_csv(path, si_record)
    text = open(path, encoding='utf-8').read().splitlines()
    open(path, 'w', encoding='utf-8').write(
        '\n'.join([text[0]] + [line + ',' for line in text[1:]]) + '\n')
    np.testing.assert_array_equal(read_record(path).current, si_record.current)


def test_input_units_say_from_what_each_channel_was_converted():
    units = ReadOptions(speed_unit='rpm', current_unit='mA', gear_ratio=10.0,
                        negated=('position',)).input_units()
    assert units['current'] == {'given': 'mA', 'si': 'A', 'factor': 1e-3}
    assert units['speed'] == {'given': 'rpm at the output of a 10:1 gear', 'si': 'rad/s',
                              'factor': pytest.approx(10 * math.pi / 30)}
    assert units['position']['negated'] is True and units['position']['factor'] == 10.0
    assert units['voltage'] == {'given': 'V', 'si': 'V', 'factor': 1.0}
    duty = ReadOptions(bus_voltage=24.0, duty_full_scale=255.0).input_units()['voltage']
    assert duty['given'] == 'duty (full scale 255) on a 24 V bus'
    assert duty['factor'] == pytest.approx(24.0 / 255.0)
    counts = ReadOptions(speed_counts_per_rev=2048.0).input_units()['speed']
    assert counts['factor'] is None and '2048 per rev' in counts['given']


def test_a_records_sample_period_is_computed_once_and_a_replaced_time_gets_its_own():
    # The median step of a long record is asked for dozens of times per identify call.
    t = np.arange(1000) * 1e-3
    record = Record(t, current=np.zeros(1000), voltage=np.zeros(1000), speed=np.zeros(1000))
    assert record.sample_period_s == pytest.approx(1e-3)
    assert vars(record)['sample_period_s'] == record.sample_period_s
    slower = record.replace(time_s=2.0 * t)
    assert slower.sample_period_s == pytest.approx(2e-3)
    assert record.slice(0, 500).sample_period_s == record.sample_period_s


@pytest.mark.parametrize('unit, factor', [('ms', 1e3), ('us', 1e6), ('ns', 1e9)])
def test_a_time_column_in_another_unit_is_read_with_time_unit(tmp_path, si_record, unit,
                                                              factor):
    path = str(tmp_path / f'{unit}.csv')
    write_csv(path, si_record.replace(time_s=np.asarray(si_record.time_s) * factor))
    read = read_record(path, options=ReadOptions(time_unit=unit))
    np.testing.assert_allclose(read.time_s, si_record.time_s, rtol=1e-12, atol=1e-15)
    assert read.sample_period_s == pytest.approx(si_record.sample_period_s)
    np.testing.assert_array_equal(read.current, si_record.current)
    assert ReadOptions(time_unit=unit).input_units()['t'] == {'given': unit, 'si': 's',
                                                              'factor': 1.0 / factor}
    assert 't' not in ReadOptions().input_units()


def test_time_unit_is_refused_for_stamped_formats_and_unknown_units(tmp_path, capsys):
    with pytest.raises(InputDataError, match='--time-unit h: choose one of s, ms, us, ns'):
        ReadOptions(time_unit='h')
    bag = tmp_path / 'run.mcap'
    bag.write_bytes(b'\x89MCAP0\r\n' + bytes(64))
    assert cli_main(['identify', str(bag), '--time-unit', 'ms']) == 2
    error = capsys.readouterr().err
    assert 'carries its own time stamps: drop --time-unit' in error


def test_a_row_of_units_under_the_header_is_named_with_the_options_that_read_them(tmp_path,
                                                                                  si_record):
    path = str(tmp_path / 'units.csv')
    write_csv(path, si_record)
    text = open(path, encoding='utf-8').read().splitlines()
    units = {'t': 'ms', 'voltage': 'V', 'current': 'A', 'speed': 'rpm', 'position': 'deg'}
    row = ','.join(units.get(name, '-') for name in text[0].split(','))
    open(path, 'w', encoding='utf-8').write('\n'.join([text[0], row] + text[1:]) + '\n')
    expected = r"line 2 looks like a row of units under the header \(t 'ms', voltage 'V'"
    with pytest.raises(InputDataError, match=expected + '.*--time-unit'):
        read_record(path)
    text[2] = text[2].replace(',', ',x', 1)  # a bad cell further down is no units row
    open(path, 'w', encoding='utf-8').write('\n'.join(text) + '\n')
    with pytest.raises(InputDataError, match='line 3, column .* is not a number'):
        read_record(path)
