"""
The file formats of records: one reader protocol, one registry from file name ending to reader.

A format is a :class:`FileFormat`: its name, the file name endings it claims and its
:class:`Reader`. :func:`register` adds one; :func:`format_of` picks the format of a path (a
directory is a bag; a file by its ending, any case; any other file is the fallback format,
CSV) and :func:`file_suffixes` lists every ending, which is what the fleet looks for when it
walks a directory. So a new format is one module with its reader plus one :func:`register`
line in :mod:`dcmotor_id.formats`, and the command line, :func:`~dcmotor_id.formats.read_record`
and the fleet's file discovery all know it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import os
from typing import Callable, Optional, Protocol

from dcmotor_id.core.records import PathLike, Record
from dcmotor_id.formats.mapping import DEFAULT_OPTIONS, ReadOptions


class Reader(Protocol):
    """
    Read one record from a path (every reader of a format takes these keywords).

    ``options`` are the column mapping, units, duty and gear
    (:class:`~dcmotor_id.formats.mapping.ReadOptions`); ``topics`` (channel -> topic name) and
    ``sample_period_s`` (the grid step of time stamps [s]) concern formats with timed streams,
    bags; a table format ignores them (:func:`table_reader`).
    """

    def __call__(self, path: PathLike, *, topics: Optional[Mapping[str, str]],
                 sample_period_s: Optional[float], options: ReadOptions) -> Record:
        """Return the record of ``path``; raise ``InputDataError`` saying what is wrong."""


@dataclass(frozen=True)
class FileFormat:
    """
    One file format of records.

    Attributes
    ----------
    name : str
        Its name (``csv``, ``bag``, ...): what :func:`format_of` and ``detect_format`` return.
    suffixes : tuple of str
        The file name endings it claims, lower case with the dot (``('.mat',)``); a file
        ending so in any case is of this format.
    read : Reader
        Its reader.
    directories : bool
        A directory is a recording of this format (a rosbag2 bag).
    fallback : bool
        A file whose ending no format claims is of this format (CSV; one format at most).

    """

    name: str
    suffixes: tuple[str, ...]
    read: Reader
    directories: bool = False
    fallback: bool = False


#: Format name -> format, in the order they were registered.
FORMATS: dict[str, FileFormat] = {}


def register(file_format: FileFormat) -> FileFormat:
    """
    Add a file format (replacing one of the same name); return it.

    Two formats claiming one ending, or two fallbacks, are refused (the first would hide the
    second).
    """
    for other in FORMATS.values():
        if other.name == file_format.name:
            continue
        shared = set(other.suffixes) & set(file_format.suffixes)
        if shared:
            raise ValueError(f'file format {file_format.name!r}: {", ".join(sorted(shared))} '
                             f'already belong(s) to {other.name!r}')
        if other.fallback and file_format.fallback:
            raise ValueError(f'file format {file_format.name!r}: {other.name!r} is the '
                             'fallback already')
    if any(suffix != suffix.lower() or not suffix.startswith('.')
           for suffix in file_format.suffixes):
        raise ValueError(f'file format {file_format.name!r}: give its endings in lower case '
                         f'with the dot, not {file_format.suffixes}')
    FORMATS[file_format.name] = file_format
    return file_format


def format_of(path: PathLike) -> FileFormat:
    """Return the format of ``path``: a directory's, else its ending's, else the fallback."""
    text = os.fspath(path)
    if os.path.isdir(text):
        for file_format in FORMATS.values():
            if file_format.directories:
                return file_format
    ending = str(text).lower()
    for file_format in FORMATS.values():
        if ending.endswith(file_format.suffixes):
            return file_format
    return next(file_format for file_format in FORMATS.values() if file_format.fallback)


def file_suffixes() -> tuple[str, ...]:
    """Return every file name ending of the registered formats (lower case)."""
    return tuple(suffix for file_format in FORMATS.values() for suffix in file_format.suffixes)


def table_reader(read: Callable[[PathLike, ReadOptions], Record]) -> Reader:
    """Return the :class:`Reader` of a table format's ``read(path, options) -> Record``."""
    def reader(path: PathLike, *, topics: Optional[Mapping[str, str]] = None,
               sample_period_s: Optional[float] = None,
               options: ReadOptions = DEFAULT_OPTIONS) -> Record:
        return read(path, options)
    reader.__doc__ = read.__doc__
    return reader
