"""
The file formats of records behind one reader: :func:`read_record` picks the format of a path.

A directory, a ``.mcap`` or a ``.db3`` file is a rosbag2 bag (:mod:`.bag`); any other file is
CSV (:mod:`.csv`). :data:`READERS` maps each format to its reader, so a new format is one
module plus one entry.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import os
from typing import Callable, Optional

from dcmotor_id.formats import bag, csv
from dcmotor_id.records import PathLike, Record

#: Format name -> reader ``(path, topics=..., sample_period_s=...) -> Record``.
READERS: dict[str, Callable[..., Record]] = {
    'bag': bag.read_bag,
    'csv': lambda path, **_: csv.read_csv(path),
}
#: File name endings of the single-file bag formats (a directory is always a bag).
BAG_SUFFIXES = ('.mcap', '.db3')


def detect_format(path: PathLike) -> str:
    """Return the format of ``path``: ``bag`` (a directory, ``.mcap``, ``.db3``) or ``csv``."""
    text = str(path)
    return 'bag' if os.path.isdir(text) or text.endswith(BAG_SUFFIXES) else 'csv'


def read_record(path: PathLike, *, topics: Optional[Mapping[str, str]] = None,
                sample_period_s: Optional[float] = None) -> Record:
    """
    Read one record from a CSV file or a rosbag2 bag, choosing the reader by the path.

    Parameters
    ----------
    path : str or os.PathLike
        A CSV file, a rosbag2 directory, a ``.mcap`` or a ``.db3`` file.
    topics : dict, optional
        Channel -> topic name, for bags (see :func:`dcmotor_id.formats.bag.read_bag`).
    sample_period_s : float, optional
        Grid step of a bag's timestamps [s]; default their median step.

    Raises
    ------
    InputDataError
        When the file cannot be read, saying why and what to do.

    """
    return READERS[detect_format(path)](path, topics=topics, sample_period_s=sample_period_s)


def read_records(paths: Iterable[PathLike], *,
                 topics: Optional[Mapping[str, str]] = None) -> list[Record]:
    """Read every path with :func:`read_record`, in order."""
    return [read_record(path, topics=topics) for path in paths]
