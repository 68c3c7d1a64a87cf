"""
The file formats of records behind one reader: :func:`read_record` picks the format of a path.

A directory, a ``.mcap`` or a ``.db3`` file is a rosbag2 bag (:mod:`.bag`); a ``.mat`` file
is MATLAB (:mod:`.mat`), a ``.parquet`` or ``.pq`` file a Parquet table (:mod:`.parquet`), a
``.wpilog`` file a WPILib DataLog (:mod:`.wpilog`); any other file is CSV (:mod:`.csv`).
Each format is registered below, one line each, in the registry of :mod:`.registry` (file
name ending -> reader of one protocol), which
:func:`detect_format`, :func:`read_record` and the fleet's file discovery all use: a new
format is one module plus one :func:`~dcmotor_id.formats.registry.register` line. Every reader
takes the :class:`~dcmotor_id.formats.mapping.ReadOptions` (column mapping, units, duty,
gear), and every record read passes :func:`~dcmotor_id.formats.quality.check_channels`
(channels that cannot identify the motor are refused, naming the channel).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import importlib
import os
from typing import Any, Optional

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike, Record
from dcmotor_id.formats.mapping import DEFAULT_OPTIONS, ReadOptions
from dcmotor_id.formats.quality import check_channels
from dcmotor_id.formats.registry import (file_suffixes, FileFormat, format_of, FORMATS, Reader,
                                         register, table_reader)


def _deferred(module: str, name: str, table: bool = False) -> Reader:
    """
    Return the reader ``name`` of the format module ``module``, imported when first called.

    A process reads one or two formats: the others' modules (rosbags' message types, the
    DataLog's stream alignment) are not imported by ``identify`` on a CSV file or in memory.
    ``table``: ``name`` is a table format's ``read(path, options)`` (:func:`table_reader`).
    """
    def reader(path: PathLike, **keywords: Any) -> Record:
        options = keywords.get('options', DEFAULT_OPTIONS)
        if not table and options.time_unit != 's':
            raise InputDataError(f'{path}: --time-unit {options.time_unit} is for a time '
                                 'column (CSV, MATLAB, Parquet files); this file carries its '
                                 'own time stamps: drop --time-unit')
        read = getattr(importlib.import_module(f'{__name__}.{module}'), name)
        return (table_reader(read) if table else read)(path, **keywords)
    return reader


register(FileFormat('bag', ('.mcap', '.db3'), _deferred('bag', 'read_bag'), directories=True))
register(FileFormat('mat', ('.mat',), _deferred('mat', 'read_mat', table=True)))
register(FileFormat('parquet', ('.parquet', '.pq'), _deferred('parquet', 'read_parquet',
                                                              table=True)))
register(FileFormat('wpilog', ('.wpilog',), _deferred('wpilog', 'read_wpilog')))
register(FileFormat('csv', ('.csv',), _deferred('csv', 'read_csv', table=True), fallback=True))

__all__ = ['detect_format', 'file_suffixes', 'FileFormat', 'FORMATS', 'read_record',
           'read_records', 'ReadOptions', 'register']


def detect_format(path: PathLike) -> str:
    """Return the format of ``path``: bag (directory, .mcap, .db3), mat, parquet, wpilog or csv."""
    return format_of(path).name


def read_record(path: PathLike, *, topics: Optional[Mapping[str, str]] = None,
                sample_period_s: Optional[float] = None,
                options: ReadOptions = DEFAULT_OPTIONS, mechanical_only: bool = False) -> Record:
    """
    Read one record from a CSV, MATLAB or rosbag2 file, choosing the reader by the path.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file, a ``.mat`` file, a rosbag2 directory, a ``.mcap`` or a ``.db3`` file.
    topics : dict, optional
        Channel -> topic name, for bags (see :func:`dcmotor_id.formats.bag.read_bag`).
    sample_period_s : float, optional
        Grid step of a bag's timestamps [s]; default ``options.sample_period_s``, else their
        median step.
    options : ReadOptions
        Column mapping, units, duty and gear (default: standard names in SI units).
    mechanical_only : bool
        The record is for the mechanical-only mode (``--torque-constant``): its voltage is not
        used, so it is not checked.

    Raises
    ------
    InputDataError
        When the file cannot be read or a channel cannot identify the motor, saying why and
        what to do.

    """
    # imported here, as in read_records: identify on records in memory needs no path checks
    # (their module imports tempfile, shutil and its compressors)
    from dcmotor_id.formats.paths import check_input_path

    check_input_path(path, directory=True)
    if os.path.isdir(path):
        for entry in sorted(os.listdir(path)):
            if not os.path.isdir(os.path.join(path, entry)):
                check_input_path(os.path.join(path, entry))
    if sample_period_s is None:
        sample_period_s = options.sample_period_s
    record = format_of(path).read(path, topics=topics, sample_period_s=sample_period_s,
                                  options=options)
    return check_channels(record, mechanical_only)


def read_records(paths: Iterable[PathLike], *,
                 topics: Optional[Mapping[str, str]] = None,
                 options: ReadOptions = DEFAULT_OPTIONS,
                 mechanical_only: bool = False) -> list[Record]:
    """
    Read every path with :func:`read_record`, in order.

    The same file given twice (by two names, or a link), or a byte-identical copy of one,
    is refused: it would count its samples twice and shrink the standard errors by the
    square root of two.
    """
    from dcmotor_id.formats.paths import same_content, same_file

    paths = list(paths)
    for index, path in enumerate(paths):
        twin = same_file(path, paths[:index])
        if twin is not None:
            raise InputDataError(f'{path}: the same file as {twin}, given twice; give each '
                                 'recording once')
    copies = same_content(paths)
    if copies is not None:
        raise InputDataError(f'{copies[1]}: byte for byte the same recording as {copies[0]} '
                             '(a copy under another name): fitted twice it would count its '
                             'samples twice and shrink the standard errors by the square root '
                             'of two; give each recording once')
    return [read_record(path, topics=topics, options=options, mechanical_only=mechanical_only)
            for path in paths]
