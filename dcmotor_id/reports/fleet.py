"""
The fleet report: an HTML page of a fleet history (``dcmotor-id fleet-report``).

What a fleet engineer needs to see which motors are changing, on one page:

* the fleet overview table, sorted by how much each motor has changed (the largest change of
  a parameter between its baseline windows and its newest ones), with its alarms, effects
  and failures, and a bar chart of the most changed motors;
* per motor, the trend of every parameter over time with its 95 % band
  (``value +/- 1.96 stderr``), the baseline, where a change alarm was decided and since when
  (:mod:`dcmotor_id.fleet.trends`), the effects found window by window, the held-out
  simulation error, and the recordings that failed with their messages.

Plots use matplotlib's object interface with the Agg canvas (no display, no global state).
"""

from __future__ import annotations

import datetime
import hashlib
import html
import json
import math
import os
import re
from typing import Any, Mapping, Sequence

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

from dcmotor_id.core.model import PARAMETER_NAMES, UNITS
from dcmotor_id.fleet.history import read_history
from dcmotor_id.fleet.trends import (Alarm, baseline_size, change_score, detect_changes,
                                     DetectorSettings, effect_alarms)

#: z of the two-sided 95 % band.
Z95 = 1.959964
_LEVEL_COLOURS = {'ERROR': '#d62728', 'WARN': '#ff7f0e', 'OK': '#2ca02c'}


def _time(stamp_ns: float) -> datetime.datetime:
    return datetime.datetime.fromtimestamp(stamp_ns * 1e-9, datetime.timezone.utc)


def _when(stamp_ns: float) -> str:
    if not math.isfinite(stamp_ns):
        return ''
    return _time(stamp_ns).strftime('%Y-%m-%d %H:%M:%S')


def _float(value: Any) -> float:
    return float(value) if value is not None else math.nan


#: Largest magnitude of a parameter or standard error a report plots: beyond it a row is
#: corrupt (a history part written by hand, a fit gone wrong) and listed as failed.
ABSURD_MAGNITUDE = 1e30


def _flag_absurd(row: Mapping[str, Any]) -> Mapping[str, Any]:
    """
    Return an ``ok`` row whose values no motor has (Ra NaN, J -1e308) as a failed row.

    Its error names the values; the motor's other windows and the other motors are reported.
    """
    if row.get('status') != 'ok':
        return row
    bad = []
    needed = ('J', 'b', 'Mc') if row.get('mode') == 'mechanical' else PARAMETER_NAMES
    for name in PARAMETER_NAMES:
        value, stderr = _float(row.get(name)), _float(row.get(f'{name}_stderr'))
        if math.isnan(value) and name not in needed:
            continue  # not identified in the mechanical-only mode
        positive = name in ('Ra', 'La', 'CPhi', 'J')
        if not (math.isfinite(value) and abs(value) < ABSURD_MAGNITUDE) or \
                (positive and value <= 0) or value < 0 or abs(stderr) >= ABSURD_MAGNITUDE:
            spread = f' +- {stderr:.3g}' if math.isfinite(stderr) and stderr else ''
            bad.append(f'{name} {value:.3g}{spread}')
    if not math.isfinite(_float(row.get('window_start_ns'))):
        bad.append(f"window_start_ns {row.get('window_start_ns')}")
    if not bad:
        return row
    return {**row, 'status': 'absurd', 'error': f'absurd values, not plotted: {", ".join(bad)}'}


class MotorTrend:
    """
    One motor's windows from the history, and what the report says about them.

    Parameters
    ----------
    motor_id : str
        The motor.
    rows : list of dict
        Its history rows (any order).
    settings : DetectorSettings
        Thresholds of the change alarms.

    """

    def __init__(self, motor_id: str, rows: Sequence[Mapping[str, Any]],
                 settings: DetectorSettings = DetectorSettings()) -> None:
        self.motor_id = motor_id
        rows = [_flag_absurd(row) for row in rows]
        self.failed = [row for row in rows if row.get('status') != 'ok']
        self.rows = sorted((row for row in rows if row.get('status') == 'ok'),
                           key=lambda row: (row['window_start_ns'], row['source_bag']))
        self.parameters = [name for name in PARAMETER_NAMES
                           if any(math.isfinite(_float(row.get(name))) for row in self.rows)]
        self.series = {name: [(float(row['window_start_ns']), _float(row.get(name)),
                               _float(row.get(f'{name}_stderr'))) for row in self.rows]
                       for name in self.parameters}
        self.effects = [(float(row['window_start_ns']), _effect_values(row.get('effects')))
                        for row in self.rows]
        self.alarms: list[Alarm] = detect_changes(self.series, settings) + \
            effect_alarms(self.effects, settings)
        self.baseline_windows = baseline_size(len(self.rows), settings)
        scores = {name: change_score(points, settings) for name, points in self.series.items()}
        finite = {name: value for name, value in scores.items() if math.isfinite(value)}
        self.largest = max(finite.items(), key=lambda item: abs(item[1]), default=('', math.nan))

    @property
    def level(self) -> str:
        """Return the highest level of the alarms, or ``OK`` when there are none."""
        levels = [alarm.level for alarm in self.alarms]
        return 'ERROR' if 'ERROR' in levels else 'WARN' if levels else 'OK'

    @property
    def score(self) -> float:
        """Return the largest change of a parameter [%] in magnitude (0 when unknown)."""
        value = abs(self.largest[1])
        return value if math.isfinite(value) else 0.0

    def effect_counts(self) -> dict[str, int]:
        """Return the windows in which each effect was found."""
        counts: dict[str, int] = {}
        for _, found in self.effects:
            for name in found:
                counts[name] = counts.get(name, 0) + 1
        return counts


def _effect_values(effects: Any) -> dict[str, float]:
    """Effect name -> the value of its first numeric parameter (NaN if none)."""
    out = {}
    for effect in effects or []:
        try:
            parameters = json.loads(effect.get('parameters') or '{}')
        except ValueError:
            parameters = {}
        numbers = [value for value in parameters.values() if isinstance(value, (int, float))]
        out[str(effect.get('name'))] = float(numbers[0]) if numbers else math.nan
    return out


def _save(figure: Figure, directory: str, name: str) -> str:
    FigureCanvasAgg(figure)
    figure.savefig(os.path.join(directory, name), dpi=90, bbox_inches='tight')
    return name


def plot_motor(trend: MotorTrend, directory: str, name: str) -> str:
    """Plot a motor's parameter trends, effects and simulation error; return the file name."""
    panels = len(trend.parameters) + 2
    columns = 2
    rows = int(math.ceil(panels / columns))
    figure = Figure(figsize=(11, 2.4 * rows))
    axes = figure.subplots(rows, columns, sharex=True, squeeze=False).ravel()
    times = [_time(row['window_start_ns']) for row in trend.rows]
    alarms = {alarm.name: alarm for alarm in trend.alarms}
    for axis, parameter in zip(axes, trend.parameters):
        _parameter_axis(axis, trend, parameter, times, alarms)
    if trend.parameters:
        axes[0].legend(fontsize=7, loc='best')
    _effects_axis(axes[len(trend.parameters)], trend, times, alarms)
    _error_axis(axes[len(trend.parameters) + 1], trend, times)
    for axis in axes[panels:]:
        axis.set_visible(False)
    for axis in axes:
        for label in axis.get_xticklabels():
            label.set_rotation(20)
            label.set_fontsize(8)
    figure.suptitle(f'motor {trend.motor_id}: {len(trend.rows)} windows, '
                    f'{len(trend.failed)} failed, alarms: {trend.level}', fontsize=12)
    figure.tight_layout()
    return _save(figure, directory, name)


def _parameter_axis(axis: Any, trend: MotorTrend, parameter: str, times: list,
                    alarms: dict[str, Any]) -> None:
    """Draw a parameter's windows with their 95 % band, the baseline and its alarm."""
    base = trend.baseline_windows
    points = trend.series[parameter]
    values = np.array([point[1] for point in points])
    band = Z95 * np.nan_to_num(np.array([point[2] for point in points]), nan=0.0)
    axis.fill_between(times, values - band, values + band, color='#9ecae1', alpha=0.6,
                      step=None, label='95 % band', linewidth=0)
    axis.errorbar(times, values, yerr=band, fmt='o', markersize=3, color='#1f77b4',
                  ecolor='#1f77b4', elinewidth=0.8, capsize=2, label='window')
    if len(values) > base:
        reference = float(np.nanmean(values[:base]))
        axis.axhline(reference, color='0.4', linestyle='--', linewidth=0.8,
                     label='baseline')
        axis.axvspan(times[0], times[base - 1], color='0.9', zorder=0)
    title = f'{parameter} [{UNITS.get(parameter, "")}]'
    alarm = alarms.get(parameter)
    if alarm is not None:
        colour = _LEVEL_COLOURS[alarm.level]
        axis.axvline(_time(alarm.raised), color=colour, linewidth=1.5,
                     label=f'{alarm.level} decided')
        if math.isfinite(alarm.since_s) and alarm.since_s != alarm.raised:
            axis.axvline(_time(alarm.since_s), color=colour, linewidth=1.0, linestyle=':',
                         label='since')
        title += f'   {alarm.level} {alarm.change_pct:+.1f} %'
        axis.set_title(title, color=colour, fontsize=10, fontweight='bold')
    else:
        axis.set_title(title, fontsize=10)
    axis.grid(alpha=0.3)
    axis.ticklabel_format(axis='y', style='sci', scilimits=(-3, 4), useOffset=False)


def _effects_axis(effect_axis: Any, trend: MotorTrend, times: list,
                  alarms: dict[str, Any]) -> None:
    """Draw the effects found per window (an appeared effect's alarm in orange)."""
    names = sorted({name for _, found in trend.effects for name in found})
    for position, effect in enumerate(names):
        found_times = [time for time, (_, found) in zip(times, trend.effects)
                       if effect in found]
        effect_alarm = alarms.get(f'effect {effect}')
        colour = _LEVEL_COLOURS['WARN'] if effect_alarm else '#1f77b4'
        effect_axis.plot(found_times, [position] * len(found_times), 's', color=colour,
                         markersize=5)
    effect_axis.set_yticks(range(len(names)), names or [])
    effect_axis.set_ylim(-0.7, max(len(names), 1) - 0.3)
    appeared = any(alarm.name.startswith('effect ') for alarm in trend.alarms)
    effect_axis.set_title('effects found per window' + ('' if names else ': none')
                          + (' (orange: appeared, an alarm)' if appeared else ''), fontsize=10)
    effect_axis.grid(alpha=0.3)


def _error_axis(error_axis: Any, trend: MotorTrend, times: list) -> None:
    """Draw the held-out simulation errors of the base and final models."""
    for key, label, colour in (('error_before', 'base model', '#d62728'),
                               ('error_after', 'final model', '#1f77b4')):
        for channel, marker in (('current', 'o'), ('speed', '^')):
            errors = [_float(row.get(f'{key}_{channel}_nrmse_pct')) for row in trend.rows]
            if any(math.isfinite(value) for value in errors):
                error_axis.plot(times, errors, marker, color=colour, markersize=3,
                                label=f'{channel}, {label}')
    error_axis.set_title('held-out simulation error [% of std]', fontsize=10)
    error_axis.legend(fontsize=7, loc='best')
    error_axis.grid(alpha=0.3)


def plot_overview(trends: Sequence[MotorTrend], directory: str, limit: int = 30) -> str:
    """Bar chart of the most changed motors' largest parameter change; return the file name."""
    shown = list(trends)[:limit]
    figure = Figure(figsize=(9, 0.28 * max(len(shown), 4) + 1.2))
    axis = figure.subplots()
    labels = [f'{trend.motor_id} ({trend.largest[0] or "-"})' for trend in shown]
    values = [trend.largest[1] if math.isfinite(trend.largest[1]) else 0.0 for trend in shown]
    colours = [_LEVEL_COLOURS[trend.level] for trend in shown]
    positions = np.arange(len(shown))[::-1]
    axis.barh(positions, values, color=colours)
    axis.set_yticks(positions, labels, fontsize=8)
    axis.axvline(0.0, color='0.3', linewidth=0.8)
    axis.set_xlabel('largest parameter change, newest windows vs baseline [%]')
    axis.set_title(f'fleet: the {len(shown)} most changed of {len(trends)} motors '
                   '(red: ERROR, orange: WARN, green: no alarm)', fontsize=10)
    axis.grid(axis='x', alpha=0.3)
    figure.tight_layout()
    return _save(figure, directory, 'overview.png')


def _cell(text: Any) -> str:
    return f'<td>{html.escape(str(text))}</td>'


def _safe_name(motor_id: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', motor_id) or 'motor'


def unique_names(motor_ids: Sequence[str]) -> dict[str, str]:
    """
    Map motor ids to file and anchor names that never collide.

    The safe name of an id (``site/m1`` -> ``site_m1``) is kept while no other id shares it,
    ignoring case (file systems that fold case); the ids that share one each get a digest of
    the id appended, so ``cell/7`` and ``cell_7`` get two plots, not one.
    """
    safe = {motor: _safe_name(motor) for motor in motor_ids}
    folded: dict[str, int] = {}
    for name in safe.values():
        folded[name.lower()] = folded.get(name.lower(), 0) + 1
    return {motor: name if folded[name.lower()] == 1 else
            f'{name}-{hashlib.sha1(motor.encode()).hexdigest()[:8]}'
            for motor, name in safe.items()}


def motor_trends(history_dir: str, settings: DetectorSettings = DetectorSettings()
                 ) -> tuple[list[MotorTrend], list[dict[str, Any]]]:
    """
    Read the history; return the motors' trends (the most changed first) and orphan errors.

    The orphan errors are the rows of recordings in which no motor could be told (bags that
    could not be read).
    """
    table = read_history(history_dir)
    by_motor: dict[str, list[dict[str, Any]]] = {}
    unassigned = []
    for row in table.to_pylist():
        if row.get('motor_id'):
            by_motor.setdefault(row['motor_id'], []).append(row)
        else:
            unassigned.append(row)
    trends = [MotorTrend(motor, rows, settings) for motor, rows in by_motor.items()]
    order = {'ERROR': 0, 'WARN': 1, 'OK': 2}
    trends.sort(key=lambda trend: (-trend.score, order[trend.level], trend.motor_id))
    return trends, unassigned


def write_fleet_report(history_dir: str, directory: str,
                       settings: DetectorSettings = DetectorSettings()) -> str:
    """
    Write ``index.html`` with the fleet overview and every motor's trends; return its path.

    Parameters
    ----------
    history_dir : str
        The fleet history (``dcmotor-id fleet --history``).
    directory : str
        Where the page and its PNGs go (created).
    settings : DetectorSettings
        Thresholds of the change alarms.

    """
    from dcmotor_id.core.errors import InputDataError
    trends, unassigned = motor_trends(history_dir, settings)
    if not trends and not unassigned:
        raise InputDataError(f'{history_dir}: no fleet history here (no part-*.parquet '
                             'files); run dcmotor-id fleet --history first')
    os.makedirs(directory, exist_ok=True)
    overview = plot_overview(trends, directory)
    parts = _fleet_head(trends, unassigned, history_dir, settings, overview)
    names = unique_names([trend.motor_id for trend in trends])
    parts += [_overview_row(trend, names[trend.motor_id]) for trend in trends]
    parts.append('</table>')
    if unassigned:
        parts.append('<h2>Recordings that could not be read</h2><ul>' + ''.join(
            f'<li>{html.escape(row.get("source_bag") or "")}: '
            f'{html.escape(row.get("error") or "")}</li>' for row in unassigned) + '</ul>')
    for trend in trends:
        parts += _motor_parts(trend, names[trend.motor_id], directory)
    parts.append('</body></html>')
    page = os.path.join(directory, 'index.html')
    with open(page, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(parts))
    return page


def _fleet_head(trends: Sequence[MotorTrend], unassigned: Sequence[Mapping[str, Any]],
                history_dir: str, settings: DetectorSettings, overview: str) -> list[str]:
    """Return the page's head: the counts, the alarm rule, the overview and its table head."""
    alarmed = sum(trend.level != 'OK' for trend in trends)
    windows = sum(len(trend.rows) for trend in trends)
    failures = sum(len(trend.failed) for trend in trends) + len(unassigned)
    return [
        '<!DOCTYPE html><html><head><meta charset="utf-8"><title>dcmotor_id fleet report'
        '</title><style>body{font-family:sans-serif;max-width:1200px;margin:auto}'
        'table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;'
        'padding:3px 6px;text-align:left}.ERROR{color:#d62728;font-weight:bold}'
        '.WARN{color:#ff7f0e;font-weight:bold}.OK{color:#2ca02c}</style></head><body>',
        '<h1>Fleet report</h1>',
        f'<p>{len(trends)} motors, {windows} windows identified, {failures} failures; '
        f'<b>{alarmed} motors with change alarms</b>. History: '
        f'{html.escape(os.path.abspath(history_dir))}.</p>',
        '<p>A parameter alarms when it differs from its baseline (the mean of a motor&#39;s '
        f'first {settings.baseline_share:.0%} of windows, at least {settings.min_baseline}) '
        f'by at least {settings.threshold:g} standard deviations and {settings.warn_pct:g} % '
        f'(ERROR from {settings.error_pct:g} %) in {settings.confirm} consecutive windows; an '
        'effect alarms when it appears in that many consecutive windows after a baseline '
        'without it. "Change" is the median of the newest windows against the baseline.</p>',
        f'<img src="{overview}" alt="most changed motors">',
        '<h2>Overview (most changed first)</h2><table><tr><th>motor</th><th>alarm</th>'
        '<th>largest change</th><th>alarms</th><th>effects (windows)</th><th>windows</th>'
        '<th>failed</th><th>last window</th></tr>']


def _overview_row(trend: MotorTrend, anchor: str) -> str:
    """Return a motor's row of the overview table."""
    parameter, value = trend.largest
    change = f'{parameter} {value:+.1f} %' if math.isfinite(value) else '-'
    effects = ', '.join(f'{name} ({count})' for name, count in
                        sorted(trend.effect_counts().items())) or '-'
    last = _when(trend.rows[-1]['window_start_ns']) if trend.rows else ''
    return (f'<tr><td><a href="#{anchor}">'
            f'{html.escape(trend.motor_id)}</a></td><td class="{trend.level}">{trend.level}'
            f'</td>{_cell(change)}{_cell("; ".join(a.summary() for a in trend.alarms) or "-")}'
            f'{_cell(effects)}{_cell(len(trend.rows))}{_cell(len(trend.failed))}'
            f'{_cell(last)}</tr>')


def _motor_parts(trend: MotorTrend, anchor: str, directory: str) -> list[str]:
    """Return a motor's section: its figure, alarms, effects and failed windows."""
    parts = [f'<h2 id="{anchor}">Motor {html.escape(trend.motor_id)} '
             f'<span class="{trend.level}">{trend.level}</span></h2>']
    if trend.rows:
        image = plot_motor(trend, directory, f'motor_{anchor}.png')
        parts.append(f'<img src="{image}" alt="trends of {html.escape(trend.motor_id)}"'
                     ' width="1000">')
    if trend.alarms:
        parts.append('<table><tr><th>alarm</th><th>level</th><th>since</th>'
                     '<th>decided</th></tr>')
        for alarm in trend.alarms:
            parts.append(f'<tr>{_cell(alarm.summary())}<td class="{alarm.level}">'
                         f'{alarm.level}</td>{_cell(_when(alarm.since_s))}'
                         f'{_cell(_when(alarm.raised))}</tr>')
        parts.append('</table>')
    else:
        parts.append('<p>No change alarm.</p>')
    parts.append(_effects_table(trend))
    if trend.failed:
        parts.append('<p>Failed:</p><ul>' + ''.join(
            f'<li>{html.escape(row.get("source_bag") or "")} window '
            f'{row.get("window_index")}: {html.escape(row.get("error") or "")}</li>'
            for row in trend.failed[:20]) + '</ul>')
    return parts


def _effects_table(trend: MotorTrend) -> str:
    counts = trend.effect_counts()
    if not counts:
        return '<p>No effect found in any window.</p>'
    rows = ['<table><tr><th>effect</th><th>windows</th><th>first found</th>'
            '<th>median value (first parameter)</th></tr>']
    for name, count in sorted(counts.items()):
        values = np.array([found[name] for _, found in trend.effects if name in found])
        first = next(time for time, found in trend.effects if name in found)
        median = float(np.nanmedian(values)) if np.isfinite(values).any() else math.nan
        rows.append(f'<tr>{_cell(name)}{_cell(f"{count} of {len(trend.rows)}")}'
                    f'{_cell(_when(first))}{_cell(f"{median:.4g}")}</tr>')
    return ''.join(rows) + '</table>'
