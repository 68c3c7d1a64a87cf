"""
``identify --current-sign-from voltage|speed``: a current logged as a magnitude (issue 29).

A motor controller's output current (a Spark MAX's ``OutputCurrent``, a servo amplifier's
current monitor) is often a magnitude.  On a record that runs both ways the regression then
sees a reversed current; the refusal names the option that mends it (negating does not), and
with the option the record is identified.
"""

import json

import numpy as np
import pytest
from schema_check import validate

from dcmotor_id.cli.main import main
from dcmotor_id.simulation import lab_scenarios


@pytest.fixture(scope='module')
def magnitude_csv(tmp_path_factory):
    """Write a geared servo's voltage steps both ways, the current as its magnitude."""
    truth = lab_scenarios.HOBBY_SERVO
    dt = 2e-3
    command = lab_scenarios.step_levels([2.2, -3.7, 6.7, -1.5, 7.4, -7.4, 4.4, -5.2, 5.9, -3.0],
                                        0.5, dt)
    out = lab_scenarios.simulate_drive(truth, command, dt)
    rng = np.random.default_rng(4)
    current = np.abs(out['current'] + rng.normal(0.0, 0.01, command.shape))
    speed = out['speed'] + rng.normal(0.0, 0.2, command.shape)
    path = tmp_path_factory.mktemp('magnitude') / 'servo.csv'
    np.savetxt(path, np.column_stack([np.arange(command.shape[0]) * dt, command, current,
                                      speed]),
               delimiter=',', header='t,voltage,current,speed', comments='')
    return str(path), truth


def test_a_magnitude_current_is_refused_naming_the_option_that_mends_it(magnitude_csv, tmp_path,
                                                                        capsys):
    path, _ = magnitude_csv
    assert main(['identify', path, '--json', str(tmp_path / 'r.json')]) == 2
    err = capsys.readouterr().err
    assert '--current-sign-from voltage' in err and 'magnitude' in err
    assert 'flip its sign with --negate current' not in err


def test_the_sign_of_the_voltage_restores_the_current(magnitude_csv, tmp_path):
    path, truth = magnitude_csv
    out = tmp_path / 'r.json'
    assert main(['identify', path, '--current-sign-from', 'voltage', '--json', str(out)]) == 0
    result = json.loads(out.read_text())
    for name in ('Ra', 'CPhi', 'J', 'Mc'):
        assert result['parameters'][name] == pytest.approx(getattr(truth, name), rel=0.1)
    assert result['input_units']['current']['sign_from'] == 'voltage'
    validate(result, 'result')


def test_a_sign_from_a_channel_the_record_lacks_is_exit_2(magnitude_csv, tmp_path, capsys):
    path, _ = magnitude_csv
    data = np.loadtxt(path, delimiter=',', skiprows=1)
    angle = np.cumsum(data[:, 3]) * 2e-3
    no_speed = tmp_path / 'angle.csv'
    np.savetxt(no_speed, np.column_stack([data[:, :3], angle]), delimiter=',',
               header='t,voltage,current,position', comments='')
    code = main(['identify', str(no_speed), '--current-sign-from', 'speed', '--json',
                 str(tmp_path / 'r.json')])
    assert code == 2
    assert '--current-sign-from speed: the record has no speed column' in \
        capsys.readouterr().err
