"""
The memory budget of reading a record: estimated before allocating, refused beyond it.

A small file can ask for a huge allocation: a zstd MCAP chunk that decompresses to GBs, a
v7.3 ``.mat`` declaring 3e9 values, a Parquet file of billions of rows.  Every reader
estimates the bytes it is about to allocate from the file's own metadata (chunk sizes,
declared shapes, row counts) and calls :func:`check_budget` first; beyond the budget the read
is refused with a message naming the file, what it declares and the option that raises the
budget (``--memory-budget GB``, default :data:`DEFAULT_BUDGET_BYTES`).
"""

from __future__ import annotations

from dcmotor_id.core.errors import InputDataError

#: Default budget of one allocation of a reader [bytes]: 1 GB, 125 million float64 values
#: (about 11 hours of three channels at 1 kHz).
DEFAULT_BUDGET_BYTES = 1e9

_budget = [DEFAULT_BUDGET_BYTES]

__all__ = ['check_budget', 'DEFAULT_BUDGET_BYTES', 'memory_budget', 'set_memory_budget']


def set_memory_budget(budget_bytes: float) -> None:
    """Set the budget [bytes] (``--memory-budget`` in GB times 1e9)."""
    if not budget_bytes > 0:
        raise InputDataError(f'--memory-budget must be positive, got {budget_bytes / 1e9:g} GB')
    _budget[0] = float(budget_bytes)


def memory_budget() -> float:
    """Return the budget [bytes]."""
    return _budget[0]


def check_budget(estimate_bytes: float, path: object, what: str,
                 fix: str = 'else cut the recording into shorter files') -> None:
    """
    Refuse an allocation estimated beyond the budget.

    Parameters
    ----------
    estimate_bytes : float
        What the reader is about to allocate [bytes].
    path : str
        The file (named in the message).
    what : str
        What the file declares, e.g. ``"variable 'current' of 3e+09 values"``.
    fix : str
        What to do instead of raising the budget.

    Raises
    ------
    InputDataError
        Naming the file, what it declares, the estimate and the option.

    """
    if estimate_bytes <= _budget[0]:
        return
    raise InputDataError(
        f'{path}: {what} would need about {estimate_bytes / 1e9:.3g} GB of memory, beyond the '
        f'memory budget of {_budget[0] / 1e9:.3g} GB; if that is right, raise it with '
        f'--memory-budget GB (this machine must have that much free), {fix}')
