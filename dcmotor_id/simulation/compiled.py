"""
The kernels of the identify path as machine code: compiled ahead of time when set up, else JIT.

Every process that calls a numba kernel pays for numba itself: importing it, initialising its
compiler's type registries (which imports :mod:`scipy.linalg`) and loading the cached machine
code, about 0.6 s of CPU, more than identifying a minute of data takes (issue 11).  The set-up
step (``python -m dcmotor_id.cli.warmup``, :func:`build`) therefore also compiles the kernels of
the identify path, :data:`AHEAD_OF_TIME`, into one extension module with numba's ahead-of-time
compiler (``numba.pycc``, which needs a C compiler); the module imports in milliseconds and
does not need numba at run time.  Its name carries a digest of the kernels' sources and of the
Python and numpy versions (:func:`module_name`), so that a module built from other sources is
never loaded: :func:`kernel` then returns numba's JIT dispatcher, as it does for every kernel
not in the table and when no module was built (no compiler, read-only install).  The
ahead-of-time functions are the same source compiled by the same compiler: they return the
same values (test/test_warmup.py compares them).
"""

from __future__ import annotations

import glob
import hashlib
import importlib
import os
import sys
from typing import Any, Callable

import numpy as np

_HERE = os.path.dirname(os.path.abspath(__file__))

#: Module of each kernel's numba source.
_SOURCES = {'kernels': 'dcmotor_id.simulation.kernels',
            'sensitivity': 'dcmotor_id.simulation.sensitivity'}

_NORMAL_ARGUMENTS = ', '.join([
    'f8[:, ::1]', 'f8[:, :, ::1]', 'f8[:, ::1]', 'f8[:, ::1]', 'f8[:, ::1]', 'i8[::1]',
    'i8[::1]', 'f8[::1]', 'f8[:, ::1]', 'i8[::1]', 'i8[::1]', 'f8[::1]', 'f8', 'f8', 'f8[::1]',
    'f8[::1]', 'f8[::1]', 'f8[:, ::1]', 'f8', 'f8[::1]', 'f8[::1]', 'f8[::1]', 'b1', 'i8[::1]',
    'f8[:, :, ::1]', 'b1'])

#: Kernels compiled ahead of time: name -> (source module key, numba signature), the argument
#: types the callers pass (C-contiguous float64 and int64 arrays).
AHEAD_OF_TIME = {
    'discretise': ('kernels', 'UniTuple(f8[:, ::1], 2)(f8[:, ::1], i8, f8)'),
    'simulate_kernel': ('kernels', 'f8[:, ::1](f8[:, ::1], f8[:, ::1], f8, f8, f8[::1], f8)'),
    'sosfilt_kernel': ('kernels', 'void(f8[:, ::1], f8[::1], f8[:, ::1])'),
    'normal_kernel': ('sensitivity', 'Tuple((f8[:, :, ::1], f8[:, ::1], f8, f8[::1], '
                      f'f8[:, :, ::1]))({_NORMAL_ARGUMENTS})'),
    'position_kernel': ('sensitivity', 'Tuple((f8[:, ::1], f8[::1], f8[:, ::1], f8, f8))('
                        'f8[:, :, ::1], f8, f8, f8[::1], f8, f8, b1, i8[::1])'),
}

#: Kernels not compiled ahead of time, and their numba module.
JIT_ONLY = {'effects_kernel': 'kernels'}

_loaded: dict[str, Callable[..., Any]] = {}


def source_digest() -> str:
    """Digest of the kernels' sources, this table, and the Python and numpy versions."""
    digest = hashlib.sha256()
    for name in sorted(_SOURCES) + ['compiled']:
        with open(os.path.join(_HERE, f'{name}.py'), 'rb') as stream:
            digest.update(stream.read())
    digest.update(f'{sys.version}|{np.__version__}'.encode())
    return digest.hexdigest()[:16]


def module_name() -> str:
    """Name of the ahead-of-time module of the present sources (in this package)."""
    return f'_aot_{source_digest()}'


def _ahead_of_time_module() -> Any:
    if os.environ.get('DCMOTOR_ID_JIT_ONLY'):
        return None
    try:
        return importlib.import_module(f'dcmotor_id.simulation.{module_name()}')
    except ImportError:
        return None


def kernel(name: str) -> Callable[..., Any]:
    """
    Return the kernel ``name``: its ahead-of-time machine code if built, else numba's JIT.

    The environment variable ``DCMOTOR_ID_JIT_ONLY`` (any non-empty value) forces the JIT
    dispatchers (numba then compiles or loads its on-disk cache as before).
    """
    found = _loaded.get(name)
    if found is not None:
        return found
    if name in AHEAD_OF_TIME:
        module = _ahead_of_time_module()
        found = getattr(module, name, None) if module is not None else None
        source = AHEAD_OF_TIME[name][0]
    else:
        source = JIT_ONLY[name]
    if found is None:
        found = getattr(importlib.import_module(_SOURCES[source]), name)
    _loaded[name] = found
    return found


def built_path() -> str | None:
    """Path of the ahead-of-time module of the present sources, None when not built."""
    found = [path for path in glob.glob(os.path.join(_HERE, f'{module_name()}.*'))
             if not path.endswith('.py')]
    return found[0] if found else None


def build(force: bool = False, verbose: bool = False) -> str:
    """
    Compile :data:`AHEAD_OF_TIME` into this package's extension module; return its path.

    Nothing is compiled when the module of the present sources exists (unless ``force``).
    Older modules (of other sources) are removed.  Needs numba's ``pycc`` and a C compiler;
    raises what they raise when they are missing.
    """
    import warnings

    existing = built_path()
    if existing is not None and not force:
        return existing
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # pycc's pending deprecation
        from numba.pycc import CC
    name = module_name()
    compiler = CC(name)
    compiler.output_dir = _HERE
    compiler.verbose = verbose
    compiler.target_cpu = 'host'
    for kernel_name, (source, signature) in AHEAD_OF_TIME.items():
        dispatcher = getattr(importlib.import_module(_SOURCES[source]), kernel_name)
        compiler.export(kernel_name, signature)(dispatcher.py_func)
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        compiler.compile()
    for path in glob.glob(os.path.join(_HERE, '_aot_*')):
        if not os.path.basename(path).startswith(name + '.'):
            os.remove(path)
    _loaded.clear()
    built = built_path()
    if built is None:
        raise RuntimeError(f'numba.pycc wrote no module {name} in {_HERE}')
    return built
