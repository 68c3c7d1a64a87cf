"""
Change alarms across a motor's windows: each parameter's trajectory against its baseline.

:func:`detect_changes` is the one entry point the fleet report calls: a sequence of
``(time, value, stderr)`` per parameter in, alarms out. It applies the rules of the
identifier node's online alarms (the same thresholds and CUSUM change-time estimate) to the
windows of the history; it is kept behind this one function so that it can be switched to
the node's detector (``dcmotor_id.monitoring``) without touching the report.

The baseline of a parameter is the mean of its first windows (``baseline_share`` of them, at
least ``min_baseline``). Every later window is compared with it in standard deviations of
the difference, ``z = (value - baseline) / sqrt(s^2 + s_b^2)``, where a window's standard
error ``s`` is inflated by the baseline's excess scatter (the Birge ratio of the baseline
windows, when above 1: variation from one recording to the next that the fit's errors do not
cover). A change is decided when ``|z| >= threshold`` and the change is at least ``warn_pct``
of the baseline (``error_pct``: level ERROR) in ``confirm`` consecutive windows; its "since"
is the start of the CUSUM excursion (drift ``drift_sigma``) that led to it.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Iterable, Mapping, Optional, Sequence

import numpy as np

#: Alarm levels, as in diagnostic_msgs/DiagnosticStatus.
LEVELS = ('OK', 'WARN', 'ERROR')


@dataclass(frozen=True)
class Alarm:
    """
    A parameter (or an effect) that changed.

    Attributes
    ----------
    name : str
        Parameter name, or ``effect <name>``.
    level : str
        ``WARN`` or ``ERROR``.
    value, baseline : float
        Value at the newest window and the baseline (effects: their first parameter).
    change_pct : float
        Change at the newest window in percent of the baseline (effects: NaN).
    sigmas : float
        Change at the newest window in standard deviations of the difference.
    since : float
        Time of the first window of the change (the input's time unit).
    raised : float
        Time of the window at which the change was decided.

    """

    name: str
    level: str
    value: float
    baseline: float
    change_pct: float
    sigmas: float
    since: float
    raised: float

    def text(self) -> str:
        """Describe the alarm in a few words (times not included)."""
        if self.name.startswith('effect '):
            return f'{self.name} appeared ({self.value:.3g})'
        return (f'{self.name} {self.change_pct:+.1f} % ({self.sigmas:+.0f} sigma, '
                f'baseline {self.baseline:.4g}, now {self.value:.4g})')


@dataclass(frozen=True)
class DetectorSettings:
    """
    Thresholds of :func:`detect_changes` (defaults: the node's online alarms).

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

    threshold: float = 5.0
    warn_pct: float = 5.0
    error_pct: float = 15.0
    drift_sigma: float = 3.0
    baseline_share: float = 0.1
    min_baseline: int = 2
    confirm: int = 2


def baseline_size(count: int, settings: DetectorSettings = DetectorSettings()) -> int:
    """Return how many of ``count`` windows form the baseline."""
    return max(settings.min_baseline, int(math.ceil(settings.baseline_share * count)))


def _one(name: str, points: Sequence[tuple[float, float, float]],
         settings: DetectorSettings) -> Optional[Alarm]:
    data = np.array([point for point in points
                     if math.isfinite(point[1]) and math.isfinite(point[2])], dtype=float)
    if data.size == 0:
        return None
    data = data[np.argsort(data[:, 0], kind='stable')]
    size = baseline_size(len(data), settings)
    if len(data) <= size:
        return None
    times, values, errors = data[:, 0], data[:, 1], np.maximum(data[:, 2], 0.0)
    base_values, base_errors = values[:size], errors[:size]
    baseline = float(np.mean(base_values))
    rms_error = float(np.sqrt(np.mean(base_errors ** 2)))
    scatter = float(np.std(base_values, ddof=1)) if size > 1 else 0.0
    birge = scatter / rms_error if rms_error > 0 else 1.0
    inflation = max(1.0, birge) if size >= 3 else 1.0
    base_error = max(rms_error * inflation, scatter) / math.sqrt(size)
    up = down = 0.0
    up_since = down_since = math.nan
    run, level, raised, since = 0, 0, math.nan, math.nan
    for time, value, error in zip(times[size:], values[size:], errors[size:]):
        spread = math.hypot(error * inflation, base_error)
        z = (value - baseline) / spread if spread > 0 else math.copysign(math.inf,
                                                                         value - baseline)
        up, up_since = (max(0.0, up + z - settings.drift_sigma),
                        up_since if up > 0 else time)
        down, down_since = (max(0.0, down - z - settings.drift_sigma),
                            down_since if down > 0 else time)
        change = 100.0 * (value - baseline) / abs(baseline) if baseline else math.inf
        beyond = abs(z) >= settings.threshold and abs(change) >= settings.warn_pct
        run = run + 1 if beyond else 0
        if run >= settings.confirm:
            level = max(level, 2 if abs(change) >= settings.error_pct else 1)
            if math.isnan(raised):
                raised = time
                since = up_since if z > 0 else down_since
    if not level:
        return None
    last_spread = math.hypot(errors[-1] * inflation, base_error)
    last_z = (values[-1] - baseline) / last_spread if last_spread > 0 else math.inf
    return Alarm(name, LEVELS[level], float(values[-1]), baseline,
                 100.0 * (values[-1] - baseline) / abs(baseline) if baseline else math.inf,
                 float(last_z), float(since), float(raised))


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
                                math.nan, since, raised))
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
