"""
CSV records: a header row naming the columns, then one sample a row.

The header names the columns ``t`` [s], ``voltage`` [V], ``current`` [A], ``speed`` [rad/s]
and optionally ``position`` [rad], in any order; other columns are ignored.
"""

from __future__ import annotations

import csv
import os

import numpy as np

from dcmotor_id.errors import InputDataError
from dcmotor_id.records import COLUMNS, PathLike, Record

#: Other names seen for the columns, for the hint of a refusal (never accepted silently).
_ALIASES = {
    't': ('time', 'time_s', 'timestamp', 'stamp'),
    'voltage': ('u', 'v', 'ua', 'volt', 'volts', 'voltage_v', 'armature_voltage'),
    'current': ('i', 'ia', 'amps', 'current_a', 'armature_current'),
    'speed': ('w', 'omega', 'speed_rad_s', 'velocity', 'rpm', 'n'),
    'position': ('theta', 'pos', 'angle', 'position_rad'),
}


def _check_names(path: PathLike, header: list[str], index: dict[str, int]) -> None:
    """
    Refuse columns that are named like a known one but not exactly (e.g. ``Voltage``).

    A missing ``current``, or ``speed`` and ``position`` both missing, are refused here with the
    header's likely candidates named (every mode needs them); a missing ``voltage`` is left to
    the caller, since the mechanical-only mode does without it.
    """
    for name in COLUMNS:
        if name in index:
            continue
        near = [column for column in header
                if column.lower() == name or column.lower() in _ALIASES[name]]
        exact_case = [column for column in near if column.lower() == name]
        if exact_case:
            raise InputDataError(
                f'{path}: column {exact_case[0]!r} must be named {name!r} (column names are '
                f'lower case: {", ".join(COLUMNS)}); rename it')
        position_given = 'position' in index or any(
            column.lower() in _ALIASES['position'] for column in header)
        if near and (name == 'current' or (name == 'speed' and not position_given)):
            unit = ' (in rad/s)' if name == 'speed' else ' (in A)'
            raise InputDataError(
                f'{path}: no column named {name!r}; found {near[0]!r}: if that is the {name}, '
                f'rename it to {name}{unit}. The columns must be named {", ".join(COLUMNS)}')


def read_csv(path: PathLike) -> Record:
    """
    Read a record from a CSV file with a header row.

    Raises
    ------
    InputDataError
        When the file is missing, empty, lacks the ``t`` column, or has a cell that is not a
        number.

    """
    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file; give the path of a CSV file or a bag')
    with open(path, newline='', encoding='utf-8-sig') as stream:
        rows = [row for row in csv.reader(stream) if row and any(cell.strip() for cell in row)]
    if not rows:
        raise InputDataError(f'{path}: the file is empty; it needs a header row '
                             f'({", ".join(COLUMNS)}) and samples')
    header = [name.strip() for name in rows[0]]
    if len(header) == 1 and any(mark in header[0] for mark in (';', '\t', ' ')):
        raise InputDataError(f'{path}: the header {header[0]!r} is one single column: the file '
                             'must be comma-separated (t,voltage,current,speed)')
    index = {}
    for position, name in enumerate(header):
        if name in COLUMNS:
            if name in index:
                raise InputDataError(f'{path}: column {name!r} appears twice in the header')
            index[name] = position
    _check_names(path, header, index)
    if 't' not in index:
        near = [name for name in header if name.lower() in ('t', 'time', 'time_s', 'timestamp')]
        hint = f' (found {near[0]!r}: rename it to t)' if near else ''
        raise InputDataError(f'{path}: no time column t in the header {header}{hint}; the '
                             f'columns must be named {", ".join(COLUMNS)}')
    if len(rows) == 1:
        raise InputDataError(f'{path}: the file has a header but no samples; record or '
                             'export the data again')
    data = {name: np.empty(len(rows) - 1) for name in index}
    for row_number, row in enumerate(rows[1:], start=2):
        for name, column in index.items():
            try:
                data[name][row_number - 2] = float(row[column])
            except (IndexError, ValueError):
                cell = row[column] if column < len(row) else '(missing)'
                raise InputDataError(
                    f'{path}: line {row_number}, column {name!r}: {cell!r} is not a number; '
                    'fix or remove that line') from None
    return Record(time_s=data['t'], current=data.get('current'), voltage=data.get('voltage'),
                  speed=data.get('speed'), position=data.get('position'), source=str(path))


def write_csv(path: PathLike, record: Record) -> None:
    """Write a record as CSV with the standard header (``t`` first)."""
    columns = record.columns()
    names = list(columns)
    table = np.column_stack([columns[name] for name in names])
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    temporary = f'{path}.partial'
    np.savetxt(temporary, table, delimiter=',', header=','.join(names), comments='',
               fmt='%.17g')
    os.replace(temporary, path)
