"""
Condition monitoring: change detection on the online estimates against a baseline (no ROS).

Every online estimate (:class:`~dcmotor_id.streaming.online.OnlineEstimate`) is compared with a
baseline (nominal values, the last ``~/identify`` result, or else the first converged online
estimate on a full window), parameter by parameter, in standard deviations of the
difference::

    z = (value - baseline) / sqrt(stderr^2 + baseline_stderr^2)

Each window estimate is itself the generalised likelihood-ratio statistic for "the
parameter now differs from the baseline" (its ``z^2 / 2``), so a change is decided when
``|z| >= threshold`` (default 5 sigma) *and* the change is large enough to matter:
``warn_pct`` of the baseline gives a WARN, ``error_pct`` an ERROR (model errors too small to
matter can be significant with small standard errors; the size gate keeps them quiet).  It
clears with hysteresis, below half of both.  "Since" is the change time estimated by a
two-sided CUSUM on ``z`` (``S+ = max(0, S+ + c (z - k))``, ``S-`` with ``-z``, drift
``k = drift_sigma``): the data time of the first estimate of the excursion that led to the
alarm.  Consecutive window estimates overlap, so each adds only the fraction ``c`` of new
data it holds (time since the previous estimate over the window length).

Two options serve series of separate windows (the fleet's history, :mod:`dcmotor_id.fleet`)
and leave the node's behaviour as it is at their defaults: ``confirm`` consecutive
observations beyond both thresholds before an alarm is raised (default 1), and a baseline
learned from the first ``baseline_count`` observations of each quantity
(:func:`baseline_from_observations`: their mean, with the estimates' standard errors inflated
by the excess scatter of those observations) instead of from one converged estimate.

While a window mixes data from before and after a sudden change, its fit is a compromise that can
move other parameters far (a step of b briefly shows as Coulomb friction); such an estimate is not
``settled`` (:attr:`~dcmotor_id.streaming.online.OnlineEstimate.settled`) and raises no new alarm
until the window restarts after the change or the mismatch has lasted half a window (a slow drift).

Where physics allows, the alarm says what the change probably is: a copper winding's
resistance rises by :data:`COPPER_ALPHA_PER_K` per kelvin, so ``Ra +18 %`` reads "winding
temperature about +46 K"; the other parameters are named for what they are and no more.
A constant load torque (``load_torque_Nm``, baseline zero) is reported in percent of the
baseline Coulomb friction, the torque it is measured against.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone
import math
from typing import Any, Iterable, Mapping, Optional, Sequence

import numpy as np

from dcmotor_id.core.model import is_admissible, PARAMETER_NAMES
from dcmotor_id.streaming.online.window import LOAD_TORQUE

__all__ = ['Alarm', 'alarm_key_values', 'Baseline', 'baseline_from_observations',
           'baseline_from_result', 'ChangeDetector',
           'COPPER_ALPHA_PER_K', 'LEVELS', 'meaning', 'monitor_from_settings',
           'nominal_baseline', 'OnlineMonitor', 'WATCHED']

#: Temperature coefficient of the resistance of annealed copper near 20 degC [1/K].
COPPER_ALPHA_PER_K = 0.00393
#: Alarm levels, as in diagnostic_msgs/DiagnosticStatus.
LEVELS = ('OK', 'WARN', 'ERROR')
#: Quantities watched.
WATCHED = PARAMETER_NAMES + (LOAD_TORQUE,)


@dataclass(frozen=True)
class Baseline:
    """
    What the estimates are compared with.

    Attributes
    ----------
    values, stderr : dict
        The six parameters (and optionally ``load_torque_Nm``, taken as 0 when missing) and
        their standard errors (0 for nominal values).
    source : str
        ``nominal``, ``identify`` or ``online``.
    time_s : float
        Data time at which it was taken (online) or NaN.
    inflation : dict
        Factor on an estimate's standard error per quantity (1 when missing): the excess
        scatter of the observations the baseline was learned from
        (:func:`baseline_from_observations`).

    """

    values: dict
    stderr: dict
    source: str
    time_s: float = math.nan
    inflation: dict = field(default_factory=dict)

    def value(self, name: str) -> float:
        """Return the baseline of ``name`` (load torque: 0 unless given)."""
        return float(self.values.get(name, 0.0 if name == LOAD_TORQUE else math.nan))

    def error(self, name: str) -> float:
        """Return the standard error of the baseline of ``name`` (0 when unknown)."""
        value = float(self.stderr.get(name, 0.0))
        return value if math.isfinite(value) else 0.0

    def factor(self, name: str) -> float:
        """Return the factor on an estimate's standard error of ``name`` (1 unless learned)."""
        value = float(self.inflation.get(name, 1.0))
        return value if math.isfinite(value) and value > 0 else 1.0


def baseline_from_observations(observations: Mapping[str, Sequence[tuple[float, float]]],
                               source: str = 'observations',
                               time_s: float = math.nan) -> Baseline:
    """
    Return the baseline learned from the first observations of each quantity.

    Per quantity, the baseline is the mean of its ``(value, stderr)`` observations. Their
    scatter beyond their standard errors (the Birge ratio, the standard deviation over the
    root mean square standard error, when above 1 and with at least 3 observations) is
    variation that the estimates' standard errors do not cover: it becomes the quantity's
    :attr:`Baseline.inflation`. The baseline's standard error is the larger of the inflated
    root mean square standard error and the scatter, over the square root of the count.

    Parameters
    ----------
    observations : dict
        Quantity -> its ``(value, stderr)`` observations (finite, at least one).
    source, time_s
        As in :class:`Baseline`.

    """
    values, stderr, inflation = {}, {}, {}
    for name, pairs in observations.items():
        data = np.asarray(pairs, dtype=float).reshape(-1, 2)
        count = len(data)
        base_values, base_errors = data[:, 0], np.maximum(data[:, 1], 0.0)
        rms_error = float(np.sqrt(np.mean(base_errors ** 2)))
        scatter = float(np.std(base_values, ddof=1)) if count > 1 else 0.0
        birge = scatter / rms_error if rms_error > 0 else 1.0
        inflation[name] = max(1.0, birge) if count >= 3 else 1.0
        values[name] = float(np.mean(base_values))
        stderr[name] = max(rms_error * inflation[name], scatter) / math.sqrt(count)
    return Baseline(values, stderr, source, time_s, inflation)


@dataclass(frozen=True)
class Alarm:
    """
    A parameter (or an effect) that changed: the node's online alarms and the fleet's trends.

    Attributes
    ----------
    name : str
        Parameter (``Ra`` ... ``Mc``), ``load_torque_Nm``, or ``effect <name>`` (fleet).
    level : str
        ``WARN`` or ``ERROR``.
    value, baseline : float
        Current estimate and baseline (SI units; effects: their first parameter).
    change_pct : float
        Change in percent of the baseline (load torque: of the baseline Coulomb friction;
        effects: NaN).
    sigmas : float
        Change in standard deviations of the difference.
    since_s : float
        Time of the first estimate of the change, in the unit of the times observed: data
        time [s] in the node, UTC [ns] in the fleet's trends.
    meaning : str
        What the change probably is, or ''.
    raised : float
        Time at which the change was decided (same unit), NaN where not tracked (the node).

    """

    name: str
    level: str
    value: float
    baseline: float
    change_pct: float
    sigmas: float
    since_s: float
    meaning: str = ''
    raised: float = math.nan

    def text(self) -> str:
        """One line, e.g. ``Ra +18.0 % (41 sigma) since 34.0 s: winding temperature ...``."""
        if self.name == LOAD_TORQUE:
            head = (f'load torque {self.value:.3g} N m ({self.change_pct:+.1f} % of the '
                    f'Coulomb friction, {self.sigmas:.0f} sigma)')
        else:
            head = f'{self.name} {self.change_pct:+.1f} % ({self.sigmas:+.0f} sigma)'
        text = f'{head} since {self.since_s:.1f} s'
        return f'{text}: {self.meaning}' if self.meaning else text

    def summary(self) -> str:
        """Describe the alarm in a few words, times not included (the fleet report's cells)."""
        if self.name.startswith('effect '):
            return f'{self.name} appeared ({self.value:.3g})'
        return (f'{self.name} {self.change_pct:+.1f} % ({self.sigmas:+.0f} sigma, '
                f'baseline {self.baseline:.4g}, now {self.value:.4g})')


def meaning(name: str, change: float) -> str:
    """
    Return what a relative ``change`` of parameter ``name`` probably is ('' if unknown).

    Only what the physics says: copper's resistance-temperature law for Ra; the other
    parameters are named by what they measure.
    """
    sign = 'up' if change > 0 else 'down'
    if name == 'Ra':
        return f'winding temperature about {change / COPPER_ALPHA_PER_K:+.0f} K (copper)'
    if name == 'CPhi':
        return f'flux {sign} (field current or magnet temperature)'
    if name == 'J':
        return f'inertia {sign}: mass coupled to the shaft changed'
    if name == 'b':
        return f'viscous friction {sign} (bearings, lubrication or a load)'
    if name == 'Mc':
        return f'Coulomb friction {sign} (bearings, brushes, seals or a load)'
    if name == LOAD_TORQUE:
        return 'a constant torque on the shaft (a load)'
    return ''


@dataclass
class _Cusum:
    """The two one-sided statistics of one quantity and where their excursions began."""

    up: float = 0.0
    down: float = 0.0
    up_since: float = math.nan
    down_since: float = math.nan
    active: bool = False
    run: int = 0


@dataclass
class ChangeDetector:
    """
    CUSUM change detection on online estimates against a :class:`Baseline`.

    Parameters
    ----------
    warn_pct, error_pct : float
        Smallest change [%] of the baseline reported as WARN and as ERROR.
    drift_sigma : float
        CUSUM drift ``k`` [standard deviations] (change-time estimate).
    threshold : float
        Decision threshold on ``|z|`` [standard deviations].
    baseline : Baseline, optional
        Without one, the first converged estimate on a full window becomes it.
    min_baseline_window_s : float
        Data an online estimate must rest on to become the baseline [s].
    confirm : int
        Consecutive observations beyond both thresholds before an alarm is raised.
    baseline_count : int
        When above 0 and without a baseline, learn each quantity's baseline from its first
        ``baseline_count`` observations (:func:`baseline_from_observations`) instead of
        taking the first converged estimate.

    """

    warn_pct: float = 5.0
    error_pct: float = 15.0
    drift_sigma: float = 3.0
    threshold: float = 5.0
    baseline: Optional[Baseline] = None
    min_baseline_window_s: float = 0.0
    confirm: int = 1
    baseline_count: int = 0
    alarms: list = field(default_factory=list)
    _stats: dict = field(default_factory=dict)
    _learning: dict = field(default_factory=dict)
    _last_time_s: float = math.nan

    def set_baseline(self, baseline: Optional[Baseline]) -> None:
        """Compare with ``baseline`` from now on (None: learn one); restart the statistics."""
        self.baseline = baseline
        self._stats = {}
        self._learning = {}
        self.alarms = []

    def update(self, estimate: Any) -> list[Alarm]:
        """Take an estimate (once per new fit; repeats are ignored); return the active alarms."""
        time_s = float(estimate.time_s)
        if not math.isfinite(time_s) or time_s == self._last_time_s:
            return self.alarms
        values = estimate.parameters
        if not all(math.isfinite(values.get(name, math.nan)) for name in PARAMETER_NAMES) \
                or not is_admissible(values):
            return self.alarms
        if self.baseline is None and not self.baseline_count:
            if estimate.converged and estimate.window_s >= self.min_baseline_window_s - 1e-9:
                self.set_baseline(Baseline(
                    {name: values[name] for name in PARAMETER_NAMES},
                    {name: estimate.stderr[name] for name in PARAMETER_NAMES}, 'online',
                    time_s))
                self._last_time_s = time_s
            return self.alarms
        previous = self._last_time_s
        self._last_time_s = time_s
        window = estimate.window_s if math.isfinite(estimate.window_s) and \
            estimate.window_s > 0 else 1.0
        weight = 1.0 if not math.isfinite(previous) else \
            min(1.0, max(time_s - previous, 0.0) / window)
        quantities = dict(values)
        stderrs = dict(estimate.stderr)
        for key, number in (estimate.effects or {}).items():
            (stderrs if key.endswith('_stderr') else quantities)[
                key[:-len('_stderr')] if key.endswith('_stderr') else key] = number
        alarms = []
        settled = bool(getattr(estimate, 'settled', True))
        for name in WATCHED:
            alarm = self.observe(name, quantities.get(name, math.nan),
                                 stderrs.get(name, math.nan), time_s, weight, settled)
            if alarm is not None:
                alarms.append(alarm)
        self.alarms = alarms
        return alarms

    def compare(self, name: str, value: float, stderr: float) -> tuple[float, float]:
        """
        Return ``z`` and the relative change of a value of ``name`` against the baseline.

        The change is relative to the baseline (load torque: to the baseline Coulomb
        friction); both are NaN when there is nothing to compare with.
        """
        base = self.baseline.value(name) if self.baseline is not None else math.nan
        if not (math.isfinite(value) and math.isfinite(stderr) and math.isfinite(base)):
            return math.nan, math.nan
        assert self.baseline is not None
        spread = math.hypot(stderr * self.baseline.factor(name), self.baseline.error(name))
        if spread <= 0:
            return math.nan, math.nan
        if name == LOAD_TORQUE:
            scale = self.baseline.value('Mc')
            change = (value - base) / scale if scale > 0 else math.inf
        else:
            change = (value - base) / abs(base) if base else math.inf
        return (value - base) / spread, change

    def observe(self, name: str, value: float, stderr: float, time_s: float,
                weight: float = 1.0, settled: bool = True) -> Optional[Alarm]:
        """
        Take one observation of one quantity; return its alarm or None.

        Parameters
        ----------
        name : str
            Quantity (:data:`WATCHED`, or any name with a baseline).
        value, stderr : float
            The estimate and its standard error (non-finite: ignored).
        time_s : float
            Its time (any unit; the alarm's ``since_s`` is in the same unit).
        weight : float
            Fraction of new data it holds (CUSUM step; 1 for separate windows).
        settled : bool
            False for a fit that mixes data from before and after a change.

        """
        if self.baseline_count and (self.baseline is None or name not in self.baseline.values):
            self._learn(name, value, stderr, time_s)
            return None
        if self.baseline is None:
            return None
        stat = self._stats.setdefault(name, _Cusum())
        z, change = self.compare(name, value, stderr)
        if not math.isfinite(z):
            return None
        base = self.baseline.value(name)
        for side, direction in (('up', 1.0), ('down', -1.0)):
            before = getattr(stat, side)
            after = min(10.0 * self.threshold,
                        max(0.0, before + weight * (direction * z - self.drift_sigma)))
            setattr(stat, side, after)
            if after > 0 and before == 0:
                setattr(stat, side + '_since', time_s)
        size = abs(change) * 100.0
        if not stat.active and not settled:
            return None  # a window mixing before and after a change: wait (see module text)
        beyond = abs(z) >= self.threshold and size >= self.warn_pct
        stat.run = stat.run + 1 if beyond else 0
        if stat.active:  # hysteresis: clears below half of both thresholds
            stat.active = abs(z) >= 0.5 * self.threshold and size >= 0.5 * self.warn_pct
        else:
            stat.active = beyond and stat.run >= self.confirm
        if not stat.active:
            return None
        level = 'ERROR' if size >= self.error_pct else 'WARN'
        since = stat.up_since if z > 0 else stat.down_since
        if not math.isfinite(since):
            since = time_s
        return Alarm(name, level, value, base, 100.0 * change, z, since, meaning(name, change))

    def _learn(self, name: str, value: float, stderr: float, time_s: float) -> None:
        """Collect the first observations of ``name``; with enough, add its baseline."""
        if not (math.isfinite(value) and math.isfinite(stderr)):
            return
        pairs = self._learning.setdefault(name, [])
        pairs.append((value, stderr))
        if len(pairs) < self.baseline_count:
            return
        learned = baseline_from_observations({name: pairs}, 'observations', time_s)
        old = self.baseline
        self.baseline = learned if old is None else Baseline(
            {**old.values, **learned.values}, {**old.stderr, **learned.stderr}, old.source,
            old.time_s, {**old.inflation, **learned.inflation})


def alarm_key_values(alarms: Iterable[Alarm], baseline: Optional[Baseline],
                     clock: Optional[tuple[float, float]] = None) -> list[tuple[str, str]]:
    """
    Return the key-values of the alarms.

    ``alarm_level``, ``alarms`` (their texts), ``baseline`` and per alarm
    ``alarm.<name>.level``, ``.change_pct``, ``.sigmas``, ``.since_s`` (data time),
    ``.value``, ``.baseline`` and ``.meaning``; with ``clock = (wall_now_s, data_now_s)``
    also ``.since`` (UTC wall time, ISO 8601).
    """
    alarms = list(alarms)
    level = max((LEVELS.index(alarm.level) for alarm in alarms), default=0)
    pairs = [('alarm_level', LEVELS[level]),
             ('alarms', '; '.join(alarm.text() for alarm in alarms)),
             ('baseline', baseline.source if baseline is not None else 'none yet')]
    for alarm in alarms:
        prefix = f'alarm.{alarm.name}.'
        pairs += [(prefix + 'level', alarm.level),
                  (prefix + 'change_pct', f'{alarm.change_pct:.6g}'),
                  (prefix + 'sigmas', f'{alarm.sigmas:.6g}'),
                  (prefix + 'since_s', f'{alarm.since_s:.6g}'),
                  (prefix + 'value', repr(alarm.value)),
                  (prefix + 'baseline', repr(alarm.baseline)),
                  (prefix + 'meaning', alarm.meaning)]
        if clock is not None:
            wall = clock[0] - (clock[1] - alarm.since_s)
            pairs.append((prefix + 'since', datetime.fromtimestamp(
                wall, timezone.utc).isoformat(timespec='seconds')))
    return pairs


def baseline_from_result(result: Mapping[str, Any]) -> Baseline:
    """Return the baseline of an ``~/identify`` result (its parameters and stderr)."""
    return Baseline({name: float(result['parameters'][name]) for name in PARAMETER_NAMES},
                    {name: float(result['stderr'].get(name, 0.0)) for name in PARAMETER_NAMES},
                    'identify')


def nominal_baseline(values: Mapping[str, float]) -> Optional[Baseline]:
    """Return a baseline of nominal values, or None unless all six are positive (b, Mc >= 0)."""
    picked = {name: float(values.get(name, 0.0)) for name in PARAMETER_NAMES}
    if not is_admissible(picked) or not all(math.isfinite(v) for v in picked.values()):
        return None
    return Baseline(picked, dict.fromkeys(PARAMETER_NAMES, 0.0), 'nominal')


class OnlineMonitor:
    """
    The identifier node's online side without ROS: estimator, change detector, baseline.

    Parameters
    ----------
    estimator : OnlineEstimator
        The online estimator (:func:`dcmotor_id.streaming.online.make_estimator`).
    detector : ChangeDetector, optional
        None switches monitoring off.
    baseline_mode : str
        ``auto`` (nominal if given, else the last ``~/identify`` result, else learned
        online), ``nominal``, ``identify`` or ``online``.
    nominal : Baseline, optional
        Nominal values (:func:`nominal_baseline`).

    """

    def __init__(self, estimator: Any, detector: Optional[ChangeDetector] = None,
                 baseline_mode: str = 'auto', nominal: Optional[Baseline] = None) -> None:
        self.estimator = estimator
        self.detector = detector
        self.baseline_mode = baseline_mode
        self.nominal = nominal
        self.error = ''
        if detector is not None and nominal is not None and baseline_mode in ('auto',
                                                                              'nominal'):
            detector.set_baseline(nominal)

    def update(self, voltage: Any, current: Any, speed: Any) -> str:
        """Feed samples; return '' or why they were refused (never raises)."""
        try:
            self.estimator.update(voltage, current, speed)
            self.error = ''
        except Exception as error:  # noqa: BLE001  (bad samples must not stop the node)
            self.error = f'online update failed: {type(error).__name__}: {error}'
        return self.error

    def break_continuity(self) -> None:
        """Declare a gap in the samples."""
        self.estimator.break_continuity()

    def feed(self, run: Any, electrical: bool = True) -> str:
        """
        Feed a run of aligned samples (a windowing ``Run``); return :meth:`update`.

        A run ``after_gap`` breaks the continuity first; its columns are voltage, current and
        speed. Without ``electrical`` (mechanical-only input, no voltage) nothing is estimated.
        """
        if run.after_gap:
            self.break_continuity()
        if not electrical:
            return ''
        return self.update(run.values[:, 0], run.values[:, 1], run.values[:, 2])

    def identified(self, result: Mapping[str, Any]) -> bool:
        """Take an ``~/identify`` result as the baseline if the mode says so; return whether."""
        if self.detector is None or self.baseline_mode not in ('auto', 'identify'):
            return False
        if self.baseline_mode == 'auto' and self.nominal is not None:
            return False
        try:
            baseline = baseline_from_result(result)
        except (KeyError, TypeError, ValueError):
            return False
        if not is_admissible(baseline.values):
            return False
        self.detector.set_baseline(baseline)
        return True

    def snapshot(self) -> tuple[Any, list[Alarm]]:
        """Return the current estimate and the active alarms (updating the detector)."""
        estimate = self.estimator.estimate()
        if self.detector is None:
            return estimate, []
        if self.baseline_mode == 'identify' and (self.detector.baseline is None or
                                                 self.detector.baseline.source != 'identify'):
            return estimate, []  # waits for ~/identify, learns nothing meanwhile
        return estimate, list(self.detector.update(estimate))

    def condition(self, alarms: Sequence[Alarm], wall_now_s: Optional[float] = None
                  ) -> tuple[str, str, list[tuple[str, str]]]:
        """Return the level, message and key-values of the condition status."""
        baseline = self.detector.baseline if self.detector is not None else None
        clock = None if wall_now_s is None else (wall_now_s, self.estimator.time_s)
        pairs = alarm_key_values(alarms, baseline, clock)
        level = pairs[0][1]
        if alarms:
            message = '; '.join(alarm.text() for alarm in alarms)
        elif self.detector is None:
            message = 'monitoring off'
        elif baseline is None:
            message = 'no baseline yet (waiting for a converged estimate or ~/identify)'
        else:
            message = f'no change against the {baseline.source} baseline'
        return level, message, pairs

    def close(self) -> None:
        """Use the samples the estimator still buffers, then release its worker."""
        self.estimator.flush()
        self.estimator.close()


def monitor_from_settings(settings: Any, sample_rate_hz: float) -> OnlineMonitor:
    """
    Build the identifier node's :class:`OnlineMonitor` from its settings.

    ``settings`` has the ``online_*``, ``monitor*`` and ``nominal_*`` fields of
    :class:`dcmotor_id.nodes.settings.IdentifierSettings`.
    """
    from dcmotor_id.streaming.online import make_estimator
    estimator = make_estimator(
        settings.online_method, 1.0 / sample_rate_hz, memory_s=settings.online_memory_s,
        converged_rel_stderr=settings.online_converged_rel_stderr,
        window_s=settings.online_window_s, refit_interval_s=settings.online_refit_interval_s,
        cpu_budget=settings.online_cpu_budget, load_torque=settings.online_load_torque,
        in_subprocess=settings.online_in_subprocess)
    detector = None
    if settings.monitor:
        detector = ChangeDetector(settings.monitor_warn_pct, settings.monitor_error_pct,
                                  threshold=settings.monitor_threshold_sigma,
                                  min_baseline_window_s=estimator.baseline_window_s)
    nominal = nominal_baseline({name: getattr(settings, f'nominal_{name}')
                                for name in PARAMETER_NAMES})
    if settings.monitor_baseline == 'nominal' and nominal is None and settings.monitor:
        raise ValueError('monitor_baseline is nominal: give nominal_Ra, nominal_La, '
                         'nominal_CPhi and nominal_J (> 0)')
    return OnlineMonitor(estimator, detector, settings.monitor_baseline, nominal)
