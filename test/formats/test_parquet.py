"""Parquet input: the same record as from CSV, mapped columns and units, clear refusals."""

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.formats import detect_format, read_record, ReadOptions


def write_table(path, columns):
    pq.write_table(pa.table({name: np.asarray(values) for name, values in columns.items()}),
                   path)


@pytest.fixture
def columns():
    t = np.arange(400) * 1e-3
    return {'t': t, 'voltage': 10 * np.sin(2 * np.pi * t), 'current': np.cos(3 * t),
            'speed': 5 * np.sin(2 * np.pi * t - 0.3)}


def test_parquet_reads_the_channels(tmp_path, columns):
    path = tmp_path / 'run.parquet'
    write_table(path, columns)
    assert detect_format(path) == 'parquet'
    record = read_record(path)
    for name in ('voltage', 'current', 'speed'):
        np.testing.assert_array_equal(getattr(record, name), columns[name])
    assert record.sample_period_s == pytest.approx(1e-3)


def test_parquet_maps_columns_and_units(tmp_path, columns):
    path = tmp_path / 'drive.parquet'
    write_table(path, {'time': columns['t'], 'u': columns['voltage'],
                       'i_mA': 1000 * columns['current'],
                       'rpm': columns['speed'] * 60 / (2 * np.pi)})
    options = ReadOptions(columns={'t': 'time', 'voltage': 'u', 'current': 'i_mA',
                                   'speed': 'rpm'}, current_unit='mA', speed_unit='rpm')
    record = read_record(path, options=options)
    np.testing.assert_allclose(record.current, columns['current'], rtol=1e-12)
    np.testing.assert_allclose(record.speed, columns['speed'], rtol=1e-12)


def test_parquet_missing_column_names_what_the_file_has(tmp_path, columns):
    path = tmp_path / 'bad.parquet'
    write_table(path, {'time': columns['t'], 'voltage': columns['voltage']})
    with pytest.raises(InputDataError, match='the file has time, voltage'):
        read_record(path)


def test_garbage_named_parquet_is_refused(tmp_path):
    path = tmp_path / 'garbage.parquet'
    path.write_bytes(b'\x00\x01 not parquet at all' * 10)
    with pytest.raises(InputDataError, match='not a readable Parquet file'):
        read_record(path)
