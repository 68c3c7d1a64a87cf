"""
One BLAS thread while identifying: the linear algebra of a fit is small, threads only cost CPU.

numpy's wheels bundle OpenBLAS, which runs a least-squares solve on a ``60000 x 10`` matrix
(the residual analysis' autoregression, the start-point regressions) on every core; on two
shared cores that takes ten times the CPU of one thread for the same result (issue 11).
:func:`single_threaded` limits the BLAS libraries loaded in the process to one thread for the
duration of a call and restores the previous counts after it, with :mod:`threadpoolctl` (the
library scikit-learn uses for the same purpose; it knows OpenBLAS, MKL and BLIS).
"""

from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

_Function = TypeVar('_Function', bound=Callable[..., Any])


def blas_threads() -> int:
    """Return the largest thread count of the BLAS libraries loaded in the process (0: none)."""
    from threadpoolctl import threadpool_info

    return max((int(pool['num_threads']) for pool in threadpool_info()
                if pool.get('user_api') == 'blas'), default=0)


def single_threaded(function: _Function) -> _Function:
    """Decorate ``function`` to run with one BLAS thread (the counts are restored after)."""
    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        # imported here: the package's import stays free of it for the nodes
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1, user_api='blas'):
            return function(*args, **kwargs)
    return wrapper  # type: ignore[return-value]
