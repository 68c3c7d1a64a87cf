"""
Online identification (no ROS here): estimators that run while the drive runs.

* :mod:`~dcmotor_id.streaming.online.base`: the :class:`OnlineEstimator` protocol every
  online estimator implements, and :func:`make_estimator`, which builds one by name.
* :mod:`~dcmotor_id.streaming.online.window` (default, :class:`WindowEstimator`): exact
  output-error fits on a sliding window, warm-started, consistent under sensor noise,
  honest standard errors.
* :mod:`~dcmotor_id.streaming.online.rls` (:class:`RlsEstimator`): the recursive least
  squares on the exactly discretised neurons; cheap but biased by noise.
* :mod:`~dcmotor_id.streaming.online.estimate`: the :class:`OnlineEstimate` both return.
* :mod:`~dcmotor_id.streaming.online.schedule`: parameters that change on a schedule
  (simulation).

Change detection on the estimates is :mod:`dcmotor_id.streaming.monitoring`.  The names are
imported from their modules on first use, so that importing one of them (the summary needs
only :data:`INTERVAL_SIGMAS`) does not load the estimators' numerics.
"""

from __future__ import annotations

from typing import Any

from dcmotor_id.core.lazy import LazyNames

#: Public name -> module of this package that defines it.
_HOME = {
    'ESTIMATORS': 'base', 'make_estimator': 'base', 'METHODS': 'base',
    'OnlineEstimator': 'base',
    'INTERVAL_SIGMAS': 'estimate', 'is_converged': 'estimate', 'NAMES': 'estimate',
    'OnlineEstimate': 'estimate', 'simultaneous_sigmas': 'estimate',
    'log2x2': 'rls', 'physical_from_discrete': 'rls', 'RlsEstimator': 'rls',
    'Change': 'schedule', 'ParameterSchedule': 'schedule', 'parse_schedule': 'schedule',
    'simulate_scheduled': 'schedule',
    'disagreement': 'window', 'LOAD_TORQUE': 'window', 'refit_window': 'window',
    'RefitJob': 'window', 'RefitOutcome': 'window', 'RefitProcess': 'window',
    'WindowEstimator': 'window',
}

_NAMES = LazyNames(__name__, _HOME)
__all__ = _NAMES.names


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use."""
    return _NAMES.load(name)


def __dir__() -> list[str]:
    """List the public names."""
    return list(__all__)
