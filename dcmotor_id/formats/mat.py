"""
MATLAB ``.mat`` records: variables (or columns of a matrix) mapped to the channels.

Version 5 files are read with :func:`scipy.io.loadmat`; version 7.3 files are HDF5 and need
the optional ``h5py`` (``pip install h5py``). By default the variables are named as the
channels (``t``, ``voltage``, ``current``, ``speed``, ``position``); ``--column current=data:7``
takes column 7 (1-based, as in MATLAB) of the matrix ``data`` (a matrix stored one channel a
row, e.g. 11 x N, is transposed and said so); ``--column t=output.time`` takes a field of a
struct (``data.signals.values:2`` a column of a field, ``ScopeData.signals(2).values`` a
field of an element of a struct array, 1-based, as Simulink logs them).  Without a time
variable, the time comes from ``--sample-period``.
"""

from __future__ import annotations

import os
import re
from typing import Any, Callable, Collection

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import COLUMNS, PathLike, Record
from dcmotor_id.formats.budget import check_budget
from dcmotor_id.formats.mapping import (build_record, column_option, DEFAULT_OPTIONS,
                                        likely_columns, note, ReadOptions)

#: The first bytes of an HDF5 file (MATLAB v7.3 puts them after a 512-byte header).
HDF5_MAGIC = b'\x89HDF\r\n\x1a\n'


def _is_hdf5(path: PathLike) -> bool:
    with open(path, 'rb') as stream:
        head = stream.read(520)
    return head[512:520] == HDF5_MAGIC or head[:8] == HDF5_MAGIC


#: Bound of a struct's size in memory against the file's size [bytes per byte]: compressed
#: MATLAB files hold numbers at about 1-10 times their stored size.
STRUCT_EXPANSION = 20.0


#: A struct array's element in a name, 1-based as in MATLAB: ``signals(2)``.
ELEMENT = re.compile(r'^(?P<field>[A-Za-z]\w*)\((?P<index>\d+)\)$')


def _elements(value: Any) -> list[Any] | None:
    """Return the elements of an array of structs (a list, or an object array), else None."""
    if isinstance(value, (list, tuple)):
        return list(value)
    if isinstance(value, np.ndarray) and value.dtype == object:
        return list(value.ravel(order='F'))
    return None


def _field_names(value: Any, prefix: str) -> list[str]:
    """
    Return ``prefix`` or, for a struct (a dict), the dotted names of its fields.

    An array of structs (Simulink's ``ScopeData.signals``) lists each element's fields
    as ``signals(K).values``, the way they are mapped.
    """
    if isinstance(value, dict):
        return [name for key in sorted(value) if not key.startswith('__')
                for name in _field_names(value[key], f'{prefix}.{key}')]
    elements = _elements(value)
    if elements and all(isinstance(element, dict) for element in elements):
        return [name for number, element in enumerate(elements, 1)
                for name in _field_names(element, f'{prefix}({number})')]
    return [prefix]


def _member(path: PathLike, name: str, value: Any, part: str) -> Any:
    """Return the field ``part`` (``field`` or ``field(K)``) of a struct ``value``, or None."""
    element = ELEMENT.match(part)
    field = element['field'] if element else part
    if _elements(value) is not None:
        raise InputDataError(
            f'{path}: {name!r}: the struct before {field!r} is an array of structs; pick '
            f'its element, 1-based as in MATLAB (e.g. ...(1).{field})')
    if not isinstance(value, dict) or field not in value:
        return None
    value = value[field]
    if element is None:
        return value
    elements = _elements(value)
    number = int(element['index'])
    if elements is None:
        elements = [value]  # a struct array of one element is loaded as the struct
    if not 1 <= number <= len(elements):
        raise InputDataError(f'{path}: {name!r}: {field!r} has {len(elements)} element(s) '
                             '(1-based)')
    return elements[number - 1]


def _load_v5(path: PathLike, needed: Collection[str]) -> Callable[[str], Any]:
    from scipy.io import loadmat, whosmat
    if os.path.getsize(path) == 0:
        raise InputDataError(f'{path}: the file is empty; give a MATLAB file with the record')
    try:
        listed = whosmat(path)
        declared = {name: shape for name, shape, _ in listed}
        # only the variables of the channels, each within the budget; structs too (their
        # fields name the channels), whose size whosmat does not give: bounded by the file's
        wanted = {item.split('.')[0] for item in needed}
        structs = [name for name, _, kind in listed if kind == 'struct']
        names = [name for name in declared if name in wanted or name in structs]
        for name in names:
            if name not in structs:
                check_budget(8.0 * float(np.prod(declared[name], dtype=float)), path,
                             f'variable {name!r} of shape {declared[name]}')
        if structs:
            check_budget(STRUCT_EXPANSION * float(os.path.getsize(path)), path,
                         f'the structs {", ".join(structs)}')
        data = loadmat(path, variable_names=names, simplify_cells=True)
        data.update({name: None for name in declared if name not in data})
    except (MemoryError, InputDataError):
        raise
    except Exception as error:  # noqa: BLE001  (MatReadError, ValueError, zlib, struct ...)
        raise InputDataError(f'{path}: not a readable MATLAB file ({error}); it is damaged or '
                             'truncated: save it again in MATLAB') from None
    variables = {key: value for key, value in data.items() if not key.startswith('__')}
    if not variables and not declared:
        raise InputDataError(f'{path}: a MATLAB file without variables; give the file with '
                             'the record')

    def get(name: str) -> Any:
        # ``output.time``, ``ScopeData.signals(2).values``: fields of MATLAB structs
        value: Any = variables
        for part in name.split('.'):
            value = _member(path, name, value, part)
            if value is None:
                return None
        return value
    get.names = [name for key in sorted(variables)  # type: ignore[attr-defined]
                 for name in _field_names(variables[key], key)]
    return get


def _load_v73(path: PathLike) -> tuple[Callable[[str], Any], Any]:
    try:
        import h5py
    except ImportError:
        raise InputDataError(
            f'{path}: a MATLAB v7.3 (HDF5) file; reading it needs h5py: pip install h5py, or '
            "save the file as version 5 in MATLAB (save(..., '-v7'))") from None
    try:
        handle = h5py.File(path, 'r')
    except Exception as error:  # noqa: BLE001  (OSError, ValueError of a damaged HDF5 file)
        raise InputDataError(f'{path}: not a readable MATLAB v7.3 (HDF5) file ({error}); it is '
                             'damaged or truncated: save it again in MATLAB') from None

    def get(name: str) -> Any:
        key = name.replace('.', '/')  # a struct's fields are an HDF5 group's members
        if key not in handle:
            return None
        item = handle[key]
        if not isinstance(item, h5py.Dataset):
            raise InputDataError(f'{path}: {name!r} is a group (a struct), not a numeric '
                                 'variable; map one of its fields with --column CHANNEL='
                                 f'{name}.FIELD')
        check_budget(8.0 * float(np.prod(item.shape, dtype=float)), path,
                     f'variable {name!r} of shape {tuple(reversed(item.shape))}')
        # HDF5 stores MATLAB arrays transposed (column-major): transpose back
        return np.asarray(item).T
    names: list[str] = []
    handle.visititems(lambda key, item: names.append(key.replace('/', '.'))
                      if isinstance(item, h5py.Dataset) and not key.startswith('#') else None)
    get.names = sorted(names)  # type: ignore[attr-defined]
    return get, handle


def _column(path: PathLike, get: Callable[[str], Any], spec: str,
            channel: str) -> np.ndarray | None:
    """Return the values named by ``spec`` (``name`` or ``name:column``), or None if absent."""
    name, _, column = spec.partition(':')
    value = get(name)
    if value is None:
        return None
    if np.iscomplexobj(value):
        imaginary = float(np.max(np.abs(np.imag(value)), initial=0.0))
        if imaginary > 0:
            raise InputDataError(f'{path}: variable {name!r} ({channel}) holds complex values '
                                 f'(imaginary parts up to {imaginary:.3g}); a measured signal '
                                 'is real: export its real values (real() in MATLAB)')
        value = np.real(value)
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputDataError(f'{path}: variable {name!r} ({channel}) is not numeric') from None
    if column:
        try:
            number = int(column)
        except ValueError:
            raise InputDataError(f'{path}: --column {channel}={spec}: the column after ":" '
                                 'must be a number (1-based, as in MATLAB)') from None
        matrix = _samples_as_rows(path, name, np.atleast_2d(array))
        if not 1 <= number <= matrix.shape[1]:
            raise InputDataError(f'{path}: --column {channel}={spec}: {name!r} has '
                                 f'{matrix.shape[1]} column(s) (1-based)')
        return np.array(matrix[:, number - 1], dtype=float)
    if array.ndim > 1 and sorted(array.shape)[-2] > 1:
        raise InputDataError(f'{path}: variable {name!r} ({channel}) is a {array.shape} matrix; '
                             f'pick a column with --column {channel}={name}:N (1-based)')
    return np.array(np.ravel(array), dtype=float)


#: Most channels a matrix stored channels-as-rows is taken to have.
MAX_CHANNELS = 64


def _samples_as_rows(path: PathLike, name: str, matrix: np.ndarray) -> np.ndarray:
    """
    Return a matrix with one sample a row, transposing one stored channels-as-rows.

    A matrix with few rows (at most :data:`MAX_CHANNELS`) and many more columns holds one
    channel a row (e.g. 11 x 20000): it is transposed, said in a note.  A row vector is a
    single channel.
    """
    rows, columns = matrix.shape[:2]
    if rows == 1 and columns > 1:
        return matrix.T
    if 1 < rows <= MAX_CHANNELS and columns > 4 * rows:
        note(f'{path}: {name!r} is a {rows} x {columns} matrix: read as {rows} channels '
             f'stored as rows of {columns} samples (column N of --column is its row N)')
        return matrix.T
    return matrix


def _suggestion(names: list[str], options: ReadOptions) -> str:
    """Return the ``--column`` options of the variables named like a channel (or nothing)."""
    unmapped = tuple(channel for channel in COLUMNS if channel not in options.columns)
    likely = likely_columns(names, unmapped)
    if not likely:
        return ''
    return ('; the names suggest ' + ' '.join(column_option(channel, name)
                                              for channel, name in likely.items()))


def read_mat(path: PathLike, options: ReadOptions = DEFAULT_OPTIONS) -> Record:
    """
    Read a record from a MATLAB ``.mat`` file (v5 via scipy, v7.3 via h5py).

    Raises
    ------
    InputDataError
        A missing file or variable (naming the variables the file has), a matrix without a
        column given, a v7.3 file without h5py installed.

    """
    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file')
    handle = None
    if _is_hdf5(path):
        get, handle = _load_v73(path)
    else:
        get = _load_v5(path, {options.column(channel).partition(':')[0]
                              for channel in options.wanted()})
    try:
        columns = {}
        for channel in options.wanted():
            values = _column(path, get, options.column(channel), channel)
            if values is None:
                timed = channel == 't' and options.sample_period_s is None
                if channel in options.columns or timed:
                    raise InputDataError(
                        f'{path}: no variable {options.column(channel).partition(":")[0]!r} for '
                        f'{channel}; the file has {", ".join(get.names)}'  # type: ignore
                        f'. Map it with {column_option(channel, "NAME")} (or NAME:COLUMN, or '
                        'STRUCT.FIELD)' + (', or give the sample period with --sample-period '
                                           'S' if channel == 't' else '')
                        + _suggestion(get.names, options))  # type: ignore[attr-defined]
                continue
            columns[channel] = values
    finally:
        if handle is not None:
            handle.close()
    lengths = {channel: values.shape[0] for channel, values in columns.items()}
    if len(set(lengths.values())) > 1:
        raise InputDataError(f'{path}: the channels have different lengths {lengths}')
    return build_record(columns, options, source=str(path))
