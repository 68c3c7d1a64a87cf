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
import fnmatch
import hashlib
import os
import stat
import tempfile
from typing import Iterable, Optional, Sequence

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike

__all__ = ['check_input_path', 'check_not_over_inputs', 'check_output_path',
           'check_replaceable', 'is_bag_dir', 'kind_of', 'same_content', 'same_file']

#: The files that mark a directory as a rosbag2 bag (a bag is read as a whole directory).
_BAG_MARKS = ('metadata.yaml',)
_BAG_SUFFIXES = ('.mcap', '.db3')


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


def _files_of(path: PathLike) -> list[str]:
    """Return the regular files an input consists of (itself, or a directory's, sorted)."""
    if os.path.isdir(path):
        return sorted(os.path.join(root, name) for root, _, names in os.walk(path)
                      for name in names if os.path.isfile(os.path.join(root, name)))
    return [str(path)] if os.path.isfile(path) else []


def _fingerprint(path: PathLike, depth: int) -> tuple:
    """
    Return the sizes of an input's files, and at ``depth`` 1 or 2 a digest of their bytes.

    Depth 1 digests the first and last MiB of each file (cheap), depth 2 all of it (BLAKE2).
    """
    files = _files_of(path)
    sizes = tuple(os.path.getsize(name) for name in files)
    if not depth:
        return sizes
    digest = hashlib.blake2b(digest_size=20)
    for name, size in zip(files, sizes):
        with open(name, 'rb') as stream:
            if depth == 1:
                digest.update(stream.read(1 << 20))
                stream.seek(max(size - (1 << 20), 0))
                digest.update(stream.read(1 << 20))
                continue
            for block in iter(lambda: stream.read(1 << 20), b''):
                digest.update(block)
    return sizes, digest.hexdigest()


def same_content(paths: Sequence[PathLike]) -> Optional[tuple[str, str]]:
    """
    Return two inputs whose bytes are identical (a copy under another name), else None.

    Only inputs of equal sizes are read (a digest of their files): a copy fitted as a second
    record would shrink the standard errors by the square root of two.
    """
    try:
        sizes = [_fingerprint(path, 0) for path in paths]
        for index, size in enumerate(sizes):
            twins = [other for other in range(index) if sizes[other] == size and size]
            for depth in (1, 2):
                mine = _fingerprint(paths[index], depth) if twins else None
                twins = [other for other in twins if _fingerprint(paths[other], depth) == mine]
            if twins:
                return str(paths[twins[0]]), str(paths[index])
    except OSError:
        return None  # the readers say what is wrong with the path
    return None


def _nearest_existing(path: str) -> str:
    """Return ``path`` or its nearest ancestor that exists."""
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return path


def check_output_path(path: str, option: str, directory: bool = False,
                      inputs: Sequence[PathLike] = (), writes: Sequence[str] = ('*',)) -> None:
    """
    Refuse an output path that cannot be written, before any work is done.

    A file option (``--json``) must not name a directory, and may only replace a regular file
    that is not one of the ``inputs`` (never a symlink, a device, a FIFO nor a recording);
    for both kinds, the nearest existing ancestor must be a directory in which a file can be
    created (tried with a temporary file, which also catches read-only file systems and
    running as root).  No output lies inside an input bag directory, and a directory output
    never holds an input under a name it ``writes`` (:func:`check_not_over_inputs`).

    Raises
    ------
    InputDataError
        Naming the option, the path and what is wrong.

    """
    target = os.path.abspath(path)
    check_not_over_inputs(path, option, inputs, directory, writes)
    if not directory:
        check_replaceable(path, option, inputs)
    if not directory and (os.path.isdir(target) or path.endswith(os.sep)):
        raise InputDataError(f'{option} {path}: is a directory; give a file name, e.g. '
                             f'{os.path.join(path, "result.json")}')
    if directory and os.path.exists(target) and not os.path.isdir(target):
        raise InputDataError(f'{option} {path}: exists and is not a directory; give a '
                             'directory for the report')
    where = target if directory and os.path.isdir(target) else os.path.dirname(target)
    existing = _nearest_existing(where)
    if not os.path.isdir(existing):
        raise InputDataError(f'{option} {path}: {existing} is a file, not a directory; choose '
                             'another place')
    try:
        handle, probe = tempfile.mkstemp(dir=existing, prefix='.dcmotor_id_probe_')
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        raise InputDataError(f'{option} {path}: cannot write in {existing} '
                             f'({error.strerror or error}); choose a writable place') from None


def check_replaceable(path: str, option: str, inputs: Sequence[PathLike] = ()) -> None:
    """Refuse an output file that exists and is not a regular file, or is an input."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return
    if stat.S_ISLNK(mode):
        raise InputDataError(f'{option} {path}: is a symbolic link (to '
                             f'{os.readlink(path)}); it is not replaced: give the path of a '
                             'new or regular file')
    if stat.S_ISDIR(mode):
        return  # refused as a directory by the caller
    if not stat.S_ISREG(mode):
        raise InputDataError(f'{option} {path}: is {kind_of(mode)}, not a regular file; it is '
                             'not replaced: give the path of a new or regular file')
    twin = same_file(path, inputs)
    if twin is not None:
        raise InputDataError(f'{option} {path}: is the input {twin}; writing there would '
                             'destroy the recording: give another file name')


def _real(path: PathLike) -> str:
    """Return the real path of ``path``, which may not exist yet (its ancestors resolved)."""
    return os.path.realpath(os.path.abspath(path))


def is_bag_dir(directory: PathLike) -> bool:
    """Whether ``directory`` looks like a rosbag2 bag (metadata or a storage file in it)."""
    try:
        names = os.listdir(directory)
    except OSError:
        return False
    return any(name in _BAG_MARKS or name.endswith(_BAG_SUFFIXES) for name in names)


def _input_areas(inputs: Iterable[PathLike]) -> tuple[list[str], list[str]]:
    """Return the directories an input reads as a whole (bags) and the input files."""
    directories, files = [], []
    for item in inputs:
        if item is None or not os.path.exists(item):
            continue
        real = _real(item)
        if os.path.isdir(real):
            directories.append(real)
        else:
            files.append(real)
            parent = os.path.dirname(real)
            if any(os.path.exists(os.path.join(parent, mark)) for mark in _BAG_MARKS):
                directories.append(parent)
    return directories, files


def _inside(path: str, directory: str) -> bool:
    """Whether the real ``path`` is ``directory`` or below it."""
    return path == directory or path.startswith(directory.rstrip(os.sep) + os.sep)


def check_not_over_inputs(path: PathLike, option: str, inputs: Sequence[PathLike],
                          directory: bool = False, writes: Sequence[str] = ('*',)) -> None:
    """
    Refuse an output inside an input bag directory, or one that would replace an input.

    Parameters
    ----------
    path : str or os.PathLike
        The output file (or directory, when ``directory``).
    option : str
        The option named in the message (``--json``, ``--export``).
    inputs : sequence of paths
        Every file and directory the command reads.
    directory : bool
        Whether ``path`` is a directory into which files are written.
    writes : sequence of str
        Shell patterns of the names written into a directory output (default: any name).

    Raises
    ------
    InputDataError
        Naming the option, the path and the input it would damage.

    """
    target = _real(path)
    directories, files = _input_areas(inputs)
    for area in directories:
        if _inside(target, area):
            raise InputDataError(
                f'{option} {path}: is inside the input bag directory {area}; writing there '
                'could replace or damage the recording: give a place outside it')
    if not directory:
        return
    for name in files:
        if os.path.dirname(name) == target and any(
                fnmatch.fnmatch(os.path.basename(name), pattern) for pattern in writes):
            raise InputDataError(
                f'{option} {path}: would overwrite the input {name} (it writes '
                f"{', '.join(writes)} there); give another directory")
