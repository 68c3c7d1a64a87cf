"""
Parquet tables as records: the columns read by pyarrow, mapped as for CSV and MATLAB files.

pyarrow is already a dependency of the fleet history, so this format costs nothing more.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike, Record
from dcmotor_id.formats.budget import check_budget
from dcmotor_id.formats.mapping import build_record, column_option, DEFAULT_OPTIONS, ReadOptions

#: File name endings of Parquet files.
PARQUET_SUFFIXES = ('.parquet', '.pq')


def _seconds(column: Any) -> np.ndarray:
    """Return a timestamp, duration or date column in seconds from its first value."""
    import pyarrow
    import pyarrow.compute as pc
    nanoseconds = pc.cast(column, pyarrow.timestamp('ns') if not pyarrow.types.is_duration(
        column.type) else pyarrow.duration('ns')).cast(pyarrow.int64()).to_numpy(
            zero_copy_only=False)
    values = np.asarray(nanoseconds, dtype=np.int64)
    return (values - values[0]).astype(float) * 1e-9 if values.size else values.astype(float)


def read_parquet(path: PathLike, options: ReadOptions = DEFAULT_OPTIONS) -> Record:
    """
    Read a record from a Parquet file: one column per channel, named as in a CSV file.

    Raises
    ------
    InputDataError
        A missing or unreadable file, or a channel column that is absent (naming the columns
        the file has) or not numeric.

    """
    import pyarrow
    import pyarrow.parquet as pq

    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file')
    try:
        schema = pq.read_schema(path)
    except (pyarrow.ArrowException, OSError) as error:
        raise InputDataError(f'{path}: not a readable Parquet file ({error})') from None
    names = list(schema.names)
    wanted = {channel: options.column(channel) for channel in options.wanted()}
    present = {channel: name for channel, name in wanted.items() if name in names}
    for channel in ('t',) + tuple(options.columns):
        if channel in wanted and channel not in present:
            raise InputDataError(
                f'{path}: no column {wanted[channel]!r} for {channel}; the file has '
                f'{", ".join(names)}. Map it with {column_option(channel, "NAME")}')
    try:
        rows = pq.ParquetFile(path).metadata.num_rows
    except (pyarrow.ArrowException, OSError) as error:
        raise InputDataError(f'{path}: not a readable Parquet file ({error})') from None
    check_budget(20.0 * rows * len(set(present.values())), path,
                 f'{rows} rows of {len(set(present.values()))} columns')
    columns = {}
    for channel, name in present.items():
        try:
            # one column at a time, released before the next: the peak is the record plus
            # one column, not the whole table beside its copy
            column = pq.read_table(path, columns=[name], use_threads=False).column(name)
            if pyarrow.types.is_timestamp(column.type) or pyarrow.types.is_duration(
                    column.type) or pyarrow.types.is_date(column.type):
                columns[channel] = _seconds(column)
                continue
            columns[channel] = np.asarray(column.to_numpy(), dtype=float)
        except (TypeError, ValueError, pyarrow.ArrowException):
            raise InputDataError(f'{path}: column {name!r} ({channel}) is not numeric; give '
                                 'numbers in SI units or map another column') from None
    return build_record(columns, options, source=str(path))
