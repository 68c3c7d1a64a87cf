"""
WPILib SysId JSON data files (issue 29: a public SysId log given to ``identify`` as it comes).

Before the reader the file was taken for a CSV and refused ("no time column t in the header
['{']").  A simulated routine is written as SysId writes it (four tests, rows of time, voltage,
position, velocity; a drivetrain with two sides): read, each test is a record of its own and
kS, kV come out of the motor's combinations.
"""

import json
import math

import numpy as np
import pytest

from dcmotor_id.cli.main import main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.formats import read_record
from dcmotor_id.formats.mapping import ReadOptions
from dcmotor_id.formats.sysid_json import read_sysid_json, SYSID_TESTS
from dcmotor_id.simulation import lab_scenarios


def routine_tests(jitter_s=0.0, seed=1):
    """Return the simulated routine's four tests as SysId rows, and the truth."""
    scenario, segment = lab_scenarios.sysid_routine()
    record = scenario.records[0]
    rng = np.random.default_rng(seed)
    angle = np.cumsum(record.speed) * record.sample_period_s
    tests = {}
    # the routine's tests: ramp forward, ramp backward, step forward, step backward
    for name, number in zip(('slow-forward', 'slow-backward', 'fast-forward', 'fast-backward'),
                            (1, 2, 3, 4)):
        rows = np.flatnonzero(segment == number)
        t = 100.0 * number + record.time_s[rows] + rng.uniform(0, jitter_s, rows.size)
        tests[name] = np.column_stack([t, record.voltage[rows], angle[rows],
                                       record.speed[rows]])
    return tests, scenario.truth


def write_sysid(path, tests, test='Simple', units='Radians', per_rotation=2 * math.pi):
    """Write a SysId JSON data file of the tests."""
    data = {name: rows.tolist() for name, rows in tests.items()}
    data.update(sysid=True, test=test, units=units, unitsPerRotation=per_rotation)
    path.write_text(json.dumps(data))
    return str(path)


def test_a_sysid_file_is_identified_test_by_test(tmp_path):
    tests, truth = routine_tests(jitter_s=0.001)
    path = write_sysid(tmp_path / 'sysid_data.json', tests)
    out = tmp_path / 'result.json'
    assert main(['identify', path, '--json', str(out), '--quiet']) == 0
    result = json.loads(out.read_text())
    assert result['mode'] == 'voltage_speed' and len(result['records']) == 4
    kv = truth.CPhi + truth.Ra * truth.b / truth.CPhi
    ks = truth.Ra * truth.Mc / truth.CPhi
    assert result['parameters']['kV'] == pytest.approx(kv, rel=0.02)
    assert result['parameters']['kS'] == pytest.approx(ks, abs=0.05 * ks + 0.01)


def test_rotations_are_read_as_radians_and_each_test_is_marked(tmp_path):
    tests, _ = routine_tests()
    in_rotations = {name: rows * [1, 1, 1 / (2 * math.pi), 1 / (2 * math.pi)]
                    for name, rows in tests.items()}
    record = read_record(write_sysid(tmp_path / 'rot.json', in_rotations, units='Rotations',
                                     per_rotation=1.0))
    speed = np.concatenate([rows[:, 3] for rows in tests.values()])
    assert np.allclose(record.speed, speed)
    assert np.unique(record.segment).tolist() == [1.0, 2.0, 3.0, 4.0]
    assert np.allclose(np.diff(record.time_s), record.sample_period_s)


def test_a_drivetrain_side_is_chosen_with_joint(tmp_path):
    tests, _ = routine_tests()
    both = {name: np.column_stack([rows[:, 0], rows[:, 1], -rows[:, 1], rows[:, 2],
                                   -rows[:, 2], rows[:, 3], -rows[:, 3], 0 * rows[:, :2]])
            for name, rows in tests.items()}
    path = write_sysid(tmp_path / 'drive.json', both, test='Drivetrain')
    left = read_record(path)
    right = read_record(path, options=ReadOptions(joint='right'))
    assert np.allclose(left.voltage, -right.voltage) and np.allclose(left.speed, -right.speed)
    with pytest.raises(InputDataError, match='--joint left or --joint right'):
        read_sysid_json(path, ReadOptions(joint='front'))


def test_another_json_file_is_refused_saying_what_is_read(tmp_path, capsys):
    path = tmp_path / 'result.json'
    path.write_text(json.dumps({'parameters': {'Ra': 1.0}}))
    assert main(['identify', str(path), '--quiet']) == 2
    err = capsys.readouterr().err
    assert 'not a WPILib SysId data file' in err and SYSID_TESTS[0] in err
    assert 'Traceback' not in err
