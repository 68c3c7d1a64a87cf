"""
Every bad input of the issue: exit code 2, a message naming the problem and what to do.

Each case writes a CSV (or several), runs ``dcmotor-id identify`` in-process and checks the
exit code, that the message names the problem (and the remedy), and that no traceback is
printed.  One case runs as a separate process to check the same at the process boundary.
"""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from dcmotor_id.cli.main import main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.identify import PERIOD_RTOL, prepare_records
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

MOTOR = PAPER_MOTORS['paper2']
DT = 1e-3
HEADER = ['t', 'voltage', 'current', 'speed']


def simulate(voltage, initial_state=(0.0, 0.0), noise=(0.01, 0.05), seed=0):
    """Simulate motor 2 for a voltage; white noise of fixed std [A, rad/s] on the outputs."""
    current, speed = simulate_motor(MOTOR, voltage, DT, initial_state)
    rng = np.random.default_rng(seed)
    t = np.arange(voltage.shape[0]) * DT
    return np.column_stack([t, voltage, current + rng.normal(0, noise[0], t.shape),
                            speed + rng.normal(0, noise[1], t.shape)])


def good_table():
    """Return 3 s of the paper excitation at 1 kHz (identifiable data)."""
    _, voltage = make_excitation('paper', 3.0, DT)
    return simulate(voltage)


def write(path, header, rows):
    """Write a CSV with a header row."""
    with open(path, 'w', newline='', encoding='utf-8') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        for row in rows:
            writer.writerow([repr(float(value)) if isinstance(value, (float, np.floating))
                             else value for value in row])
    return str(path)


def run(capsys, *args):
    """Run ``dcmotor-id identify``; return the exit code and the stderr text."""
    code = main(['identify', *map(str, args)])
    captured = capsys.readouterr()
    assert 'Traceback' not in captured.err + captured.out
    return code, captured.err


def expect_refusal(capsys, args, *phrases):
    """Assert exit code 2 and every phrase (case-insensitive) in the error message."""
    code, message = run(capsys, *args)
    assert code == 2, message
    # a fit that runs beyond 2 s (a loaded machine) prints its progress before the error
    start = message.find('dcmotor-id: error: ')
    assert start >= 0, message
    assert all(line.startswith('dcmotor-id: ') and ' s ' in line
               for line in message[:start].splitlines()), message
    message = message[start:]
    for phrase in phrases:
        assert phrase.lower() in message.lower(), (phrase, message)
    return message


@pytest.fixture(scope='module')
def table():
    """Return the good data (samples x [t, voltage, current, speed])."""
    return good_table()


@pytest.fixture
def out(tmp_path):
    """Return the path of the JSON result (never written on refusal)."""
    return tmp_path / 'result.json'


def test_good_data_pass(table, tmp_path, out, capsys):
    code, message = run(capsys, write(tmp_path / 'good.csv', HEADER, table), '--json', out)
    assert code == 0, message
    assert out.exists()


@pytest.mark.parametrize('header, phrases', [
    (['time', 'voltage', 'current', 'speed'], ['no time column t', "found 'time'", 'rename']),
    (['t', 'Voltage', 'current', 'speed'], ["'Voltage' must be named 'voltage'", 'rename']),
    (['t', 'voltage', 'amps', 'speed'], ["found 'amps'", 'rename it to current']),
    (['t', 'voltage', 'current', 'rpm'], ["found 'rpm'", 'rename it to speed', 'rad/s']),
    (['t', 'voltage', 'current', 'x2'], ['speed (or position)', 'name the columns']),
    (['t', 'volts_in', 'current', 'speed'], ['no voltage column', '--torque-constant']),
    (['t', 'voltage', 'current', 'current'], ["'current' appears twice"]),
])
def test_missing_or_misnamed_columns(table, tmp_path, out, capsys, header, phrases):
    path = write(tmp_path / 'named.csv', header, table)
    expect_refusal(capsys, [path, '--json', out], *phrases)
    assert not out.exists()


def test_a_current_under_another_name_is_not_fitted_silently(table, tmp_path, out, capsys):
    """Issue 31: no current column gives kS, kV, kA, with a warning naming the fix."""
    path = write(tmp_path / 'named.csv', ['t', 'voltage', 'x1', 'speed'], table)
    code, message = run(capsys, path, '--json', out)
    assert code == 0, message
    result = json.loads(out.read_text())
    assert result['mode'] == 'voltage_speed' and set(result['parameters']) == {'kS', 'kV', 'kA'}
    assert any('name its column current' in text for text in result['warnings'])


def test_columns_named_with_units_get_the_options_that_map_them(table, tmp_path, out, capsys):
    header = ['Time [s]', 'Voltage (V)', 'Current (A)', 'velocity']
    path = write(tmp_path / 'units.csv', header, table)
    options = ["--column 't=Time [s]'", "--column 'voltage=Voltage (V)'",
               "--column 'current=Current (A)'", '--column speed=velocity']
    expect_refusal(capsys, [path, '--json', out], "found 'Current (A)'", *options)
    mapped = ['--column', 't=Time [s]', '--column', 'voltage=Voltage (V)',
              '--column', 'current=Current (A)', '--column', 'speed=velocity']
    code, message = run(capsys, path, '--no-discover', '--json', out, *mapped)
    assert code == 0, message


@pytest.mark.parametrize('column, value', [(2, 'nan'), (3, 'inf'), (1, '-inf'), (0, 'nan')])
def test_nan_and_inf(table, tmp_path, out, capsys, column, value):
    rows = table.tolist()
    rows[50][column] = value
    path = write(tmp_path / 'nan.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], f"column '{HEADER[column]}'", 'NaN/inf',
                   'sample 50', 'remove or repair')


def test_non_numeric_cell(table, tmp_path, out, capsys):
    rows = table.tolist()
    rows[7][1] = 'twelve'
    path = write(tmp_path / 'text.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], "line 9, column 'voltage'", 'not a number',
                   'fix or remove')


def test_non_monotonic_timestamps(table, tmp_path, out, capsys):
    rows = table.tolist()
    rows[70], rows[71] = rows[71], rows[70]
    path = write(tmp_path / 'backwards.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], 'timestamps go backwards', 'sample 71',
                   'sort the samples by time')


def test_duplicate_timestamps(table, tmp_path, out, capsys):
    rows = table.tolist()
    rows.insert(80, list(rows[80]))
    path = write(tmp_path / 'duplicate.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], 'duplicate timestamp', 'remove duplicated')


def test_irregular_sampling_refused_with_reason_and_resampled_on_request(table, tmp_path, out,
                                                                         capsys):
    rows = np.delete(table, [100, 101, 102], axis=0)  # a 4 ms gap
    path = write(tmp_path / 'gap.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], 'irregular sampling', '0.004',
                   'median of 0.001', '--resample', '1 gap(s)', 'about 3 samples missing',
                   'split the record')
    code, message = run(capsys, path, '--json', out, '--resample')
    assert code == 0, message
    assert out.exists()


def test_jittered_timestamps_are_resampled_onto_a_uniform_grid(table):
    rng = np.random.default_rng(1)
    t = table[:, 0] + rng.uniform(-0.2, 0.2, table.shape[0]) * DT
    record = Record(t, table[:, 2], table[:, 1], table[:, 3], source='jitter')
    with pytest.raises(InputDataError, match='irregular sampling') as refusal:
        prepare_records([record])
    assert 'jitter' in str(refusal.value) and '--sample-period 0.001' in str(refusal.value)
    assert 'gap' not in str(refusal.value)
    uniform = prepare_records([record], resample=True)[0]
    assert np.allclose(np.diff(uniform.time_s), uniform.sample_period_s, rtol=1e-9)


def test_too_few_samples(table, tmp_path, out, capsys):
    path = write(tmp_path / 'short.csv', HEADER, table[:20])
    expect_refusal(capsys, [path, '--json', out], 'only 20 samples', 'at least',
                   'record for longer')


def test_empty_file_and_header_only(tmp_path, out, capsys):
    empty = tmp_path / 'empty.csv'
    empty.write_text('')
    expect_refusal(capsys, [empty, '--json', out], 'the file is empty', 'header row')
    header_only = write(tmp_path / 'header.csv', HEADER, [])
    expect_refusal(capsys, [header_only, '--json', out], 'header but no samples')


def test_missing_file_and_wrong_delimiter(table, tmp_path, out, capsys):
    expect_refusal(capsys, [tmp_path / 'nothere.csv', '--json', out], 'no such file')
    # Issue 19: semicolon- and tab-separated files are read now; spaces still are not.
    path = tmp_path / 'spaces.csv'
    path.write_text(' '.join(HEADER) + '\n'
                    + '\n'.join(' '.join(repr(v) for v in row) for row in table[:200]))
    expect_refusal(capsys, [path, '--json', out], 'separated by commas, semicolons or tabs')


def test_constant_voltage(tmp_path, out, capsys):
    u = 100.0
    balance = np.array([[MOTOR.Ra, MOTOR.CPhi], [MOTOR.CPhi, -MOTOR.b]])
    steady = np.linalg.solve(balance, [u, MOTOR.Mc])
    rows = simulate(np.full(3000, u), initial_state=tuple(steady))
    path = write(tmp_path / 'constant.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], 'voltage is constant',
                   'not identifiable', 'La, J, b and Mc', 'changing voltage')


def test_an_angle_in_degrees_wrapping_at_360_is_named_with_its_unit_option(tmp_path, out,
                                                                           capsys):
    # An absolute encoder read in degrees (0-360) without --position-unit deg was refused as a
    # voltage command that never reaches the motor: the message names the unit instead.
    voltage = np.full(3000, 100.0)
    current, speed = simulate_motor(MOTOR, voltage, DT)
    current = current + np.random.default_rng(0).normal(0.0, 0.01, current.shape)
    angle = np.degrees(np.cumsum(speed) * DT) % 360.0
    rows = np.column_stack([np.arange(3000) * DT, voltage, current, angle])
    header = ['t', 'voltage', 'current', 'position']
    path = write(tmp_path / 'degrees.csv', header, rows)
    message = expect_refusal(capsys, [path, '--json', out], 'jumps by about 360',
                             'an angle in degrees that wraps at 360', 'pass --position-unit deg')
    assert message.index('--position-unit deg') < message.index('never reaches the motor')
    code, message = run(capsys, path, '--position-unit', 'deg', '--json', out)
    assert code == 0, message
    # The same jumps beyond [0, 360] are no angle in degrees: the voltage is the suspect.
    path = write(tmp_path / 'beyond.csv', header, np.column_stack([rows[:, :3], angle + 400.0]))
    message = expect_refusal(capsys, [path, '--json', out], 'never reaches the motor')
    assert '--position-unit' not in message


def test_motor_never_moves(tmp_path, out, capsys):
    # 1 V gives a stall torque CPhi u / Ra = 0.44 N m below Mc = 1 N m: the shaft never moves.
    t = np.arange(3000) * DT
    rows = simulate(np.sin(2 * np.pi * 2.0 * t))
    assert np.all(simulate_motor(MOTOR, np.sin(2 * np.pi * 2.0 * t), DT)[1] == 0.0)
    path = write(tmp_path / 'still.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--json', out], 'never moves', 'CPhi, J, b and Mc',
                   'not identifiable', 'while the motor turns')


def test_speed_never_reverses_is_identified_partially(tmp_path, out, capsys):
    # Issue 8 changed this from a refusal: one-direction data identify J, b and the
    # direction's total friction torque; Mc and a load torque are listed as not separable.
    t = np.arange(3000) * DT
    rows = simulate(60.0 + 40.0 * np.sin(2 * np.pi * 1.0 * t))
    path = write(tmp_path / 'forward.csv', HEADER, rows)
    code, message = run(capsys, path, '--json', out, '--no-discover')
    assert code == 0, message
    result = json.loads(out.read_text())
    assert 'never reverses' in result['not_identifiable']['Mc']
    assert 'load_torque' in result['not_identifiable']
    assert result['combined']['friction_torque_Nm']['direction'] == 'positive'
    for name in ('J', 'b'):
        assert abs(result['parameters'][name] / getattr(MOTOR, name) - 1) < 0.05, name
    # The mechanical-only mode too.
    shaft = write(tmp_path / 'shaft.csv', ['t', 'current', 'speed'], rows[:, [0, 2, 3]])
    code, message = run(capsys, shaft, '--json', out, '--torque-constant', '0.7',
                        '--no-discover')
    assert code == 0, message
    assert 'Mc' in json.loads(out.read_text())['not_identifiable']


@pytest.mark.parametrize('method, phrases', [
    ('paper', ['non-physical values', 'signs and units']),
    ('refined', ['does not reproduce the data', 'units, signs']),
])
def test_non_physical_results(table, tmp_path, out, capsys, method, phrases):
    flipped = table.copy()
    flipped[:, 2] *= -1.0  # current sensor wired the wrong way round
    path = write(tmp_path / 'flipped.csv', HEADER, flipped)
    expect_refusal(capsys, [path, '--json', out, '--method', method], *phrases)
    assert not out.exists()


def test_records_with_different_sample_periods(table, tmp_path, out, capsys):
    first = write(tmp_path / 'a.csv', HEADER, table)
    slow = table[::2].copy()
    second = write(tmp_path / 'b.csv', HEADER, slow)
    expect_refusal(capsys, [first, second, '--json', out], 'different sample periods',
                   'identify them separately or resample')


def stretched(table, stretch):
    """Return the table with its time column stretched by ``1 + stretch``."""
    rows = table.copy()
    rows[:, 0] *= 1.0 + stretch
    return rows


@pytest.mark.parametrize('stretch', [2.6e-5, -0.9 * PERIOD_RTOL])
def test_sample_periods_within_clock_jitter_are_one_period(table, stretch):
    # EMPS's two records: 0.999984 ms and 1.00001 ms, one clock logged with rounding.
    first = Record(table[:, 0], table[:, 2], table[:, 1], table[:, 3], source='a')
    second = first.replace(time_s=stretched(table, stretch)[:, 0], source='b')
    prepared = prepare_records([first, second])
    assert prepared[0].sample_period_s == pytest.approx(prepared[1].sample_period_s, rel=1e-12)
    assert prepared[1].sample_period_s == pytest.approx(DT * (1.0 + stretch / 2), rel=1e-9)
    assert np.array_equal(prepared[1].speed, second.speed)
    assert prepared[1].time_s[0] == second.time_s[0]


def test_records_at_one_period_within_clock_jitter_are_identified(table, tmp_path, out, capsys):
    first = write(tmp_path / 'a.csv', HEADER, table)
    second = write(tmp_path / 'b.csv', HEADER, stretched(table, 2.6e-5))
    code, message = run(capsys, first, second, '--no-discover', '--json', out)
    assert code == 0, message
    assert len(json.loads(out.read_text(encoding='utf-8'))['records']) == 2


def test_periods_beyond_the_tolerance_are_refused(table, tmp_path, out, capsys):
    first = write(tmp_path / 'a.csv', HEADER, table)
    second = write(tmp_path / 'b.csv', HEADER, stretched(table, 3 * PERIOD_RTOL))
    expect_refusal(capsys, [first, second, '--json', out], 'different sample periods',
                   'identify them separately or resample')


def test_speed_cutoff_above_nyquist(table, tmp_path, out, capsys):
    position = np.concatenate([[0.0], np.cumsum(table[:-1, 3]) * DT])
    rows = np.column_stack([table[:, :3], position])
    path = write(tmp_path / 'encoder.csv', ['t', 'voltage', 'current', 'position'], rows)
    expect_refusal(capsys, [path, '--json', out, '--speed-cutoff', '800'], 'Nyquist',
                   '500 Hz', 'lower cut-off')


def test_refusal_at_the_process_boundary(table, tmp_path):
    rows = table.tolist()
    rows[10][3] = 'nan'
    path = write(tmp_path / 'nan.csv', HEADER, rows)
    completed = subprocess.run(
        [sys.executable, '-m', 'dcmotor_id.cli.main', 'identify', path, '--json',
         str(tmp_path / 'r.json')], capture_output=True, text=True, timeout=60)
    assert completed.returncode == 2
    assert 'Traceback' not in completed.stderr
    assert "column 'speed' has 1 NaN/inf value(s)" in completed.stderr


@pytest.mark.parametrize('count', ['1', '-3', '2.5'])
def test_an_unusable_structure_bootstrap_is_refused_before_any_fit(table, tmp_path, out, capsys,
                                                                   count):
    with pytest.raises(SystemExit) as exit_:
        main(['identify', write(tmp_path / 'good.csv', HEADER, table), '--json', str(out),
              '--structure-bootstrap', count])
    assert exit_.value.code == 2
    message = capsys.readouterr().err
    assert 'argument --structure-bootstrap: give a whole number' in message, message
    assert 'Traceback' not in message and not out.exists()


def test_structure_bootstrap_is_reported_in_the_json(table, tmp_path, out, capsys):
    code, message = run(capsys, write(tmp_path / 'good.csv', HEADER, table), '--json', out,
                        '--structure-bootstrap', 2)
    assert code == 0, message
    info = json.loads(out.read_text())['structure_uncertainty']
    assert info['resamples'] == 2 and info['completed'] + info['failed'] == 2
    assert sum(item['count'] for item in info['structures']) == info['completed']


@pytest.mark.parametrize('column, channel', [(3, 'speed'), (2, 'current'), (1, 'voltage')])
def test_a_reversed_channel_is_named_and_negate_fixes_it(table, tmp_path, out, capsys, column,
                                                         channel):
    rows = table.copy()
    rows[:, column] *= -1.0  # an encoder counting the other way, a sensor mounted reversed
    path = write(tmp_path / 'reversed.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--no-discover'], f'the {channel} looks reversed',
                   f'--negate {channel}')
    code, message = run(capsys, path, '--no-discover', '--negate', channel, '--json', out)
    assert code == 0, message
    parameters = json.loads(out.read_text())['parameters']
    assert parameters['CPhi'] == pytest.approx(MOTOR.CPhi, rel=0.02)
    assert parameters['J'] == pytest.approx(MOTOR.J, rel=0.05)


def test_a_reversed_speed_is_named_in_the_mechanical_only_mode(table, tmp_path, capsys):
    rows = table.copy()
    rows[:, 3] *= -1.0
    path = write(tmp_path / 'reversed.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--no-discover', '--torque-constant', str(MOTOR.CPhi)],
                   'the speed looks reversed', 'J = -', '--negate speed')


def test_ka_and_ta_errors_of_an_armature_resistance_at_its_bound_are_infinite():
    from dcmotor_id.core.model import derived_stderr

    # Ra pressed to 1e-170 Ohm by a reversed voltage: its square underflowed to a division
    # by zero, an internal error instead of the refusal
    errors = derived_stderr({'Ra': 1e-170, 'La': 1e-3}, np.eye(2), ['Ra', 'La'])
    assert errors == {'Ka': np.inf, 'Ta': np.inf}


def test_a_current_of_zero_is_not_called_reversed(table, tmp_path, capsys):
    rows = table.copy()
    rows[:, 2] = 0.0  # a current sensor that was not connected: no flip mends it
    path = write(tmp_path / 'nocurrent.csv', HEADER, rows)
    message = expect_refusal(capsys, [path, '--no-discover'])
    assert 'looks reversed' not in message


def test_a_constant_current_in_steady_state_is_refused_in_the_mechanical_only_mode(
        table, tmp_path, capsys):
    rows = table.copy()
    rows[:, 2], rows[:, 3] = 2.0, 10.0  # one torque, one speed: b w + Mc = K i only
    path = write(tmp_path / 'steady.csv', HEADER, rows)
    expect_refusal(capsys, [path, '--torque-constant', '0.7'], 'the current is constant',
                   'J is not identifiable', 'changing current')


def test_degrees_wrapping_at_360_under_a_varying_voltage_are_named_in_the_refusal(
        tmp_path, out, capsys):
    # With a varying voltage the read-time check has nothing to say; the fit on an angle
    # read 57 times too large was refused with "check the units" only.
    t = np.arange(3000) * DT
    voltage = 100.0 * np.sin(2 * np.pi * 1.0 * t)
    current, speed = simulate_motor(MOTOR, voltage, DT)
    angle = np.degrees(np.cumsum(speed) * DT) % 360.0
    path = write(tmp_path / 'degrees.csv', ['t', 'voltage', 'current', 'position'],
                 np.column_stack([t, voltage, current, angle]))
    expect_refusal(capsys, [path, '--json', out, '--no-discover'], 'does not reproduce',
                   'an angle in degrees that wraps at 360', 'pass --position-unit deg')
    code, message = run(capsys, path, '--position-unit', 'deg', '--json', out, '--no-discover')
    assert code == 0, message
