"""The result summary: the CLI table, the node's one-line answer and key-values (no ROS)."""

import math
from types import SimpleNamespace

from dcmotor_id.streaming.summary import (format_errors, format_line, format_table, format_value,
                                          online_key_values, parameter_key_values,
                                          result_key_values, RESULT_KEYS)

RESULT = {
    'method': 'refined', 'mode': 'electromechanical', 'records': ['a.csv', 'b.csv'],
    'n_samples': 12000, 'sample_period_s': 1e-3,
    'parameters': {'Ra': 1.5, 'La': 0.0021, 'CPhi': 0.0821, 'J': 1.2e-5, 'b': 3.4e-6,
                   'Mc': 0.0012, 'Ka': 12.18, 'Ta': 0.0027},
    'stderr': {'Ra': 0.003, 'La': 2e-6, 'CPhi': 1e-5, 'J': 1e-8, 'b': 1e-7, 'Mc': 1e-5,
               'Ka': 0.01, 'Ta': 1e-6},
    'units': {'Ra': 'Ohm', 'La': 'H', 'CPhi': 'V s/rad', 'J': 'kg m^2', 'b': 'N m s/rad',
              'Mc': 'N m', 'Ka': 'rad/(V s)', 'Ta': 's'},
    'error_before': {'current_nrmse_pct': 10.5, 'speed_nrmse_pct': None},
    'error_after': {'current_nrmse_pct': 1.25, 'speed_nrmse_pct': 0.5},
    'effects': [{'name': 'load_torque', 'parameters': {'torque_Nm': 0.25}},
                {'name': 'backlash', 'parameters': {'side': 'both', 'count': 3}}],
    'unexplained': True,
    'paper': {'parameters': {'Ra': 1.49, 'La': 0.00211, 'CPhi': 0.0822, 'J': 1.21e-5,
                             'b': 3.5e-6, 'Mc': 0.00121, 'Ka': 12.17, 'Ta': 0.00271}},
    'bags': ['/tmp/w1', '/tmp/w2'], 'record_errors': ['window 3 not recorded: disk full'],
}

# The texts the CLI and the node produced before the summary had one home.
TABLE = (
    'method: refined   mode: electromechanical   records: 2   samples: 12000   dt: 0.001 s\n'
    'parameter            value        stderr      rel.  unit\n'
    'Ra                     1.5         0.003      0.2%  Ohm\n'
    'La                  0.0021         2e-06   0.0952%  H\n'
    'CPhi                0.0821         1e-05   0.0122%  V s/rad\n'
    'J                  1.2e-05         1e-08   0.0833%  kg m^2\n'
    'b                  3.4e-06         1e-07     2.94%  N m s/rad\n'
    'Mc                  0.0012         1e-05    0.833%  N m\n'
    'Ka                   12.18          0.01   0.0821%  rad/(V s)\n'
    'Ta                  0.0027         1e-06    0.037%  s\n'
    'effect load_torque: torque_Nm = 0.25\n'
    'effect backlash: side = both, count = 3\n'
    'simulation error before: current 10.5 %\n'
    'simulation error after:  current 1.25 %, speed 0.5 %\n'
    'structure remains in the residual that no candidate effect explains')
LINE = (
    'refined: Ra=1.5 Ohm, La=0.0021 H, CPhi=0.0821 V s, J=1.2e-05 kg m^2, b=3.4e-06 N '
    'm s/rad, Mc=0.0012 N m, Ka=12.18 1/Ohm, Ta=0.0027 s (current 1.25 %, speed 0.5 '
    '%; 12000 samples in 2 window(s)); effects: load_torque torque_Nm=0.25; backlash '
    'side=both, count=3; paper: Ra=1.49, La=0.00211, CPhi=0.0822, J=1.21e-05, '
    'b=3.5e-06, Mc=0.00121, Ka=12.17, Ta=0.00271; bags: /tmp/w1, /tmp/w2; not '
    'recorded: window 3 not recorded: disk full')
KEY_VALUES = [
    ('Ra', '1.5'), ('La', '0.0021'), ('CPhi', '0.0821'), ('J', '1.2e-05'), ('b', '3.4e-06'),
    ('Mc', '0.0012'), ('Ka', '12.18'), ('Ta', '0.0027'), ('Ra_stderr', '0.003'),
    ('La_stderr', '2e-06'), ('CPhi_stderr', '1e-05'), ('J_stderr', '1e-08'),
    ('b_stderr', '1e-07'), ('Mc_stderr', '1e-05'), ('Ka_stderr', '0.01'), ('Ta_stderr', '1e-06'),
    ('effect.load_torque.torque_Nm', '0.25'), ('effect.backlash.side', 'both'),
    ('effect.backlash.count', '3.0')]


def test_the_cli_table_is_unchanged():
    assert format_table(RESULT) == TABLE


def test_the_node_line_is_unchanged():
    assert format_line(RESULT) == LINE


def test_a_failed_paper_method_and_no_bags_read_as_before():
    result = dict(RESULT, paper='too short', bags=[], record_errors=[], effects=[])
    assert format_line(result) == LINE.split(' (current')[0] + (
        ' (current 1.25 %, speed 0.5 %; 12000 samples in 2 window(s)); paper failed: too short')


def test_the_line_needs_no_recording_keys():
    result = {key: value for key, value in RESULT.items() if key not in ('bags', 'record_errors')}
    assert format_line(result) == LINE.split('; bags: ')[0]


def test_key_values_are_the_documented_keys_in_order():
    pairs = result_key_values(RESULT)
    assert pairs == KEY_VALUES
    assert [key for key, _ in pairs][:16] == \
        list(RESULT_KEYS) + [f'{key}_stderr' for key in RESULT_KEYS]


def test_missing_values_are_nan_and_numbers_keep_full_precision():
    assert parameter_key_values({'Ra': 1 / 3})[:2] == [('Ra', repr(1 / 3)), ('La', 'nan')]
    assert format_value(None) == 'nan'
    assert format_value(True) == 'True' and format_value('both') == 'both'
    assert format_value(3) == '3.0'
    assert format_errors({'current_nrmse_pct': 1.0, 'speed_nrmse_pct': None}) == 'current 1 %'


def test_online_key_values_end_with_the_convergence_keys():
    estimate = SimpleNamespace(
        parameters=dict.fromkeys(RESULT_KEYS, 2.0), stderr=dict.fromkeys(RESULT_KEYS, math.nan),
        converged=True, innovation_rms={'current': 0.01, 'speed': 0.5}, n_updates=42)
    pairs = online_key_values(estimate)
    assert [key for key, _ in pairs][:16] == \
        list(RESULT_KEYS) + [f'{key}_stderr' for key in RESULT_KEYS]
    assert pairs[16:] == [('converged', 'true'), ('innovation_rms_current_A', '0.01'),
                          ('innovation_rms_speed_rad_s', '0.5'), ('n_updates', '42')]
    assert pairs[8] == ('Ra_stderr', 'nan')


def test_a_parameter_held_at_zero_or_without_error_shows_no_relative_error():
    """A kS held at 0 (one step from rest, no current) prints '-', not 'nan%'."""
    result = dict(RESULT, parameters={'kS': 0.0, 'kV': 0.044, 'kA': 0.0017},
                  stderr={'kS': 1.0, 'kV': 0.0044, 'kA': None},
                  units={'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad'},
                  not_identifiable={'kS': 'one voltage level'})
    rows = format_table(result).splitlines()[2:5]
    assert 'nan' not in ' '.join(rows)
    assert rows[0].split()[:4] == ['kS', '0', '1', '-']
    assert rows[1].split()[3] == '10%'
    assert rows[2].split()[3] == '-'
