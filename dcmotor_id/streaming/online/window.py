"""
The default online estimator: an exact output-error fit on a sliding window, refitted warm.

Why this design (bench/online_results.md has the numbers):

* **Consistent under sensor noise.**  The fit is the offline one
  (:class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`): the motor is simulated
  from the
  measured voltage alone with the exact ZOH hybrid solution (no Euler bias at any sample
  period, Coulomb friction and stick-slip through reversals located exactly) and compared
  with the measured current and speed, so their noise never enters a regressor.  A
  recursive least squares on measured regressors (:mod:`dcmotor_id.streaming.online.rls`) is biased
  by
  that noise (b 88 % off at 1 % noise); a recursive instrumental-variable or prediction-error
  method would be consistent too, but neither reaches the maximum-likelihood spread nor has
  standard errors as simple to make honest, and the refit is cheap enough (below).
* **Honest standard errors.**  They are the fit's Gauss-Newton ones, floored at
  :data:`STDERR_FLOOR_REL` of the value (the solver's tolerance, which dominates without
  noise).  Over hundreds of draws the RMS of error over reported standard error is 0.9-1.1
  per parameter; the figures of 20 draws scatter more (the spread of 20 draws is known to
  +-16 %, and a badly excited window, motor 1 under the paper's excitation after 10 s, makes
  the standard error itself vary from draw to draw).  A warm start at the optimum once left
  them 10x too large at 0.1 % noise (fixed in the fit's reweighting).
* **Cost.**  A warm-started refit of 30 s at 1 kHz takes 0.1-0.5 s of CPU.  Refits run every
  ``refit_interval_s`` of data, stretched so that they never take more than ``cpu_budget``
  of one core; buffering a sample costs nothing measurable, so the estimator keeps up at any
  sample rate (at 10 kHz the refits simply come less often).  In the node they run in a
  process of their own (:class:`RefitProcess`), so a fit never stalls the sample intake.
* **The window.**  It grows from the start (and from a restart after a change) up to
  ``window_s`` (30 s), then slides: after 30 s the estimate uses the same data as an offline
  fit of those 30 s and has its spread (a 20 s window: 1.2-1.6 times it).  A gap (lost
  samples, :meth:`WindowEstimator.break_continuity`) does not shorten it: the runs on either
  side are fitted together, each from its own initial state.
* **Tracking.**  The window forgets everything older than ``window_s``, so a ramp is
  followed with a lag of a fraction of a window.  A sudden change makes the window's fit
  leave a simulation error above the noise level of the recent fits; the last
  ``restart_s`` are then fitted alone and, if the model holds there, the window restarts
  from them (a change-adaptive window), so a step is tracked within seconds rather than a
  window (bench: tracking lag).  A change too small to raise the simulation error (a load
  torque of 0.7 % of the drive torque) is followed with a lag of about a window.
* **A load torque.**  With speeds of both signs in the window, a constant torque on the
  shaft (``load_torque_Nm``, as the ``load_torque`` effect) is estimated as well; a drive
  turning one way only cannot tell it from Coulomb friction, and it is left out then.

The estimate is *converged* when

1. the last fit succeeded and is recent, gives a physical motor and every parameter's
   relative standard error is below ``converged_rel_stderr``;
2. its simulation error is within the statistical fluctuation of the noise level of the
   recent fits (:data:`CONVERGED_MISMATCH_SIGMAS`): a change younger than the window shows
   there first;
3. it agrees with the fit before (since the start or a restart; after a restart a second fit
   must confirm the first): no parameter moved by more than
   :data:`~dcmotor_id.streaming.online.estimate.INTERVAL_SIGMAS` standard errors of the difference
   of
   two estimates from overlapping windows (:func:`disagreement`), i.e. no drift.

Its published interval is the simultaneous one (:attr:`OnlineEstimate.interval
<dcmotor_id.streaming.online.estimate.OnlineEstimate.interval>`, ``INTERVAL_SIGMAS`` = 3.51
standard
errors: the six hold together as often as one 3-sigma interval).  Why these and nothing more
(bench/online_results.md): with honest standard errors a parameter beyond 3 sigma is what
six separate 3-sigma intervals give in up to 1.6 % of the estimates, not a defect to hide by
inflating the errors; the simultaneous interval makes that rare (at most 0.27 %).  Rules 2
and 3 make ``converged`` false while the motor changes (a window lagging behind a ramp is
off by more than its errors although each fit is sound); what no rule can see is a change
younger than about one refit (bench: converged checks while tracking).  A full window is not
required: a shorter window's estimate has honest, larger errors and says so.
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
import math
from multiprocessing import get_context
import os
import time
from typing import Any, Callable, Mapping, Optional, Sequence
import warnings

import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.core.model import is_admissible, PARAMETER_NAMES
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators.base import ExogenousTerm
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.streaming.online.estimate import (INTERVAL_SIGMAS, is_converged, NAMES,
                                                  OnlineEstimate)

__all__ = ['disagreement', 'LOAD_TORQUE', 'RefitJob', 'RefitOutcome', 'RefitProcess',
           'refit_window', 'STDERR_FLOOR_REL', 'WindowEstimator']

#: Relative floor of every reported standard error: the fit's step tolerance (1e-8 on the
#: logarithms) leaves noise-free estimates this close, not closer.
STDERR_FLOOR_REL = 1e-6
#: Name of the load-torque estimate in :attr:`OnlineEstimate.effects`.
LOAD_TORQUE = 'load_torque_Nm'
_LOAD_TERM = 'load_torque.torque_Nm'
#: Runs (between gaps) shorter than this many samples are left out of a fit.
MIN_RUN_SAMPLES = 100
#: Fraction of the window each speed sign needs for the load torque to be separable.
MIN_SIGN_FRACTION = 0.1
#: Simulation error over the reference noise level above which the window is suspected to
#: hold a change (white noise keeps the ratio within a percent or two of 1 over a window).
MISMATCH = 1.1
#: Ratio at or below which the recent data alone are taken to fit (restart).
HOLDS = 1.05
#: Standard deviations of the RMS of white noise (``1 / sqrt(2 n)`` relative, n samples)
#: by which the ratio may exceed 1 for a converged estimate: 1.014 for 30 s at 1 kHz.  On
#: stationary data (both motors, three excitations, 0.1-3 % noise, 1008 refits of 30 s
#: windows) the ratio stayed below 1.0065; a change younger than the window raises it
#: first (a ramp of Ra: 1.02 after 6 s).
CONVERGED_MISMATCH_SIGMAS = 3.5
#: Fits that held whose simulation error makes the reference noise level (their median).
REFERENCE_FITS = 5


def disagreement(previous: 'RefitOutcome', last: 'RefitOutcome') -> dict:
    """
    Return by parameter how far two refits lie apart in standard errors of their difference.

    Output-error estimates from windows of ``n_a`` and ``n_b`` samples sharing ``n_c`` are
    correlated by ``rho = n_c / sqrt(n_a n_b)`` (each sample brings the same information), so
    their difference has the variance ``s_a^2 + s_b^2 - 2 rho s_a s_b`` (a grown window:
    ``s_a^2 - s_b^2``).  A stationary motor keeps the ratio of order one; a drift inside the
    window (a ramp the window lags behind) makes it large.
    """
    start_a, start_b = previous.time_s - previous.window_s, last.time_s - last.window_s
    shared = max(0.0, min(previous.time_s, last.time_s) - max(start_a, start_b))
    rho = min(1.0, shared / math.sqrt(max(previous.window_s * last.window_s, 1e-300)))
    ratios = {}
    for name in PARAMETER_NAMES:
        error_a, error_b = previous.stderr[name], last.stderr[name]
        variance = max(error_a ** 2 + error_b ** 2 - 2.0 * rho * error_a * error_b, 0.0)
        scale = math.sqrt(variance) + STDERR_FLOOR_REL * abs(last.parameters[name])
        ratios[name] = abs(last.parameters[name] - previous.parameters[name]) / scale
    return ratios


@dataclass(frozen=True)
class RefitJob:
    """
    One window to fit: plain arrays, so that it pickles cheaply to a worker process.

    Attributes
    ----------
    sample_period_s : float
        Sample period [s].
    runs : tuple
        ``(voltage, current, speed)`` arrays of each contiguous run in the window.
    initial : dict or None
        Warm start (the last estimate's six parameters); None starts cold.
    load_torque : bool
        Estimate a constant load torque if the speed takes both signs.
    time_s : float
        Data time at the end of the window [s].
    reference_rms : dict or None
        Simulation-error RMS per channel of recent fits that held (the noise level); a fit
        well above it triggers the change-adaptive restart (see :func:`refit_window`).
    restart_s : float
        Length of the recent data a restart refits [s].

    """

    sample_period_s: float
    runs: tuple
    initial: Optional[dict]
    load_torque: bool
    time_s: float
    reference_rms: Optional[dict] = None
    restart_s: float = 5.0


@dataclass(frozen=True)
class RefitOutcome:
    """What a refit gives back (``error`` non-empty when it failed)."""

    time_s: float
    window_s: float
    parameters: dict = field(default_factory=dict)
    stderr: dict = field(default_factory=dict)
    effects: dict = field(default_factory=dict)
    noise_std: dict = field(default_factory=dict)
    cpu_s: float = 0.0
    error: str = ''
    torque_rms_Nm: float = math.nan
    restarted_samples: int = 0
    mismatch: float = math.nan


def _records(job: RefitJob) -> list[Record]:
    dt = job.sample_period_s
    return [Record(np.arange(len(voltage)) * dt, current=current, voltage=voltage, speed=speed)
            for voltage, current, speed in job.runs]


def _load_term(records: Sequence[Record], initial: Optional[Mapping[str, float]]
               ) -> list[ExogenousTerm]:
    """Return the load-torque term if the window's speeds take both signs, else none."""
    speed = np.concatenate([rec.speed for rec in records])
    fractions = (np.mean(speed > 0), np.mean(speed < 0))
    if min(fractions) < MIN_SIGN_FRACTION:
        return []
    current = np.concatenate([rec.current for rec in records])
    constant = float(initial['CPhi']) if initial else 1.0
    scale = max(0.05 * constant * float(np.std(current)), 1e-9)
    return [ExogenousTerm(_LOAD_TERM, 'torque', tuple(-np.ones(len(rec)) for rec in records),
                          scale, 0.0)]


def _fit(records: list[Record], initial: Optional[dict], load_torque: bool) -> tuple:
    """Fit records warm (then cold if that fails); return the estimate and the terms."""
    terms = _load_term(records, initial) if load_torque else []
    try:
        return RefinedEstimator(initial=initial).fit(records, terms=terms), terms
    except Exception:  # noqa: BLE001  (a warm start into a bad region: start cold)
        if initial is None:
            raise
        return RefinedEstimator().fit(records, terms=terms), terms


def _mismatch(noise_std: Mapping[str, float], reference: Optional[Mapping[str, float]]
              ) -> float:
    """Return the largest ratio of a fit's simulation-error RMS to the reference (or NaN)."""
    if not reference:
        return math.nan
    return max((noise_std[channel] / reference[channel] for channel in noise_std
                if reference.get(channel, 0) > 0), default=math.nan)


def refit_window(job: RefitJob) -> RefitOutcome:
    """
    Fit the window of ``job`` by exact output error; never raise.

    A warm start that fails is retried cold (the automatic start of the offline fit).

    Change-adaptive restart: when the fit leaves a simulation error well above the noise
    level of recent fits (:data:`MISMATCH`), the motor probably changed inside the window.
    The last ``restart_s`` alone are then fitted too; if the model holds there
    (:data:`HOLDS`), that fit is the outcome and the estimator forgets the older data, so a
    step change is tracked within a few seconds instead of a window.
    """
    started = time.process_time()
    window_s = sum(len(run[0]) for run in job.runs) * job.sample_period_s
    try:
        with warnings.catch_warnings(), np.errstate(all='ignore'):
            # data that are no motor make the start-point search divide by zero: reported
            # as a failed fit, not as warnings in the node's log
            warnings.simplefilter('ignore', RuntimeWarning)
            return _refit(job, started, window_s)
    except Exception as error:  # noqa: BLE001  (a failed update must never stop the caller)
        text = str(error) or type(error).__name__
        return RefitOutcome(job.time_s, window_s, cpu_s=time.process_time() - started,
                            error=f'online fit failed: {text}')


def _refit(job: RefitJob, started: float, window_s: float) -> RefitOutcome:
    """Do the work of :func:`refit_window`."""
    records = _records(job)
    estimate, terms = _fit(records, job.initial, job.load_torque)
    restarted = 0
    mismatch = _mismatch(estimate.info['noise_std'], job.reference_rms)
    tail = int(round(job.restart_s / job.sample_period_s))
    if tail > 0 and mismatch > MISMATCH and len(records[-1]) >= 2 * tail:
        recent = [records[-1].slice(len(records[-1]) - tail, len(records[-1]))]
        base = {name: float(estimate.parameters[name]) for name in PARAMETER_NAMES}
        try:
            candidate, candidate_terms = _fit(recent, base, job.load_torque)
        except Exception:  # noqa: BLE001  (no restart then)
            candidate = None
        if candidate is not None and _mismatch(candidate.info['noise_std'],
                                               job.reference_rms) <= HOLDS:
            estimate, terms, records, restarted = candidate, candidate_terms, recent, tail
            window_s = tail * job.sample_period_s
    parameters = {name: float(estimate.parameters[name]) for name in NAMES}
    stderr = {name: max(float(estimate.stderr[name]), STDERR_FLOOR_REL * abs(value))
              for name, value in parameters.items()}
    effects = {LOAD_TORQUE: math.nan, LOAD_TORQUE + '_stderr': math.nan}
    if terms:
        load = float(estimate.parameters[_LOAD_TERM])
        effects = {LOAD_TORQUE: load,
                   LOAD_TORQUE + '_stderr': max(float(estimate.stderr[_LOAD_TERM]),
                                                STDERR_FLOOR_REL * abs(load))}
    current = np.concatenate([rec.current for rec in records])
    torque_rms = float(parameters['CPhi'] * np.sqrt(np.mean(current ** 2)))
    return RefitOutcome(job.time_s, window_s, parameters, stderr, effects,
                        dict(estimate.info['noise_std']),
                        time.process_time() - started, torque_rms_Nm=torque_rms,
                        restarted_samples=restarted, mismatch=mismatch)


class RefitProcess:
    """
    Run :func:`refit_window` in a process of its own; a dead process is restarted.

    Call it with a job to get a :class:`~concurrent.futures.Future` of the outcome.
    """

    def __init__(self) -> None:
        self._pool: Optional[ProcessPoolExecutor] = None

    def _start(self) -> ProcessPoolExecutor:
        from dcmotor_id.streaming.worker import warm_up, watch_parent
        pool = ProcessPoolExecutor(max_workers=1, mp_context=get_context('spawn'),
                                   initializer=watch_parent, initargs=(os.getpid(),))
        pool.submit(warm_up)
        return pool

    def warm(self) -> None:
        """Start the process now (imports and the numba cache load before the first fit)."""
        if self._pool is None:
            self._pool = self._start()

    def __call__(self, job: RefitJob) -> Future:
        """Submit ``job``; restart the process if it died."""
        if self._pool is None:
            self._pool = self._start()
        try:
            return self._pool.submit(refit_window, job)
        except (BrokenProcessPool, RuntimeError):
            self._pool = self._start()
            return self._pool.submit(refit_window, job)

    def shutdown(self) -> None:
        """Stop the process without waiting for a fit that runs."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = None


class WindowEstimator:
    """
    Exact output-error fits on a sliding window of the latest samples, warm-started.

    Parameters
    ----------
    sample_period_s : float
        Sample period of the data fed in [s].
    window_s : float
        Longest window fitted [s]: the window grows from the start (and from a restart after
        a change) up to this length, then slides; gaps do not shorten it.
    refit_interval_s : float
        Data time between refits [s] (stretched to respect ``cpu_budget``).
    min_window_s : float
        Data needed before the first fit [s].
    converged_rel_stderr : float
        Relative standard error every parameter must be below for ``converged``.
    cpu_budget : float
        Largest fraction of one core the refits may take, per second of data.
    load_torque : bool
        Estimate a constant load torque when the window holds both speed signs.
    restart_s : float
        Recent data refitted alone when the window no longer fits (a change inside it) [s];
        0 switches the change-adaptive restart off.
    submit : callable, optional
        ``submit(job) -> Future`` running :func:`refit_window` elsewhere (e.g. a
        :class:`RefitProcess`); without it the refits run inside :meth:`update`.
    initial : dict, optional
        Start of the first fit (e.g. nominal values); default the offline automatic start.

    """

    method = 'window'

    def __init__(self, sample_period_s: float, window_s: float = 30.0,
                 refit_interval_s: float = 2.0, min_window_s: float = 2.0,
                 converged_rel_stderr: float = 0.05, cpu_budget: float = 0.05,
                 load_torque: bool = True, restart_s: float = 5.0,
                 submit: Optional[Callable[[RefitJob], Future]] = None,
                 initial: Optional[Mapping[str, float]] = None) -> None:
        if not sample_period_s > 0:
            raise ValueError('sample_period_s must be positive')
        if not window_s > 0 or not refit_interval_s > 0 or not cpu_budget > 0:
            raise ValueError('window_s, refit_interval_s and cpu_budget must be positive')
        self.sample_period_s = float(sample_period_s)
        self.window_s = float(window_s)
        self.refit_interval_s = float(refit_interval_s)
        self.min_window_s = min(float(min_window_s), self.window_s)
        self.converged_rel_stderr = float(converged_rel_stderr)
        self.cpu_budget = float(cpu_budget)
        self.load_torque = bool(load_torque)
        self.restart_s = float(restart_s)
        self.submit = submit
        self.baseline_window_s = self.window_s
        self._window_n = max(MIN_RUN_SAMPLES, int(round(self.window_s / self.sample_period_s)))
        self._first_initial = dict(initial) if initial else None
        self.reset()

    @classmethod
    def from_options(cls, sample_period_s: float,
                     options: Mapping[str, Any]) -> 'WindowEstimator':
        """
        Build from the node's options (those of the constructor; others are ignored).

        ``in_subprocess`` (without ``submit``) runs the refits in a :class:`RefitProcess`.
        """
        names = ('window_s', 'refit_interval_s', 'min_window_s', 'converged_rel_stderr',
                 'cpu_budget', 'load_torque', 'submit', 'initial')
        chosen = {name: options[name] for name in names if name in options}
        if options.get('in_subprocess') and chosen.get('submit') is None:
            process = RefitProcess()
            process.warm()
            chosen['submit'] = process
        return cls(sample_period_s, **chosen)

    def close(self) -> None:
        """Stop the worker process of the refits, if it has one."""
        shutdown = getattr(self.submit, 'shutdown', None)
        if shutdown is not None:
            shutdown()

    def reset(self) -> None:
        """Forget everything."""
        self._chunks: deque = deque()
        self._buffered = 0
        self._run = 0
        self._since_refit = 0
        self.n_updates = 0
        self.n_refits = 0
        self.n_failures = 0
        self.cpu_s = 0.0
        self._initial = self._first_initial
        self._future: Optional[Future] = None
        self._last: Optional[RefitOutcome] = None
        self._previous: Optional[RefitOutcome] = None
        self._restarted = False
        self._last_cpu_s = 0.0
        self._job_updates = 0
        self._held: deque = deque(maxlen=REFERENCE_FITS)
        self._mismatch_since = math.nan
        self.n_restarts = 0
        self.status = ''

    @property
    def time_s(self) -> float:
        """Return the data time fed so far [s] (gaps not counted)."""
        return self.n_updates * self.sample_period_s

    @property
    def interval_s(self) -> float:
        """Return the data time between refits now [s] (stretched to the CPU budget)."""
        return max(self.refit_interval_s, self._last_cpu_s / self.cpu_budget)

    def break_continuity(self) -> None:
        """Declare a gap: the next sample is not the successor of the last one."""
        self._run += 1

    def update(self, voltage: ArrayLike, current: ArrayLike, speed: ArrayLike) -> int:
        """
        Feed consecutive samples (arrays of equal length, continuing the previous call).

        Samples with a non-finite value are dropped as a gap.  Starts a refit when one is
        due.  Returns the number of samples taken.
        """
        block = np.vstack([np.asarray(values, dtype=float).ravel()
                           for values in (voltage, current, speed)]) \
            if np.ndim(voltage) else None
        if block is None or not np.size(voltage) == np.size(current) == np.size(speed):
            raise ValueError('voltage, current and speed must be arrays of the same length')
        finite = np.all(np.isfinite(block), axis=0)
        taken = 0
        start = 0
        while start < block.shape[1]:
            if not finite[start]:
                self.break_continuity()
                start += 1
                continue
            stop = start + int(np.argmin(finite[start:])) if not finite[start:].all() \
                else block.shape[1]
            self._append(block[:, start:stop])
            taken += stop - start
            start = stop
        self.n_updates += taken
        self._since_refit += taken
        self._maybe_refit()
        return taken

    def _append(self, part: np.ndarray) -> None:
        self._chunks.append((self._run, part.copy()))
        self._buffered += part.shape[1]
        self._trim(self._window_n)

    def _trim(self, keep: int) -> None:
        """Keep the newest ``keep`` samples of the buffer."""
        while self._buffered > keep:
            run, oldest = self._chunks[0]
            excess = self._buffered - keep
            if oldest.shape[1] <= excess:
                self._chunks.popleft()
                self._buffered -= oldest.shape[1]
            else:
                self._chunks[0] = (run, oldest[:, excess:])
                self._buffered -= excess

    def _job(self) -> RefitJob:
        runs: list[list[np.ndarray]] = []
        last_run = None
        for run, part in self._chunks:
            if run != last_run:
                runs.append([])
                last_run = run
            runs[-1].append(part)
        arrays = []
        for parts in runs:
            joined = np.hstack(parts)
            if joined.shape[1] >= MIN_RUN_SAMPLES:
                arrays.append((joined[0].copy(), joined[1].copy(), joined[2].copy()))
        reference = None
        if len(self._held) >= 2:
            reference = {channel: float(np.median([held[channel] for held in self._held]))
                         for channel in self._held[-1]}
        self._job_updates = self.n_updates
        return RefitJob(self.sample_period_s, tuple(arrays),
                        dict(self._initial) if self._initial else None, self.load_torque,
                        self.time_s, reference, min(self.restart_s, 0.5 * self.window_s))

    def _maybe_refit(self) -> None:
        self.poll()
        if self._future is not None:
            return
        if self._since_refit * self.sample_period_s < self.interval_s - 1e-9 or \
                self._buffered * self.sample_period_s < self.min_window_s - 1e-9:
            return
        job = self._job()
        if not job.runs:
            return
        self._since_refit = 0
        if self.submit is None:
            self._accept(refit_window(job))
            return
        try:
            self._future = self.submit(job)
        except Exception as error:  # noqa: BLE001  (report; try again at the next interval)
            self._failed(f'online fit could not start: {type(error).__name__}: {error}')

    def poll(self) -> bool:
        """Take the outcome of a refit that has finished elsewhere; return whether one had."""
        future = self._future
        if future is None or not future.done():
            return False
        self._future = None
        try:
            outcome = future.result()
        except Exception as error:  # noqa: BLE001  (a dead worker: report, carry on)
            self._failed(f'online fit failed: {type(error).__name__}: {error}')
            return True
        self._accept(outcome)
        return True

    def wait(self, timeout_s: Optional[float] = None) -> None:
        """Wait for a refit running elsewhere and take its outcome (tests, benchmarks)."""
        future = self._future
        if future is not None:
            try:
                future.result(timeout=timeout_s)
            except Exception:  # noqa: BLE001  (poll reports it)
                pass
            self.poll()

    def flush(self) -> None:
        """
        Fit the current window here and now (e.g. when the input ends).

        A refit running elsewhere is abandoned; nothing happens without new data since the
        last fit.
        """
        self._future = None
        if self._since_refit == 0 or \
                self._buffered * self.sample_period_s < self.min_window_s - 1e-9:
            return
        job = self._job()
        if job.runs:
            self._since_refit = 0
            self._accept(refit_window(job))

    def _failed(self, message: str) -> None:
        self.n_failures += 1
        self.status = message
        self._initial = self._first_initial

    def _accept(self, outcome: RefitOutcome) -> None:
        self.n_refits += 1
        self.cpu_s += outcome.cpu_s
        self._last_cpu_s = outcome.cpu_s
        if outcome.error:
            self._failed(outcome.error)
            return
        self._previous = self._last
        self._last = outcome
        self.status = ''
        if outcome.restarted_samples:
            self._previous = None  # nothing before the restart to compare with
            self._restarted = True
            # forget what came before the recent data the restart fitted
            self._trim(outcome.restarted_samples + self.n_updates - self._job_updates)
            self.n_restarts += 1
            self._held.clear()
        if outcome.restarted_samples or not outcome.mismatch > MISMATCH:
            self._mismatch_since = math.nan
            if not outcome.restarted_samples:
                self._held.append(dict(outcome.noise_std))
        elif not math.isfinite(self._mismatch_since):
            self._mismatch_since = outcome.time_s
        base = {name: outcome.parameters[name] for name in PARAMETER_NAMES}
        self._initial = base if is_admissible(base) else self._first_initial

    def estimate(self) -> OnlineEstimate:
        """Return the current :class:`OnlineEstimate` (the last successful fit)."""
        self.poll()
        nan = {name: math.nan for name in NAMES}
        last = self._last
        if last is None:
            status = self.status or (
                f'waiting for {self.min_window_s:g} s of data' if self.n_refits == 0
                else 'no fit yet')
            return OnlineEstimate(nan, dict(nan), False, {}, self.n_updates, self.method,
                                  status=status, effects={LOAD_TORQUE: math.nan,
                                                          LOAD_TORQUE + '_stderr': math.nan})
        status = self.status
        age_s = self.time_s - last.time_s
        if not status and age_s > 3.0 * self.interval_s + self.window_s:
            status = f'the last fit is {age_s:.1f} s of data old'
        mismatched = math.isfinite(self._mismatch_since)
        if not status and mismatched:
            status = (f'the model does not hold over the window (simulation error '
                      f'{last.mismatch:.2f} times the noise level): the motor is changing')
        settled = not mismatched or last.time_s - self._mismatch_since >= 0.5 * self.window_s
        converged = not status and is_converged(last.parameters, last.stderr,
                                                self.converged_rel_stderr)
        if not converged and not status:
            status = 'not all parameters determined to the threshold'
        samples = max(last.window_s / self.sample_period_s, 1.0)
        if converged and last.mismatch > 1.0 + CONVERGED_MISMATCH_SIGMAS / math.sqrt(2 * samples):
            converged = False
            status = (f'the simulation error is {last.mismatch:.3f} times the noise level of the '
                      'recent fits: the motor may be changing')
        if converged and self._previous is None and self._restarted:
            # the motor has just changed: a fit of the few seconds since is not trusted alone
            converged = False
            status = 'the window restarted after a change: waiting for a second fit to confirm'
        if converged and self._previous is not None:
            ratios = disagreement(self._previous, last)
            name = max(ratios, key=lambda key: ratios[key])
            if not ratios[name] <= INTERVAL_SIGMAS:
                converged = False
                status = (f'{name} moved {ratios[name]:.1f} standard errors of the difference '
                          'between the last two fits: the motor is drifting')
        rms = {'current': last.noise_std.get('current', math.nan),
               'speed': last.noise_std.get('speed', math.nan)}
        return OnlineEstimate(dict(last.parameters), dict(last.stderr), converged, rms,
                              self.n_updates, self.method, last.time_s, last.window_s,
                              dict(last.effects), status, last.cpu_s, last.torque_rms_Nm,
                              settled)
