"""
What every online estimator reports: the :class:`OnlineEstimate` snapshot and convergence.

The published interval of a parameter is ``value +- INTERVAL_SIGMAS * stderr``
(:attr:`OnlineEstimate.interval`): a *simultaneous* interval for the six parameters.  Six
separate 3-sigma intervals miss at least one true value in up to 1.6 % of honest estimates
(bench/online_results.md: 1.6-1.9 %); with :data:`INTERVAL_SIGMAS` (Sidak: each interval
at the confidence level whose sixth power is that of one 3-sigma interval, 99.73 %) all six
hold together at least as often as one 3-sigma interval does.  The standard errors themselves
are not inflated.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from statistics import NormalDist
from typing import Mapping

import numpy as np

from dcmotor_id.core.model import DERIVED_NAMES, is_admissible, PARAMETER_NAMES

__all__ = ['INTERVAL_SIGMAS', 'is_converged', 'NAMES', 'OnlineEstimate', 'simultaneous_sigmas']

#: Names reported, in order.
NAMES = PARAMETER_NAMES + DERIVED_NAMES


def simultaneous_sigmas(count: int, sigmas: float = 3.0) -> float:
    """
    Return the multiple of the standard error for ``count`` simultaneous intervals (Sidak).

    ``count`` independent Gaussian estimates all lie within this many standard errors with the
    probability that one lies within ``sigmas`` (correlated ones more often).
    """
    # The standard library's normal quantile, not scipy.stats: importing that costs about
    # 1.3 s of CPU in every process that formats a result (the command line, the node).
    coverage = 1.0 - math.erfc(sigmas / math.sqrt(2.0))
    return -NormalDist().inv_cdf(0.5 * (1.0 - coverage ** (1.0 / count)))


#: Standard errors spanned by a published interval: the six parameters' intervals together
#: hold as often as one 3-sigma interval (3.51).
INTERVAL_SIGMAS = simultaneous_sigmas(len(PARAMETER_NAMES))


@dataclass(frozen=True)
class OnlineEstimate:
    """
    A snapshot of an online estimate.

    Attributes
    ----------
    parameters : dict
        Ra, La, CPhi, J, b, Mc, Ka, Ta in SI units (NaN before the data excite the motor).
    stderr : dict
        Their standard errors (NaN where unknown).
    converged : bool
        Every parameter physical, each relative standard error below the threshold (and, for
        the window estimator, the last fit succeeded, is recent and agrees with the one
        before within their errors).
    innovation_rms : dict
        ``current`` [A] and ``speed`` [rad/s]: RMS of the prediction error (the RLS: one step
        ahead over its forgetting horizon; the window estimator: the simulation error of its
        last fit, i.e. the sensor noise when the model holds).
    n_updates : int
        Sample pairs (RLS) or samples (window) used so far.
    method : str
        ``rls`` or ``window``.
    time_s : float
        Data time the estimate refers to: the end of the data it used, in seconds of samples
        fed since the start (gaps not counted).
    window_s : float
        Length of the data behind the estimate [s] (the RLS: its memory).
    effects : dict
        Further estimated quantities by name (the window estimator: ``load_torque_Nm``, a
        constant torque on the shaft, NaN when the data cannot separate it from Coulomb
        friction), with ``<name>_stderr``.
    status : str
        Why the estimate is not (or no longer) converged, or ''.
    fit_cpu_s : float
        CPU time of the last fit [s] (window estimator; NaN for the RLS).
    torque_rms_Nm : float
        RMS of the drive torque ``CPhi i`` over the window [N m] (scale of a load torque).
    settled : bool
        False while the model has stopped holding over the window for less than half a
        window (the motor changed inside it; the fit mixes before and after): change alarms
        wait for a restarted window or for the change to persist.

    """

    parameters: dict
    stderr: dict
    converged: bool
    innovation_rms: dict = field(default_factory=dict)
    n_updates: int = 0
    method: str = 'rls'
    time_s: float = math.nan
    window_s: float = math.nan
    effects: dict = field(default_factory=dict)
    status: str = ''
    fit_cpu_s: float = math.nan
    torque_rms_Nm: float = math.nan
    settled: bool = True

    @property
    def interval(self) -> dict:
        """Return the half-widths of the published (simultaneous) intervals by name."""
        return {name: INTERVAL_SIGMAS * error for name, error in self.stderr.items()}


def is_converged(values: Mapping[str, float], stderr: Mapping[str, float],
                 threshold: float) -> bool:
    """Admissible parameters (``is_admissible`` of the model), each well determined."""
    if not all(np.isfinite(values.get(name, math.nan)) for name in PARAMETER_NAMES):
        return False
    if not is_admissible(values):
        return False
    for name in PARAMETER_NAMES:
        error = stderr[name]
        if not np.isfinite(error) or error > threshold * abs(values[name]):
            return False
    return True
