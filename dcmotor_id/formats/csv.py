"""
CSV records: a header row naming the columns, then one sample a row.

The header names the columns ``t`` [s], ``voltage`` [V], ``current`` [A], ``speed`` [rad/s]
and optionally ``position`` [rad], in any order; other columns are ignored. Other names and
units are read through :class:`~dcmotor_id.formats.mapping.ReadOptions` (``--column``,
``--current-unit`` ...).

Large files are parsed in blocks by numpy's C reader, only the needed columns, each kept as
one array: a 10-million-row file needs little more memory than its numbers
(bench/csv_memory_results.md). A file that is not text (binary data, UTF-16 without a byte
order mark) is refused with a message instead of a decoding traceback; UTF-16 with a byte
order mark is read.  A JSON object (a file starting with ``{``) is read as a WPILib SysId data
file (:mod:`~dcmotor_id.formats.sysid_json`).
"""

from __future__ import annotations

import codecs
import csv
import io
from itertools import islice, repeat
import os
from typing import Callable, IO, Iterator, Sequence

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import COLUMNS, PathLike, Record
from dcmotor_id.formats.mapping import (build_record, column_option, DEFAULT_OPTIONS,
                                        looks_like, note, ReadOptions)
from dcmotor_id.formats.sysid_json import is_sysid_json, read_sysid_json

#: Rows parsed per block (the block's array is the only temporary copy).
BLOCK_ROWS = 1 << 18
#: Bytes looked at to tell text from binary data.
SNIFF_BYTES = 1 << 16


def _check_names(path: PathLike, header: list[str], index: dict[str, int]) -> None:
    """
    Refuse columns that are named like a known one but not exactly (e.g. ``Voltage``).

    A missing ``current``, or ``speed`` and ``position`` both missing, are refused here with the
    header's likely candidates named (every mode needs them); a missing ``voltage`` is left to
    the caller, since the mechanical-only mode does without it.  The message gives the
    ``--column`` options of every column the header names like a known one.
    """
    nearest = {name: [column for column in header
                      if looks_like(column, name)]
               for name in COLUMNS if name not in index}
    options = ' '.join(column_option(name, near[0]) for name, near in nearest.items() if near)
    for name, near in nearest.items():
        exact_case = [column for column in near if column.lower() == name]
        if exact_case:
            raise InputDataError(
                f'{path}: column {exact_case[0]!r} must be named {name!r} (column names are '
                f'lower case: {", ".join(COLUMNS)}); rename it or map it with {options}')
        position_given = 'position' in index or bool(nearest.get('position'))
        if near and (name == 'current' or (name == 'speed' and not position_given)):
            unit = ' (in rad/s)' if name == 'speed' else ' (in A)'
            raise InputDataError(
                f'{path}: no column named {name!r}; found {near[0]!r}: if that is the {name}, '
                f'rename it to {name}{unit} or map it with {options}. The '
                f'columns must be named {", ".join(COLUMNS)}')


def _encoding(path: PathLike) -> str:
    """
    Return the text encoding of the file, or refuse binary data with a message.

    UTF-8 (with or without a byte order mark) and UTF-16 with a byte order mark are read;
    NUL bytes or bytes that are not UTF-8 mean the file is not a CSV text file.
    """
    with open(path, 'rb') as stream:
        head = stream.read(SNIFF_BYTES)
    if head.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return 'utf-16'
    zero = head.find(b'\x00')
    if zero >= 0:
        even_zeros = head[1::2].count(0) > 0.4 * len(head[1::2])
        hint = (' It looks like UTF-16 without a byte order mark: save it as UTF-8.'
                if even_zeros else ' Give a comma-separated text file.')
        raise InputDataError(f'{path}: not a CSV text file (a NUL byte at byte {zero}).{hint}')
    try:
        # the sniffed block may end inside a multi-byte character: decode incrementally
        codecs.getincrementaldecoder('utf-8')().decode(head, final=False)
    except UnicodeDecodeError as error:
        raise InputDataError(
            f'{path}: not a CSV text file (byte {error.start} is not UTF-8 text). Give a '
            'comma-separated text file in UTF-8') from None
    return 'utf-8-sig'


def _refuse_nul(path: PathLike, block: int = 1 << 20) -> None:
    """
    Refuse a text file with a NUL byte anywhere (a NUL-padded or sparse file).

    A run of NUL bytes has no line end: the parser would take gigabytes of it as one line.
    Read in blocks of ``block`` bytes, so the scan needs no more memory than one block.
    """
    offset = 0
    with open(path, 'rb') as stream:
        while True:
            data = stream.read(block)
            if not data:
                return
            zero = data.find(b'\x00')
            if zero >= 0:
                raise InputDataError(
                    f'{path}: not a CSV text file: a NUL byte at byte {offset + zero} (a file '
                    'padded with zeros, or cut while written?); remove the padding (e.g. tr -d '
                    "'\\000') or re-export the CSV")
            offset += len(data)


def _open_text(path: PathLike, encoding: str) -> IO[str]:
    return open(path, newline='', encoding=encoding, errors='strict')


def read_csv(path: PathLike, options: ReadOptions = DEFAULT_OPTIONS) -> Record:
    """
    Read a record from a CSV file with a header row.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    options : ReadOptions
        Column mapping and units (default: the standard names in SI units).

    Raises
    ------
    InputDataError
        When the file is missing, empty, not text, lacks the ``t`` column, or has a cell that
        is not a number.

    """
    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file; give the path of a CSV file or a bag')
    if is_sysid_json(path):  # no format claims .json: result files are JSON too
        if options.time_unit != 's':
            raise InputDataError(f'{path}: --time-unit is for a time column; a SysId JSON '
                                 'log gives its sample period: drop --time-unit')
        return read_sysid_json(path, options)
    encoding = _encoding(path)
    if encoding != 'utf-16':
        _refuse_nul(path)
    try:
        with _open_text(path, encoding) as stream:
            header, header_line, delimiter = _header(path, stream)
            index = _column_index(path, header, options)
            columns = _parse(path, stream, (header_line, len(header)), index,
                             lambda: _open_text(path, encoding), delimiter)
    except UnicodeDecodeError as error:
        raise InputDataError(f'{path}: not a CSV text file (bytes that are not {encoding} '
                             f'text: {error.reason}); give a comma-separated UTF-8 file'
                             ) from None
    if delimiter != ',':
        note(f'{path}: read as {SEPARATORS[delimiter]}-separated (decimal commas accepted)')
    return build_record(columns, options, source=str(path))


#: Separators recognised besides the comma, by name (a decimal comma comes with them).
SEPARATORS = {';': 'semicolon', '\t': 'tab'}


def _header(path: PathLike, stream: IO[str]) -> tuple[list[str], int, str]:
    """
    Return the header's names, its line number (1-based) and the column separator.

    The separator is the comma, or a semicolon or tab when the header has no comma but one
    of those (the spreadsheet dialect of locales with a decimal comma); an empty file is
    refused.
    """
    for number, line in enumerate(stream, start=1):
        delimiter = ','
        if ',' not in line:
            delimiter = next((mark for mark in SEPARATORS if mark in line), ',')
        cells = next(_checked(path, csv.reader([line], delimiter=delimiter), number - 1), [])
        if cells and any(cell.strip() for cell in cells):
            header = [name.strip() for name in cells]
            if len(header) == 1 and ' ' in header[0].strip():
                raise InputDataError(
                    f'{path}: the header {header[0]!r} is one single column: the file must be '
                    'separated by commas, semicolons or tabs (t,voltage,current,speed)')
            return header, number, delimiter
    raise InputDataError(f'{path}: the file is empty; it needs a header row '
                         f'({", ".join(COLUMNS)}) and samples')


def _column_index(path: PathLike, header: list[str], options: ReadOptions) -> dict[str, int]:
    """Return channel -> column number of the header, refusing ambiguous or odd names."""
    index: dict[str, int] = {}
    for channel in options.wanted():
        name = options.column(channel)
        positions = [number for number, column in enumerate(header) if column == name]
        if len(positions) > 1:
            raise InputDataError(f'{path}: column {name!r} appears twice in the header')
        if positions:
            index[channel] = positions[0]
        elif channel in options.columns:
            raise InputDataError(f'{path}: {column_option(channel, name)}: no column {name!r} '
                                 f'in the header; it has {", ".join(header)}')
    standard = {channel: number for channel, number in index.items() if channel in COLUMNS}
    _check_names(path, header, standard)
    if 't' not in index and options.sample_period_s is None:
        near = [name for name in header if looks_like(name, 't')]
        hint = (f' (found {near[0]!r}: rename it to t or map it with '
                f'{column_option("t", near[0])})') if near else ''
        raise InputDataError(f'{path}: no time column t in the header {header}{hint}; the '
                             f'columns must be named {", ".join(COLUMNS)} (or mapped with '
                             '--column CHANNEL=NAME), or give the sample period with '
                             '--sample-period S')
    return index


def _parse(path: PathLike, stream: IO[str], header: tuple[int, int], index: dict[str, int],
           reopen: Callable[[], IO[str]], delimiter: str = ',') -> dict[str, np.ndarray]:
    """
    Parse the samples of the chosen columns in blocks; return channel -> values.

    numpy's C parser reads each block of lines into one small array; each column of it is
    kept as its own piece and the pieces are joined once per channel at the end, so the
    peak is about the numbers themselves plus one column and one block.  With a separator
    other than the comma, a comma is a decimal comma.  ``header``: the header's line number
    and its number of columns (a line with more fields is refused by the row-by-row parser,
    :func:`_parse_slowly`: the C parser reads only the chosen columns and would not see it).
    """
    channels = list(index)
    usecols = [index[channel] for channel in channels]
    pieces: dict[str, list[np.ndarray]] = {channel: [] for channel in channels}
    while True:
        lines = list(islice(stream, BLOCK_ROWS))
        if not lines:
            break
        if delimiter != ',':
            lines = [line.replace(',', '.') for line in lines]
        try:
            block = np.loadtxt(lines, delimiter=delimiter, usecols=usecols, ndmin=2, comments=None,
                               quotechar='"', dtype=float)
        except ValueError:
            block = None
        if block is None or block.shape[1] != len(channels) or \
                _overlong(lines, header[1], delimiter):
            del lines, pieces
            with reopen() as again:
                return _parse_slowly(path, again, header, index, delimiter)
        for column, channel in enumerate(channels):
            pieces[channel].append(np.ascontiguousarray(block[:, column]))
        del block, lines
    if not any(pieces[channel] for channel in channels):
        raise InputDataError(f'{path}: the file has a header but no samples; record or '
                             'export the data again')
    out = {}
    for channel in channels:
        out[channel] = np.concatenate(pieces.pop(channel))
    return out


def _overlong(lines: Sequence[str], width: int, delimiter: str) -> bool:
    """
    Whether a line may have more fields than the header (fields beyond it not all empty).

    A quick screen by counting separators (a quoted separator can make it say yes: the
    row-by-row parser then decides); separators at a line's end (``1,2,3,4,``) are no field.
    """
    if max(map(str.count, lines, repeat(delimiter)), default=0) < width:
        return False
    return any(line.rstrip().rstrip(delimiter).count(delimiter) >= width for line in lines)


def _parse_slowly(path: PathLike, stream: IO[str], header: tuple[int, int],
                  index: dict[str, int], delimiter: str = ',') -> dict[str, np.ndarray]:
    """
    Parse row by row with the csv module, to name the first bad cell or row (skip blank rows).

    Only reached when the fast parser refuses a block: its messages carry no line number of
    the file, and rows of empty cells (``,,,``) are skipped here as blank lines.  A row with
    more fields than the header (two lines run together, a stray separator) is refused: its
    cells cannot be matched to the columns.
    """
    values: dict[str, list[float]] = {channel: [] for channel in index}
    reader = csv.reader(stream, delimiter=delimiter)
    decimal_comma = delimiter != ','
    header_line, width = header
    for row_number, row in enumerate(_checked(path, reader), start=1):
        if row_number <= header_line or not row or not any(cell.strip() for cell in row):
            continue
        if any(cell.strip() for cell in row[width:]):
            raise InputDataError(
                f'{path}: line {row_number} has {len(row)} fields and the header {width}: two '
                'lines run together or a stray separator; fix or remove that line')
        for name, column in index.items():
            try:
                cell = row[column]
                values[name].append(float(cell.replace(',', '.') if decimal_comma else cell))
            except (IndexError, ValueError):
                if row_number == header_line + 1 and _units_row(row, index):
                    raise InputDataError(_units_row_text(path, row_number, row, index)) from None
                cell = row[column] if column < len(row) else '(missing)'
                what = ('the segment column (--segment-column: > 0 in a test, 0 between '
                        'tests)') if name == 'segment' else f'column {name!r}'
                raise InputDataError(
                    f'{path}: line {row_number}, {what}: {cell!r} is not a number; '
                    'fix or remove that line') from None
    if not any(values.values()):
        raise InputDataError(f'{path}: the file has a header but no samples; record or '
                             'export the data again')
    return {name: np.array(items, dtype=float) for name, items in values.items()}


def _units_row(row: Sequence[str], index: dict[str, int]) -> bool:
    """Whether a row under the header names units: none of its chosen cells is a number."""
    cells = [row[column].strip() for column in index.values() if column < len(row)]
    return bool(cells) and not any(_is_number(cell) for cell in cells)


def _is_number(cell: str) -> bool:
    """Whether a cell reads as a number (a decimal comma too)."""
    try:
        float(cell.replace(',', '.'))
    except ValueError:
        return False
    return True


def _units_row_text(path: PathLike, line: int, row: Sequence[str],
                    index: dict[str, int]) -> str:
    """Return the refusal of a row of units under the header, with the options that read them."""
    units = ', '.join(f'{channel} {row[column].strip()!r}' for channel, column in index.items()
                      if column < len(row) and row[column].strip())
    return (f'{path}: line {line} looks like a row of units under the header ({units}), not '
            'samples: delete that line and give the units that are not SI with the reading '
            'options (--time-unit ms|us|ns, --current-unit mA, --speed-unit rpm|rps|deg/s, '
            '--position-unit deg); the columns are read in s, V, A, rad/s and rad otherwise')


def _checked(path: PathLike, rows: Iterator[list[str]],
             before: int = 0) -> Iterator[list[str]]:
    """
    Yield the rows of a ``csv.reader``, its error an InputDataError naming the line.

    The csv module refuses a field beyond its limit of 131,072 characters (a 100 MB line, a
    2 MB column name) with a bare ``csv.Error``.
    """
    number = before
    while True:
        try:
            row = next(rows)
        except StopIteration:
            return
        except csv.Error as error:
            raise InputDataError(
                f'{path}: line {before + getattr(rows, "line_num", number - before + 1)}: '
                f'{error}; a CSV of samples has short cells: check that this is the right '
                'file') from None
        number += 1
        yield row


def write_csv(path: PathLike, record: Record) -> None:
    """Write a record as CSV with the standard header (``t`` first), atomically."""
    columns = record.columns()
    names = list(columns)
    table = np.column_stack([columns[name] for name in names])
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    temporary = f'{path}.{os.getpid()}.{id(table):x}.partial'
    try:
        np.savetxt(temporary, table, delimiter=',', header=','.join(names), comments='',
                   fmt='%.17g')
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def read_csv_text(text: str, options: ReadOptions = DEFAULT_OPTIONS,
                  source: str = '<text>') -> Record:
    """Read a record from CSV text (tests, small in-memory tables)."""
    stream = io.StringIO(text)
    header, header_line, delimiter = _header(source, stream)
    index = _column_index(source, header, options)
    columns = _parse(source, stream, (header_line, len(header)), index,
                     lambda: io.StringIO(text), delimiter)
    return build_record(columns, options, source=source)
