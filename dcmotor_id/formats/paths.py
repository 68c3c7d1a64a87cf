"""
Input and output paths checked before any byte is read or written (issue 21).

An input must be a regular file (or, for a bag, a directory): a FIFO blocks a reader forever,
``/dev/zero`` never ends, a symlink loop cannot be opened, and each used to end as a hang or
as "no such file".  An output may only replace a regular file that is not one of the inputs:
a symlink or a device node is never replaced, and a recording is never overwritten by a
result.  Every refusal names the option or file, what it is, and what to do.
"""

from __future__ import annotations

import errno
import os
import stat
from typing import Iterable, Optional

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike

__all__ = ['check_input_path', 'kind_of', 'same_file']


def kind_of(mode: int) -> str:
    """Return a name for the kind of file of a ``st_mode`` (for the messages)."""
    for test, name in ((stat.S_ISFIFO, 'a FIFO (named pipe)'),
                       (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device'), (stat.S_ISSOCK, 'a socket'),
                       (stat.S_ISDIR, 'a directory'), (stat.S_ISLNK, 'a symbolic link'),
                       (stat.S_ISREG, 'a regular file')):
        if test(mode):
            return name
    return 'a special file'


def _stat(path: PathLike, what: str) -> os.stat_result:
    """``os.stat`` of an input, with every failure turned into a message naming the path."""
    try:
        return os.stat(path)
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise InputDataError(f'{what}{path}: is a symbolic link loop (it points, through '
                                 'links, at itself); give the real file') from None
        if error.errno == errno.ENOENT:
            dangling = os.path.islink(path)
            reason = ('is a symbolic link to a missing file' if dangling else 'no such file')
            raise InputDataError(f'{what}{path}: {reason}; check the path') from None
        if error.errno == errno.EACCES:
            raise InputDataError(f'{what}{path}: permission denied; make it readable (chmod '
                                 'u+r) or run as its owner') from None
        raise InputDataError(f'{what}{path}: cannot be opened ({error.strerror or error}); '
                             'check the path') from None


def check_input_path(path: PathLike, what: str = '', directory: bool = False) -> None:
    """
    Refuse an input that is not a regular file (or a directory, when ``directory``).

    Parameters
    ----------
    path : str or os.PathLike
        The input.
    what : str
        Prefix of the message naming the option, e.g. ``'--prior '`` (default none).
    directory : bool
        Whether a directory is accepted (a rosbag2 directory, a folder to search).

    Raises
    ------
    InputDataError
        For a missing path, a symlink loop, a FIFO, a device, a socket, naming the path, what
        it is and what to give instead.

    """
    mode = _stat(path, what).st_mode
    if stat.S_ISREG(mode) or (directory and stat.S_ISDIR(mode)):
        return
    if stat.S_ISDIR(mode):
        raise InputDataError(f'{what}{path}: is a directory; give a file')
    raise InputDataError(f'{what}{path}: is {kind_of(mode)}, not a regular file: it could '
                         'block or never end; copy the data to a file and give that')


def same_file(path: PathLike, others: Iterable[PathLike]) -> Optional[str]:
    """Return the first of ``others`` that is the same file as ``path`` (None if none is)."""
    try:
        mine = os.stat(path)
    except OSError:
        return None
    for other in others:
        try:
            theirs = os.stat(other)
        except OSError:
            continue
        if (mine.st_dev, mine.st_ino) == (theirs.st_dev, theirs.st_ino):
            return str(other)
    return None
