"""One registry of file formats: detect_format, read_record and the fleet's discovery use it."""

import json

import numpy as np
import pytest

from dcmotor_id.fleet import find_sources, FleetOptions
from dcmotor_id.fleet.tasks import read_windows
from dcmotor_id.formats import (detect_format, file_suffixes, FileFormat, FORMATS, read_record,
                                register)
from dcmotor_id.formats.mapping import build_record, DEFAULT_OPTIONS
from dcmotor_id.formats.registry import format_of, table_reader


def _read_toy(path, options=DEFAULT_OPTIONS):
    """Read a toy format: one JSON object of columns."""
    with open(path, encoding='utf-8') as stream:
        columns = {name: np.asarray(values, dtype=float)
                   for name, values in json.load(stream).items()}
    return build_record(columns, options, source=str(path))


@pytest.fixture
def toy_format():
    """Register the toy format ``.toyjson`` for one test, and remove it afterwards."""
    before = dict(FORMATS)
    yield register(FileFormat('toy', ('.toyjson',), table_reader(_read_toy)))
    FORMATS.clear()
    FORMATS.update(before)


def _toy_file(path, seconds=2.0, dt=1e-3):
    t = np.arange(0.0, seconds, dt)
    voltage = 10.0 * np.sign(np.sin(2 * np.pi * 3 * t)) + 1.0
    current = np.sin(2 * np.pi * 5 * t) + 0.1 * voltage
    speed = np.cos(2 * np.pi * 2 * t) + 0.2 * voltage
    path.write_text(json.dumps({'t': t.tolist(), 'voltage': voltage.tolist(),
                                'current': current.tolist(), 'speed': speed.tolist()}))
    return path


def test_the_built_in_formats_are_registered():
    assert list(FORMATS) == ['bag', 'mat', 'parquet', 'wpilog', 'csv']
    assert [detect_format(name) for name in ('x.mcap', 'x.db3', 'x.mat', 'x.parquet', 'x.pq',
                                             'x.wpilog', 'x.csv', 'x.txt', 'x')] \
        == ['bag', 'bag', 'mat', 'parquet', 'parquet', 'wpilog', 'csv', 'csv', 'csv']
    # an ending in capitals is the same format (a bare bag was read as CSV before)
    assert [detect_format(name) for name in ('X.MCAP', 'X.DB3', 'X.MAT', 'X.PARQUET')] \
        == ['bag', 'bag', 'mat', 'parquet']
    assert set(file_suffixes()) == {'.mcap', '.db3', '.mat', '.parquet', '.pq', '.wpilog',
                                    '.csv'}


def test_a_directory_is_a_bag(tmp_path):
    assert detect_format(tmp_path) == 'bag'
    assert format_of(str(tmp_path)).directories


def test_a_registered_format_is_read_and_found_by_the_fleet(tmp_path, toy_format):
    (tmp_path / 'fleet' / 'm7').mkdir(parents=True)
    path = _toy_file(tmp_path / 'fleet' / 'm7' / 'run.toyjson')
    (tmp_path / 'fleet' / 'm7' / 'notes.txt').write_text('not a recording')
    assert detect_format(path) == 'toy' and '.toyjson' in file_suffixes()
    record = read_record(path)
    assert len(record) == 2000 and record.source == str(path)
    found = find_sources([str(tmp_path / 'fleet')])
    assert [(source.path, source.kind) for source in found] == [(str(path), 'toy')]
    read = read_windows(found[0], FleetOptions(discover=False, window_s=1.0, min_window_s=0.5,
                                               motor_from='path'))
    assert not read.errors
    assert [(window.motor_id, len(window.record)) for window in read.windows] \
        == [('m7', 1000), ('m7', 1000)]


def test_the_registry_refuses_an_ending_twice_and_two_fallbacks(toy_format):
    with pytest.raises(ValueError, match=r"\.toyjson already belong\(s\) to 'toy'"):
        register(FileFormat('other', ('.toyjson',), toy_format.read))
    with pytest.raises(ValueError, match="'csv' is the fallback already"):
        register(FileFormat('other', ('.other',), toy_format.read, fallback=True))
    with pytest.raises(ValueError, match='lower case with the dot'):
        register(FileFormat('other', ('.OTHER',), toy_format.read))
    assert 'other' not in FORMATS


def test_each_format_module_is_imported_when_its_reader_is_first_called():
    # The registry names the suffixes the format modules define; the modules themselves are
    # imported by their first read (identify on a CSV file or in memory loads no rosbags).
    from dcmotor_id.formats import parquet, wpilog
    assert FORMATS['parquet'].suffixes == parquet.PARQUET_SUFFIXES
    assert FORMATS['wpilog'].suffixes == wpilog.WPILOG_SUFFIXES
    code = ('import sys\n'
            'from dcmotor_id.formats import FORMATS\n'
            'late = ["bag", "mat", "parquet", "wpilog", "csv"]\n'
            'print(all("dcmotor_id.formats." + name not in sys.modules for name in late))\n')
    assert _run_python(code) == 'True'


def _run_python(code):
    """Run ``code`` in a fresh interpreter with this checkout on the path; return its output."""
    import os
    import subprocess
    import sys
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = {**os.environ, 'PYTHONPATH': root}
    return subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, check=True, timeout=120).stdout.strip()
