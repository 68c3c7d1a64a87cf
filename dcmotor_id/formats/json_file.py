"""
Results written as strict JSON, atomically: a reader sees the old file or the whole new one.

Non-finite numbers become ``null`` (JSON has no NaN); the target may only replace a regular
file (:func:`dcmotor_id.formats.paths.check_replaceable`).
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import tempfile
from typing import Any, Mapping, TextIO

import numpy as np

from dcmotor_id.formats.paths import check_replaceable

__all__ = ['load_json', 'SCHEMA_VERSION', 'STDOUT', 'dump_json', 'with_schema_version',
           'write_json', 'write_result_json']

#: Version of the layout of the JSON the command line writes (``schema_version`` in each; the
#: schemas: docs/schema/). Raised when a key changes meaning or goes away, not for a new key.
SCHEMA_VERSION = 1
#: The ``--json`` target that means stdout.
STDOUT = '-'


def load_json(stream: Any) -> Any:
    """
    Return the JSON document of a text stream, like ``json.load``.

    Every failure is a ``json.JSONDecodeError`` (a ``ValueError``), also a document nested
    beyond Python's recursion limit (100,000 ``[``), which ``json`` ends with a RecursionError.
    """
    text = stream.read()
    try:
        return json.loads(text)
    except RecursionError:
        raise json.JSONDecodeError('nested too deeply (more levels than any result file '
                                   'has)', text[:100], 0) from None


def _json_safe(value):
    """Replace non-finite floats by None (JSON has no NaN), recursively."""
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def dump_json(stream: TextIO, result: Mapping[str, Any]) -> None:
    """Write the result as strict JSON to an open text stream (non-finite numbers: null)."""
    json.dump(_json_safe(result), stream, indent=2, allow_nan=False)


def write_json(path: str, result: Mapping[str, Any]) -> None:
    """
    Write the result as strict JSON, atomically.

    The text goes to a temporary file of a unique name in the target directory (so concurrent
    runs never share one), then is renamed into place: a reader sees the old file or the whole
    new one, never a torn one.
    """
    check_replaceable(path, 'the output')
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=directory, suffix='.partial',
                                         prefix=f'.{os.path.basename(path)}.')
    try:
        with os.fdopen(handle, 'w', encoding='utf-8') as stream:
            dump_json(stream, result)
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def with_schema_version(result: Mapping[str, Any]) -> dict:
    """Return ``result`` with ``schema_version`` (:data:`SCHEMA_VERSION`) as its first key."""
    return {'schema_version': SCHEMA_VERSION,
            **{key: value for key, value in result.items() if key != 'schema_version'}}


def write_result_json(target: str, result: Mapping[str, Any],
                      stdout: TextIO | None = None) -> None:
    """
    Write a command's result with its schema version to ``target``: a file, or stdout.

    Parameters
    ----------
    target : str
        A path (written atomically, :func:`write_json`), or :data:`STDOUT` (``-``).
    result : mapping
        The result; ``schema_version`` is added.
    stdout : file-like, optional
        The stream of ``-`` (default ``sys.stdout``; the command line passes the real stdout
        while the rest of its output goes to stderr).

    """
    document = with_schema_version(result)
    if target != STDOUT:
        write_json(target, document)
        return
    stream = sys.stdout if stdout is None else stdout
    dump_json(stream, document)
    stream.write('\n')
    stream.flush()
