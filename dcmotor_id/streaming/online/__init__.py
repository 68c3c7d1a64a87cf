"""
Online identification (no ROS here): estimators that run while the drive runs.

* :mod:`~dcmotor_id.streaming.online.window` (default, :class:`WindowEstimator`): exact
  output-error
  fits on a sliding window, warm-started, consistent under sensor noise, honest standard
  errors.
* :mod:`~dcmotor_id.streaming.online.rls` (:class:`OnlineEstimator`, alias :class:`RlsEstimator`):
  the
  recursive least squares on the exactly discretised neurons; cheap but biased by noise.
* :mod:`~dcmotor_id.streaming.online.estimate`: the :class:`OnlineEstimate` both return.
* :mod:`~dcmotor_id.streaming.online.schedule`: parameters that change on a schedule (simulation).

Change detection on the estimates is :mod:`dcmotor_id.streaming.monitoring`.
"""

from dcmotor_id.streaming.online.estimate import (INTERVAL_SIGMAS, is_converged, NAMES,
                                                  OnlineEstimate, simultaneous_sigmas)
from dcmotor_id.streaming.online.rls import (log2x2, OnlineEstimator, physical_from_discrete,
                                             RlsEstimator)
from dcmotor_id.streaming.online.schedule import (Change, ParameterSchedule, parse_schedule,
                                                  simulate_scheduled)
from dcmotor_id.streaming.online.window import (disagreement, LOAD_TORQUE, refit_window, RefitJob,
                                                RefitOutcome, RefitProcess, WindowEstimator)

__all__ = [
    'Change', 'disagreement', 'INTERVAL_SIGMAS', 'is_converged', 'LOAD_TORQUE', 'log2x2',
    'make_estimator', 'NAMES',
    'OnlineEstimate', 'OnlineEstimator', 'parse_schedule', 'ParameterSchedule',
    'METHODS', 'physical_from_discrete', 'RefitJob', 'RefitOutcome', 'RefitProcess',
    'refit_window', 'RlsEstimator', 'simulate_scheduled', 'simultaneous_sigmas',
    'WindowEstimator',
]

#: Online methods by name (the node's ``online_method``).
METHODS = ('window', 'rls')


def make_estimator(method: str, sample_period_s: float, **options):
    """
    Build the online estimator ``method`` (``window`` or ``rls``).

    Options a method does not take are ignored: ``memory_s`` is the RLS's, ``window_s``,
    ``refit_interval_s``, ``cpu_budget``, ``load_torque``, ``submit`` and ``initial`` the
    window's; ``converged_rel_stderr`` both.
    """
    if method == 'rls':
        return OnlineEstimator(sample_period_s, options.get('memory_s', 10.0),
                               options.get('converged_rel_stderr', 0.05))
    if method == 'window':
        names = ('window_s', 'refit_interval_s', 'min_window_s', 'converged_rel_stderr',
                 'cpu_budget', 'load_torque', 'submit', 'initial')
        return WindowEstimator(sample_period_s, **{name: options[name] for name in names
                                                   if name in options})
    raise ValueError(f'unknown online method {method!r}; one of {", ".join(METHODS)}')
