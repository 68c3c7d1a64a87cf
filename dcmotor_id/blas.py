"""
One BLAS thread while identifying: the linear algebra of a fit is small, threads only cost CPU.

numpy's wheels bundle OpenBLAS, which runs a least-squares solve on a ``60000 x 10`` matrix
(the residual analysis' autoregression, the start-point regressions) on every core; on two
shared cores that takes ten times the CPU of one thread for the same result (issue 11).
:func:`single_threaded` limits OpenBLAS to one thread for the duration of a call and restores
the previous count after it.  It finds the library among the shared objects of numpy's wheel
(``numpy.libs``); with another BLAS (a distribution's numpy, MKL, Accelerate) it does nothing.
"""

from __future__ import annotations

import ctypes
import functools
import glob
import os
from typing import Any, Callable, TypeVar

import numpy as np

_Function = TypeVar('_Function', bound=Callable[..., Any])

#: (get, set) function names of the OpenBLAS builds numpy's wheels bundle (64-bit integers
#: with the ``scipy_`` prefix, then plain).
_SYMBOLS = (('scipy_openblas_get_num_threads64_', 'scipy_openblas_set_num_threads64_'),
            ('openblas_get_num_threads64_', 'openblas_set_num_threads64_'),
            ('openblas_get_num_threads', 'openblas_set_num_threads'))

_control: list[Any] = []


def _openblas() -> tuple[Any, Any] | None:
    """Return the (get, set) thread-count functions of numpy's OpenBLAS, None if not found."""
    if not _control:
        found = None
        libraries = os.path.join(os.path.dirname(os.path.dirname(np.__file__)), 'numpy.libs')
        for path in sorted(glob.glob(os.path.join(libraries, '*openblas*'))):
            try:
                library = ctypes.CDLL(path)
            except OSError:
                continue
            for get_name, set_name in _SYMBOLS:
                get = getattr(library, get_name, None)
                put = getattr(library, set_name, None)
                if get is not None and put is not None:
                    get.restype = ctypes.c_int
                    put.argtypes = [ctypes.c_int]
                    found = (get, put)
                    break
            if found is not None:
                break
        _control.append(found)
    return _control[0]


def single_threaded(function: _Function) -> _Function:
    """Decorate ``function`` to run with one OpenBLAS thread (the count is restored after)."""
    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        control = _openblas()
        if control is None:
            return function(*args, **kwargs)
        get, put = control
        previous = int(get())
        put(1)
        try:
            return function(*args, **kwargs)
        finally:
            put(previous)
    return wrapper  # type: ignore[return-value]
