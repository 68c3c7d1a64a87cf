"""
Results written as strict JSON, atomically: a reader sees the old file or the whole new one.

Non-finite numbers become ``null`` (JSON has no NaN); the target may only replace a regular
file (:func:`dcmotor_id.formats.paths.check_replaceable`).
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from typing import Any, Mapping

import numpy as np

from dcmotor_id.formats.paths import check_replaceable

__all__ = ['load_json', 'write_json']


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
            json.dump(_json_safe(result), stream, indent=2, allow_nan=False)
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
