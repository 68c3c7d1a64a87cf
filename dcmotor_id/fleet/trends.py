"""
Change alarms across a motor's windows: each parameter's trajectory against its baseline.

:func:`detect_changes` is the one entry point the fleet report calls: a sequence of
``(time, value, stderr)`` per parameter in, alarms out. The rules are those of the
identifier node's online alarms, :class:`dcmotor_id.streaming.monitoring.ChangeDetector` (threshold
in
standard deviations, WARN and ERROR sizes, CUSUM change time, hysteresis); this module only
adapts the history to it, with the detector's two options for separate windows: the baseline
is learned from a parameter's first windows (``baseline_share`` of them, at least
``min_baseline``; their mean, the later windows' standard errors inflated by the excess
scatter of those windows) and an alarm needs ``confirm`` consecutive windows beyond both
thresholds. An alarm, once raised, stays in the report: its "since" and "raised" are those of
the first decision, its level the highest reached, its value the newest window's.

The appearance of effects (:func:`effect_alarms`) and the overview's change score
(:func:`change_score`) are the fleet's own.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Iterable, Mapping, Optional, Sequence

import numpy as np

from dcmotor_id.streaming.monitoring import Alarm, ChangeDetector, LEVELS

__all__ = ['Alarm', 'baseline_size', 'change_score', 'detect_changes', 'DetectorSettings',
           'effect_alarms', 'LEVELS']


@dataclass(frozen=True)
class DetectorSettings:
    """
    Thresholds of :func:`detect_changes` (defaults: those of the node's online alarms).

    Attributes
    ----------
    threshold : float
        ``|z|`` at which a change is significant [standard deviations].
    warn_pct, error_pct : float
        Smallest change of the baseline [%] reported as WARN and as ERROR.
    drift_sigma : float
        CUSUM drift [standard deviations] (change-time estimate).
    baseline_share : float
        Share of the first windows that forms the baseline.
    min_baseline : int
        Fewest baseline windows.
    confirm : int
        Consecutive windows beyond both thresholds before an alarm.

    """

    threshold: float = ChangeDetector.threshold
    warn_pct: float = ChangeDetector.warn_pct
    error_pct: float = ChangeDetector.error_pct
    drift_sigma: float = ChangeDetector.drift_sigma
    baseline_share: float = 0.1
    min_baseline: int = 2
    confirm: int = 2

    def detector(self, baseline_count: int) -> ChangeDetector:
        """Return the node's detector with these thresholds, for windows of a history."""
        return ChangeDetector(self.warn_pct, self.error_pct, self.drift_sigma, self.threshold,
                              confirm=self.confirm, baseline_count=baseline_count)


def baseline_size(count: int, settings: DetectorSettings = DetectorSettings()) -> int:
    """Return how many of ``count`` windows form the baseline."""
    return max(settings.min_baseline, int(math.ceil(settings.baseline_share * count)))


def _one(name: str, points: Sequence[tuple[float, float, float]],
         settings: DetectorSettings) -> Optional[Alarm]:
    """Run the node's detector along one parameter's windows; return its alarm or None."""
    data = sorted(((float(time), float(value), max(float(error), 0.0))
                   for time, value, error in points
                   if math.isfinite(value) and math.isfinite(error)), key=lambda item: item[0])
    size = baseline_size(len(data), settings)
    if len(data) <= size:
        return None
    detector = settings.detector(size)
    level, since, raised = 0, math.nan, math.nan
    for time, value, error in data:
        alarm = detector.observe(name, value, error, time)
        if alarm is None:
            continue
        level = max(level, LEVELS.index(alarm.level))
        if math.isnan(raised):
            since, raised = alarm.since_s, time
    if not level or detector.baseline is None:
        return None
    _, value, error = data[-1]
    z, change = detector.compare(name, value, error)
    return Alarm(name, LEVELS[level], value, detector.baseline.value(name), 100.0 * change,
                 z, since, raised=raised)


def detect_changes(series: Mapping[str, Sequence[tuple[float, float, float]]],
                   settings: DetectorSettings = DetectorSettings()) -> list[Alarm]:
    """
    Find the parameters whose trajectory changed against their baseline.

    Parameters
    ----------
    series : dict
        Parameter name -> ``(time, value, stderr)`` of every window (any time unit, any
        order; non-finite points are skipped).
    settings : DetectorSettings
        Thresholds.

    Returns
    -------
    list of Alarm
        One per changed parameter (at most), in the order of ``series``.

    """
    alarms = []
    for name, points in series.items():
        alarm = _one(name, points, settings)
        if alarm is not None:
            alarms.append(alarm)
    return alarms


def effect_alarms(windows: Iterable[tuple[float, Mapping[str, float]]],
                  settings: DetectorSettings = DetectorSettings()) -> list[Alarm]:
    """
    Find the effects that appeared.

    An effect appeared when it is absent from every baseline window and then found in
    ``confirm`` consecutive windows.

    Parameters
    ----------
    windows : iterable of tuple
        ``(time, {effect name: its first parameter's value})`` per window.
    settings : DetectorSettings
        ``baseline_share``, ``min_baseline`` and ``confirm`` are used.

    """
    ordered = sorted(windows, key=lambda item: item[0])
    size = baseline_size(len(ordered), settings)
    if len(ordered) <= size:
        return []
    before = set().union(*(set(found) for _, found in ordered[:size]))
    later = ordered[size:]
    names = sorted(set().union(*(set(found) for _, found in later)) - before)
    alarms = []
    for name in names:
        run, since, raised = 0, math.nan, math.nan
        for time, found in later:
            run = run + 1 if name in found else 0
            if run == 1:
                start = time
            if run >= settings.confirm and math.isnan(raised):
                since, raised = start, time
        if not math.isnan(raised):
            value = next((found[name] for _, found in reversed(later) if name in found),
                         math.nan)
            alarms.append(Alarm(f'effect {name}', 'WARN', float(value), 0.0, math.nan,
                                math.nan, since, raised=raised))
    return alarms


def change_score(points: Sequence[tuple[float, float, float]],
                 settings: DetectorSettings = DetectorSettings()) -> float:
    """
    Return how much a parameter changed [%].

    The median of its newest windows against the mean of its baseline windows (as many of
    each); NaN with too few windows.
    """
    values = [point[1] for point in sorted(points) if math.isfinite(point[1])]
    size = baseline_size(len(values), settings)
    if len(values) <= size:
        return math.nan
    baseline = float(np.mean(values[:size]))
    recent = float(np.median(values[-size:]))
    return 100.0 * (recent - baseline) / abs(baseline) if baseline else math.nan
