"""
The interface every online estimator implements, and the table that builds one by name.

An online estimator is fed consecutive samples while the drive runs and gives an
:class:`~dcmotor_id.streaming.online.estimate.OnlineEstimate` whenever asked.  The identifier
node and :class:`~dcmotor_id.streaming.monitoring.OnlineMonitor` see only this protocol.

Adding an online estimator: one module in this folder with a class that implements
:class:`OnlineEstimator` (``method`` its name, ``from_options`` its constructor from the node's
options), one line in :data:`ESTIMATORS`, and its test.
"""

from __future__ import annotations

import importlib
from typing import Any, Mapping, Protocol, runtime_checkable

from numpy.typing import ArrayLike

from dcmotor_id.streaming.online.estimate import OnlineEstimate

__all__ = ['ESTIMATORS', 'make_estimator', 'METHODS', 'OnlineEstimator']


@runtime_checkable
class OnlineEstimator(Protocol):
    """
    What an online estimator offers its users (the node, the monitor, the benchmarks).

    Attributes
    ----------
    method : str
        Its name in :data:`ESTIMATORS` (the node's ``online_method``).
    sample_period_s : float
        Sample period of the data fed in [s].
    baseline_window_s : float
        Data time an estimate stands for [s]: a change detector learns its baseline over
        at least this long.

    """

    method: str
    sample_period_s: float
    baseline_window_s: float

    @classmethod
    def from_options(cls, sample_period_s: float,
                     options: Mapping[str, Any]) -> 'OnlineEstimator':
        """Build the estimator from the node's options (each takes those it knows)."""

    @property
    def time_s(self) -> float:
        """Return the data time fed so far [s] (gaps not counted)."""

    def reset(self) -> None:
        """Forget everything."""

    def break_continuity(self) -> None:
        """Declare a gap: the next sample is not the successor of the last one."""

    def update(self, voltage: ArrayLike, current: ArrayLike, speed: ArrayLike) -> int:
        """Feed consecutive samples [V, A, rad/s]; return the number taken."""

    def estimate(self) -> OnlineEstimate:
        """Return the current estimate."""

    def flush(self) -> None:
        """Use the samples still buffered (at the end of a run)."""

    def close(self) -> None:
        """Release what the estimator holds (worker processes)."""


#: Online estimators by name: module of this package and class.
ESTIMATORS: dict[str, tuple[str, str]] = {
    'window': ('window', 'WindowEstimator'),
    'rls': ('rls', 'RlsEstimator'),
}

#: Online methods by name (the node's ``online_method``).
METHODS = tuple(ESTIMATORS)


def estimator_class(method: str) -> Any:
    """Return the class of the online estimator ``method`` (imported on first use)."""
    if method not in ESTIMATORS:
        raise ValueError(f'unknown online method {method!r}; one of {", ".join(METHODS)}')
    module, name = ESTIMATORS[method]
    return getattr(importlib.import_module(f'{__package__}.{module}'), name)


def make_estimator(method: str, sample_period_s: float, **options: Any) -> OnlineEstimator:
    """
    Build the online estimator ``method`` (a key of :data:`ESTIMATORS`).

    Options a method does not take are ignored: ``memory_s`` is the RLS's, ``window_s``,
    ``refit_interval_s``, ``min_window_s``, ``cpu_budget``, ``load_torque``, ``submit``,
    ``in_subprocess`` and ``initial`` the window's; ``converged_rel_stderr`` both.
    """
    return estimator_class(method).from_options(sample_period_s, options)
