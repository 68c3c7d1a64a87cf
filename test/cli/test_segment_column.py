"""
``identify --segment-column NAME``: the tests of a record as logged (issue 29, test segments).

A simulated SysId routine (quasistatic ramps and steps, braked between them with the logged
voltage and current at 0) is written to a CSV with two candidate columns: ``test`` numbers the
four tests, ``half`` keeps only the first and third.  The column given decides the tests
(detection alone would find all four), each test is fitted as a record of its own and named in
the JSON's ``records``; a missing or non-numeric column is exit 2 with a message naming it.
"""

import json

import numpy as np
import pytest
from support import motor_samples

from dcmotor_id.cli.main import main
from dcmotor_id.core.records import Record, resample_uniform
from dcmotor_id.formats import read_record, ReadOptions
from dcmotor_id.formats.bag import write_bag
from dcmotor_id.identification.pipeline.segments import marked_tests, split_tests
from dcmotor_id.simulation import lab_scenarios


@pytest.fixture(scope='module')
def routine_csv(tmp_path_factory):
    """Write the routine with its segment columns; return the path and the truth."""
    scenario, segment = lab_scenarios.sysid_routine()
    record = scenario.records[0]
    half = np.where(np.isin(segment, (2, 4)), 0, segment)
    path = tmp_path_factory.mktemp('routine') / 'routine.csv'
    np.savetxt(path, np.column_stack([record.time_s, record.voltage, record.current,
                                      record.speed, segment, half]),
               delimiter=',', header='t,voltage,current,speed,test,half', comments='')
    return str(path), scenario.truth


def identify_json(path, tmp_path, *options):
    """Run ``identify`` with options; return the exit code and the JSON (None on failure)."""
    out = tmp_path / 'result.json'
    code = main(['identify', path, '--json', str(out), '--quiet', *options])
    return code, (json.loads(out.read_text()) if code == 0 else None)


def test_the_column_decides_the_tests_and_names_them(routine_csv, tmp_path):
    path, truth = routine_csv
    code, result = identify_json(path, tmp_path, '--segment-column', 'half')
    assert code == 0
    # Detection would have cut four tests; the column keeps two.
    assert result['records'] == [f'{path} [test 1: 0-6.98 s]', f'{path} [test 2: 16-18.98 s]']
    assert any('the segment column marks the tests: fitted as 2 separate records' in text
               for text in result['warnings'])
    for name in ('Ra', 'CPhi', 'J'):
        assert result['parameters'][name] == pytest.approx(getattr(truth, name), rel=0.05), name


def test_every_test_of_the_column_is_fitted(routine_csv, tmp_path):
    path, truth = routine_csv
    code, result = identify_json(path, tmp_path, '--segment-column', 'test')
    assert code == 0
    assert len(result['records']) == 4
    assert result['parameters']['CPhi'] == pytest.approx(truth.CPhi, rel=0.05)


def test_without_the_option_the_column_is_not_read(routine_csv):
    path, _ = routine_csv
    assert read_record(path).segment is None
    marked = read_record(path, options=ReadOptions(columns={'segment': 'half'}))
    assert np.array_equal(np.unique(marked.segment), [0.0, 1.0, 3.0])


def test_a_change_of_value_starts_the_next_test():
    segment = np.array([0, 1, 1, 2, 2, 2, 0, 0, 3, 3, -1])
    assert marked_tests(segment) == [(1, 3), (3, 6), (8, 10)]


def test_a_column_marking_one_test_over_the_whole_record_leaves_it_whole(routine_csv):
    path, _ = routine_csv
    record = read_record(path, options=ReadOptions(columns={'segment': 'half'}))
    whole = record.replace(segment=np.ones(len(record)))
    tests = split_tests([whole])
    assert tests.records == (whole,) and tests.note == ''


def test_a_missing_column_is_refused_naming_the_option(routine_csv, capsys):
    path, _ = routine_csv
    assert main(['identify', path, '--segment-column', 'phase', '--quiet']) == 2
    err = capsys.readouterr().err
    assert '--segment-column phase' in err and "no column 'phase'" in err
    assert 'Traceback' not in err


def test_a_column_that_is_not_numeric_is_refused(tmp_path, capsys):
    path = tmp_path / 'words.csv'
    path.write_text('t,voltage,current,speed,phase\n0,1,0.1,0,1\n0.001,1,0.1,0.2,ramp\n')
    assert main(['identify', str(path), '--segment-column', 'phase', '--quiet']) == 2
    err = capsys.readouterr().err
    assert 'the segment column (--segment-column' in err and "'ramp' is not a number" in err
    assert 'Traceback' not in err


def test_a_column_with_no_test_long_enough_is_refused(tmp_path, capsys):
    scenario, segment = lab_scenarios.sysid_routine()
    record = scenario.records[0]
    path = tmp_path / 'short.csv'
    marks = np.zeros(len(record))
    marks[5:20] = 1.0  # one test of 15 samples
    np.savetxt(path, np.column_stack([record.time_s, record.voltage, record.current,
                                      record.speed, marks]),
               delimiter=',', header='t,voltage,current,speed,test', comments='')
    assert main(['identify', str(path), '--segment-column', 'test', '--quiet']) == 2
    err = capsys.readouterr().err
    assert 'the segment column marks no test of 100 samples or more' in err


def test_without_a_current_the_column_splits_the_voltage_speed_fit(tmp_path):
    scenario, segment = lab_scenarios.sysid_routine()
    record = scenario.records[0]
    path = tmp_path / 'no_current.csv'
    np.savetxt(path, np.column_stack([record.time_s, record.voltage, record.speed, segment]),
               delimiter=',', header='t,voltage,speed,test', comments='')
    code, result = identify_json(str(path), tmp_path, '--segment-column', 'test')
    assert code == 0 and result['mode'] == 'voltage_speed'
    assert len(result['records']) == 4
    assert any('fitted as 4 separate records' in text for text in result['warnings'])


def test_resampling_keeps_each_sample_s_mark():
    record = Record(np.array([0.0, 0.01, 0.03, 0.04]), voltage=np.ones(4), speed=np.ones(4),
                    segment=np.array([0.0, 1.0, 1.0, 2.0]))
    assert resample_uniform(record, 0.01).segment.tolist() == [0.0, 1.0, 1.0, 1.0, 2.0]


def test_a_bag_carries_no_segment_column_and_the_option_is_refused(tmp_path, capsys):
    stamps, channels = motor_samples(2.0)
    write_bag(tmp_path / 'bag', stamps, channels)
    assert main(['identify', str(tmp_path / 'bag'), '--segment-column', 'test', '--quiet']) == 2
    err = capsys.readouterr().err
    assert "--segment-column test: this file's format carries no such column" in err
    assert 'Traceback' not in err
