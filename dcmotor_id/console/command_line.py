"""
What every command-line entry point shares: argument types, and failures as exit codes.

The ``dcmotor-id`` command (:mod:`dcmotor_id.cli.main`) and a node's command-line mode
(``exciter --plan``) parse numbers with :func:`positive` and :func:`non_negative` (and the
memory budget with :func:`add_memory_budget`) and run their
work through :func:`run_reporting`: every failure ends as one message on stderr, never as a
traceback; 2 for bad input, data that cannot identify the motor and what the machine refuses
(a path, memory), with what to do; 1 for anything else, with a short report (a bug); 130 when
interrupted.
"""

from __future__ import annotations

import argparse
import errno
import os
import platform
import sys
import traceback
from typing import Any, Callable

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.formats.budget import DEFAULT_BUDGET_BYTES

__all__ = ['add_memory_budget', 'non_negative', 'os_error_message', 'positive',
           'run_reporting']


def positive(text: str) -> float:
    """Return ``text`` as a finite number above 0 (an ``argparse`` type)."""
    value = float(text)
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text}')
    return value


def non_negative(text: str) -> float:
    """Return ``text`` as a finite number at or above 0 (an ``argparse`` type)."""
    value = float(text)
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f'must be zero or a positive number, got {text}')
    return value


def add_memory_budget(group: Any) -> None:
    """Add the ``--memory-budget GB`` option to an ``argparse`` parser or group."""
    group.add_argument('--memory-budget', type=positive, default=DEFAULT_BUDGET_BYTES / 1e9,
                       metavar='GB', help='largest allocation a file may ask for, estimated '
                       'before reading (default %(default)g GB); larger files are refused')


#: Unexpected exceptions that come from the data or the machine, not from a bug: exit 2.
_ENVIRONMENT_HINTS = (
    (MemoryError, 'not enough memory for these data; identify a shorter record or fewer '
                  'files at a time, or free memory'),
    (UnicodeError, 'the input is not text in UTF-8; save it as a UTF-8 CSV'),
    (np.linalg.LinAlgError, 'the numbers do not fit a DC motor model; check that the columns '
                            'are what their names say (current in A, speed in rad/s, not '
                            'swapped) and that the data come from one drive'),
    (FloatingPointError, 'the numbers overflow the computation; check the units of the '
                         'columns'),
    (OverflowError, 'the numbers overflow the computation; check the units of the columns'),
)


#: What to do about an error of the operating system, by errno.
_OS_HINTS = {
    errno.EACCES: 'permission denied: make it readable/writable for this user (chmod) or '
                  'choose another place',
    errno.EPERM: 'operation not permitted: choose another place or run as its owner',
    errno.EEXIST: 'already exists and is in the way: remove it or choose another name',
    errno.ENOENT: 'no such file or directory: check the path',
    errno.ENOSPC: 'no space left on the device: free space or write elsewhere',
    errno.EROFS: 'the file system is read-only: write elsewhere',
    errno.ENOTDIR: 'a part of the path is a file, not a directory: check the path',
    errno.EISDIR: 'is a directory: give a file',
    errno.ELOOP: 'a symbolic link loop: give the real path',
    errno.ENAMETOOLONG: 'the name is too long: choose a shorter path',
}


def os_error_message(error: OSError) -> str:
    """Return an error of the operating system as a sentence naming the path and the fix."""
    where = error.filename if error.filename is not None else ''
    if error.filename2 is not None:
        where = f'{where} -> {error.filename2}'
    hint = _OS_HINTS.get(error.errno or 0)
    if hint is None:
        hint = f'{error.strerror or error}: check the path and the machine'
    return f'{where}: {hint}' if where else hint


def _bug_report(error: BaseException) -> str:
    """Return a short report of an unexpected exception: where it happened and versions."""
    frames = traceback.extract_tb(error.__traceback__)
    where = ', '.join(f'{os.path.basename(frame.filename)}:{frame.lineno} {frame.name}'
                      for frame in frames[-3:])
    return (f'dcmotor-id: internal error: {type(error).__name__}: {error}\n'
            f'  at {where or "?"}\n'
            f'  python {platform.python_version()}, numpy {np.__version__}, '
            f'{platform.system()} {platform.machine()}\n'
            '  This is a bug of dcmotor-id: please report it with this text, the command line '
            'and, if you can, the input files.')


def run_reporting(handler: Callable[[Any], int], args: Any) -> int:
    """
    Return ``handler(args)``, or the exit code of its failure, after a one-line message.

    Every failure ends as a message, never as a traceback: 2 for bad input, data that cannot
    identify the motor and what the machine refuses (a path, memory), with what to do; 1 for
    anything else, with a short report (a bug); 130 when interrupted.
    """
    try:
        return handler(args)
    except DcMotorIdError as error:
        print(f'dcmotor-id: error: {error}', file=sys.stderr)
        return 2
    except OSError as error:
        print(f'dcmotor-id: error: {os_error_message(error)}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('dcmotor-id: interrupted', file=sys.stderr)
        return 130
    except Exception as error:  # noqa: BLE001  (the top-level handler: a message, not a trace)
        for kind, hint in _ENVIRONMENT_HINTS:
            if isinstance(error, kind):
                print(f'dcmotor-id: error: {type(error).__name__}: {error}: {hint}',
                      file=sys.stderr)
                return 2
        print(_bug_report(error), file=sys.stderr)
        return 1
