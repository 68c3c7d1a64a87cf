"""The CLI contract: commands, options, JSON keys, exit codes (other tools depend on them)."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from dcmotor_id.cli.main import main
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.csv import read_csv

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
#: Where the console script is installed: next to this interpreter (``make test`` runs the
#: tests with .venv/bin/python), in the repository's .venv, or on the PATH.
CONSOLE_SCRIPTS = (os.path.join(os.path.dirname(sys.executable), 'dcmotor-id'),
                   os.path.join(ROOT, '.venv', 'bin', 'dcmotor-id'),
                   shutil.which('dcmotor-id') or '')
PARAMETER_KEYS = {'Ra', 'La', 'CPhi', 'J', 'b', 'Mc', 'Ka', 'Ta'}
ERROR_KEYS = {'current_nrmse_pct', 'speed_nrmse_pct'}


@pytest.fixture(scope='module')
def simulated_csv(tmp_path_factory):
    """Simulate motor 2 with the CLI: 4 s of the paper excitation at 1 kHz, 0.5 % noise."""
    path = str(tmp_path_factory.mktemp('cli') / 'paper2.csv')
    assert main(['simulate', '--motor', 'paper2', '--excitation', 'paper', '--duration', '4',
                 '--sample-period', '1e-3', '--noise', '0.005', '--out', path]) == 0
    return path


def check_contract(result, mechanical=False):
    """Assert the JSON layout of the CLI contract."""
    keys = {'J', 'b', 'Mc'} if mechanical else PARAMETER_KEYS
    assert set(result['parameters']) == keys
    assert set(result['stderr']) == keys
    assert isinstance(result['method'], str)
    assert isinstance(result['effects'], list)
    assert all({'name', 'parameters'} <= set(effect) for effect in result['effects'])
    for errors in (result['error_before'], result['error_after']):
        assert set(errors) == ERROR_KEYS
        assert errors['speed_nrmse_pct'] > 0
        if mechanical:
            assert errors['current_nrmse_pct'] is None
        else:
            assert errors['current_nrmse_pct'] > 0
    assert all(np.isfinite(value) for value in result['parameters'].values())
    assert all(np.isfinite(value) and value >= 0 for value in result['stderr'].values())


def test_simulate_writes_the_standard_columns(simulated_csv):
    record = read_csv(simulated_csv)
    assert len(record) == 4000
    assert record.sample_period_s == pytest.approx(1e-3)
    assert record.voltage is not None and record.current is not None
    assert record.speed is not None
    with open(simulated_csv, encoding='utf-8') as stream:
        assert stream.readline().strip() == 't,voltage,current,speed'


def test_installed_console_script_identify(simulated_csv, tmp_path):
    installed = [path for path in CONSOLE_SCRIPTS if path and os.access(path, os.X_OK)]
    assert installed, f'the console script dcmotor-id is not installed in {CONSOLE_SCRIPTS}'
    out = tmp_path / 'result.json'
    completed = subprocess.run(
        [installed[0], 'identify', simulated_csv, '--json', str(out), '--no-discover'],
        capture_output=True, text=True, timeout=120)
    assert completed.returncode == 0, completed.stderr
    result = json.loads(out.read_text())
    check_contract(result)
    assert result['method'] == 'refined'
    assert result['effects'] == []  # --no-discover
    truth = PAPER_MOTORS['paper2'].as_dict()
    for name, value in result['parameters'].items():
        assert value == pytest.approx(truth[name], rel=0.01), name
    # stdout is a readable table naming every parameter.
    for name in PARAMETER_KEYS:
        assert f'\n{name} ' in completed.stdout
    assert 'simulation error' in completed.stdout


def test_paper_method_and_json_written(simulated_csv, tmp_path, capsys):
    out = tmp_path / 'sub' / 'paper.json'
    assert main(['identify', simulated_csv, '--json', str(out), '--method', 'paper']) == 0
    result = json.loads(out.read_text())
    check_contract(result)
    assert result['method'] == 'paper'
    assert 'method: paper' in capsys.readouterr().out


def test_several_files_are_identified_together(simulated_csv, tmp_path):
    second = str(tmp_path / 'prbs.csv')
    assert main(['simulate', '--motor', 'paper2', '--excitation', 'prbs', '--duration', '2',
                 '--sample-period', '1e-3', '--noise', '0.005', '--seed', '3',
                 '--out', second]) == 0
    out = tmp_path / 'both.json'
    assert main(['identify', simulated_csv, second, '--json', str(out)]) == 0
    result = json.loads(out.read_text())
    check_contract(result)
    assert len(result['records']) == 2
    assert len(result['initial_states']) == 2


def test_mechanical_only_mode(simulated_csv, tmp_path):
    record = read_csv(simulated_csv)
    path = tmp_path / 'shaft.csv'
    table = np.column_stack([record.time_s, record.current, record.speed])
    np.savetxt(path, table, delimiter=',', header='t,current,speed', comments='')
    out = tmp_path / 'shaft.json'
    assert main(['identify', str(path), '--json', str(out), '--torque-constant', '0.7',
                 '--no-discover']) == 0
    result = json.loads(out.read_text())
    check_contract(result, mechanical=True)
    truth = PAPER_MOTORS['paper2'].as_dict()
    for name in ('J', 'b', 'Mc'):
        assert result['parameters'][name] == pytest.approx(truth[name], rel=0.01)


def test_without_json_prints_the_table(simulated_csv, capsys):
    assert main(['identify', simulated_csv]) == 0
    out = capsys.readouterr().out
    assert 'method: refined' in out and 'CPhi' in out


def test_module_entry_point_and_usage_errors():
    completed = subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.main', 'identify', '--help'],
                               capture_output=True, text=True, timeout=60)
    assert completed.returncode == 0
    for option in ('--json', '--method', '--torque-constant', '--no-discover'):
        assert option in completed.stdout
    with pytest.raises(SystemExit) as exit_info:
        main(['identify', 'x.csv', '--method', 'magic'])
    assert exit_info.value.code == 2


def test_json_is_strict_and_has_no_nan(tmp_path):
    from dcmotor_id.cli.main import write_json
    out = tmp_path / 'sub' / 'r.json'
    write_json(str(out), {'stderr': {'Ra': float('nan'), 'La': 1.0}, 'x': [float('inf')]})
    text = out.read_text()
    assert 'NaN' not in text and 'Infinity' not in text
    assert json.loads(text) == {'stderr': {'Ra': None, 'La': 1.0}, 'x': [None]}
    assert not (tmp_path / 'sub' / 'r.json.partial').exists()
