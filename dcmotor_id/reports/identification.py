"""
The before/after report: an HTML page with PNG plots (``dcmotor-id identify --report DIR``).

What a control engineer needs to judge the identified model, on one page:

* the verdict (effects found, residual explained or not) and the held-out simulation error of
  the base and the final model;
* measured vs simulated current and speed, base model and final model, with the held-out part
  marked (there the model runs free from the end of the training part: a prediction);
* the held-out residual before and after, and its autocorrelation with the 99 % band of a
  white sequence, plus its cross-correlation with the input;
* the parameter table with 95 % confidence intervals, the effects with their parameters, and
  every search round with the candidates' scores.

Plots use matplotlib's object interface with the Agg canvas (no display, no global state).
"""

from __future__ import annotations

import html
import os
import re
from typing import Any, Mapping, Sequence, TYPE_CHECKING

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
import numpy as np

from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.residuals import (autocorrelation, confidence_band,
                                                 cross_correlation, DEFAULT_LAGS, output_channels,
                                                 simulate_records)

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.validate import Validation

#: Units of the plotted channels.
CHANNEL_UNITS = {'current': 'A', 'speed': 'rad/s', 'voltage': 'V', 'position': 'rad'}
#: z of the two-sided 95 % interval of the parameter table.
Z95 = 1.959964
_COLOURS = {'measured': '0.55', 'before': '#d62728', 'after': '#1f77b4', 'band': '0.85'}


def _save(figure, directory, name):
    FigureCanvasAgg(figure)
    path = os.path.join(directory, name)
    figure.savefig(path, dpi=110, bbox_inches='tight')
    return name


def _series(found, records, result):
    """Per record: time, measured, base and final simulation, and the split index."""
    out = []
    if found is not None:
        for index, rec in enumerate(found.final.records):
            base_rec = found.base.records[index]
            n = min(len(rec), len(base_rec))
            item = {'time': rec.time_s[:n], 'stop': found.final.stops[index], 'measured': {},
                    'before': {}, 'after': {}}
            for channel in found.outputs:
                item['measured'][channel] = getattr(rec, channel)[:n]
                item['before'][channel] = found.base.simulated[index][channel][:n]
                item['after'][channel] = found.final.simulated[index][channel][:n]
            out.append(item)
        return out, found.outputs
    model = OutputErrorModel(records, result.get('torque_constant'))
    all_simulated = simulate_records(model, dict(result['parameters']), result['initial_states'])
    for rec, simulated in zip(records, all_simulated):
        # one model only: before and after are the same mapping (drawn once, as 'model')
        same = {channel: simulated[channel] for channel in model.outputs}
        item = {'time': rec.time_s, 'stop': len(rec), 'before': same, 'after': same,
                'measured': {channel: getattr(rec, channel) for channel in model.outputs}}
        out.append(item)
    return out, output_channels(result['mode'] == 'mechanical')


#: Records drawn side by side in one row of the small multiples.
COLUMNS_PER_ROW = 4
#: Records given their own residual analysis (the rest are listed as not drawn).
MAX_RECORDS_DRAWN = 12
#: Transients zoomed into per record (the largest input changes).
TRANSIENTS = 3


def _grid(count: int, rows_each: int, width: float = 3.6, height: float = 2.1):
    """Return a figure and axes for ``count`` panels of ``rows_each`` stacked axes each."""
    columns = min(count, COLUMNS_PER_ROW)
    groups = -(-count // columns)
    if rows_each == 1:
        height *= 1.3  # one channel: room for its detail
    # few records: wider panels (a long record in a narrow panel hides its steps)
    figure = Figure(figsize=(max(10.0 if columns < 3 else 6.0, width * columns),
                             height * rows_each * groups + 1.2))
    axes = figure.subplots(rows_each * groups, columns, squeeze=False)
    return figure, axes, columns


def plot_fit(series: list[dict], outputs: Sequence[str], directory: str,
             errors: Mapping[str, Mapping[str, float | None]],
             units: Mapping[str, str] = CHANNEL_UNITS, name: str = 'fit.png',
             labels: Sequence[str] | None = None,
             scores: Sequence[str] | None = None) -> str:
    """
    Measured vs model before and after for every record (small multiples), held-out marked.

    One column per record (wrapping after :data:`COLUMNS_PER_ROW`), one row per channel;
    ``scores`` (one short text per record, e.g. its NRMSE) goes under the record's name.
    """
    shown = series[:MAX_RECORDS_DRAWN]
    figure, axes, columns = _grid(len(shown), len(outputs))
    for number, item in enumerate(shown):
        group, column = divmod(number, columns)
        t = item['time']
        stop = item['stop']
        for row, channel in enumerate(outputs):
            ax = axes[group * len(outputs) + row, column]
            ax.plot(t, item['measured'][channel], color=_COLOURS['measured'], lw=1.4,
                    label='measured')
            if item['before'] is not item['after']:
                ax.plot(t, item['before'][channel], color=_COLOURS['before'], lw=0.8, ls='--',
                        label='base model')
            ax.plot(t, item['after'][channel], color=_COLOURS['after'], lw=0.8,
                    label='final model' if item['before'] is not item['after'] else 'model')
            if stop < len(t):
                ax.axvspan(t[stop], t[-1], color=_COLOURS['band'], alpha=0.5, lw=0,
                           label='held out')
            ax.set_ylabel(f'{channel} [{units.get(channel, "")}]', fontsize=8)
            ax.tick_params(labelsize=7)
            ax.grid(True, lw=0.3)
            ax.xaxis.set_major_locator(MaxNLocator(5))
            if row == 0:
                title = _record_label(labels, number)
                if scores and number < len(scores) and scores[number]:
                    title += '\n' + scores[number]
                ax.set_title(title, fontsize=8)
        axes[group * len(outputs) + len(outputs) - 1, column].set_xlabel('time [s]', fontsize=8)
    for number in range(len(shown), axes.shape[1] * (axes.shape[0] // len(outputs))):
        group, column = divmod(number, columns)
        for row in range(len(outputs)):
            axes[group * len(outputs) + row, column].set_visible(False)
    handles, texts = axes[0, 0].get_legend_handles_labels()
    more = f' ({len(series) - len(shown)} more not drawn)' if len(series) > len(shown) else ''
    before = ', '.join(f'{c} {_pct(errors["before"].get(f"{c}_nrmse_pct"))}' for c in outputs)
    after = ', '.join(f'{c} {_pct(errors["after"].get(f"{c}_nrmse_pct"))}' for c in outputs)
    title = f'Every record: measured vs simulated (free run on the input){more}'
    held_out = any(item['stop'] < len(item['time']) for item in series)
    if any(errors.get('after', {}).values()) and held_out:
        title += f'.\nHeld-out NRMSE base {before}; final {after}'
    elif any(errors.get('after', {}).values()):
        title += f'.\nNRMSE {after}'
    _title_and_legend(figure, title, handles, texts)
    return _save(figure, directory, name)


def _title_and_legend(figure: Figure, title: str, handles: list, texts: list[str]) -> None:
    """Lay the panels out below a title and one legend (heights in inches, not fractions)."""
    height = figure.get_figheight()
    lines = title.count('\n') + 1
    legend_top = 1.0 - (0.1 + 0.17 * lines) / height
    # the layout first: tight_layout would reserve room for a suptitle a second time
    figure.tight_layout(rect=(0, 0, 1, legend_top - 0.3 / height))
    figure.suptitle(title, fontsize=9, y=1.0 - 0.05 / height, va='top')
    if handles:
        figure.legend(handles, texts, loc='upper center', ncol=len(texts), fontsize=8,
                      bbox_to_anchor=(0.5, legend_top))


def _record_label(labels: Sequence[str] | None, number: int) -> str:
    """Return ``record N: name`` (the file name only, at most 40 characters)."""
    if labels and number < len(labels) and labels[number]:
        return f'record {number + 1}: {os.path.basename(str(labels[number]))[-40:]}'
    return f'record {number + 1}'


def _transients(values: np.ndarray, count: int, width: int) -> list[int]:
    """
    Return where the ``count`` largest input changes are, ``width`` samples apart.

    A change is the difference between the input's means over a tenth of the window after
    and before a sample (so a fast ramp counts as well as a step, and a noise spike, which
    moves one sample of a mean, does not), and only where the window fits in the record
    after it (the window starts a fifth of its width before the change).
    """
    values = np.asarray(values, dtype=float)
    lag = max(1, width // 10)
    lead = width // 5
    if values.size < width + lag:
        return []
    finite = np.where(np.isfinite(values), values, 0.0)
    total = np.concatenate([[0.0], np.cumsum(finite)])
    # change[k]: mean of samples k .. k+lag-1 minus mean of k-lag .. k-1 (k = lag .. n-lag)
    after = (total[2 * lag:] - total[lag:-lag]) / lag
    before = (total[lag:-lag] - total[:-2 * lag]) / lag
    change = np.abs(after - before)
    steps = np.arange(change.size) + lag
    change[steps + width - lead > values.size] = 0.0
    chosen: list[int] = []
    for index in np.argsort(-change, kind='stable'):  # the earliest of equal changes
        if change[index] <= 0 or len(chosen) >= count:
            break
        step = int(steps[index])
        if all(abs(step - other) >= width for other in chosen):
            chosen.append(step)
    return sorted(chosen)


def _transient_width(item: dict) -> int:
    """Return the samples of a transient window: 1/25 of the record, 50 to 2000."""
    return int(np.clip(len(item['time']) // 25, 50, 2000))


def plot_transients(series: list[dict], outputs: Sequence[str], inputs: Sequence[np.ndarray],
                    directory: str, input_name: str,
                    units: Mapping[str, str] = CHANNEL_UNITS,
                    name: str = 'transients.png',
                    labels: Sequence[str] | None = None) -> str:
    """Zoom on the largest input changes of every record: measured vs simulated."""
    shown = series[:MAX_RECORDS_DRAWN]
    figure = Figure(figsize=(3.6 * TRANSIENTS, 1.9 * len(outputs) * len(shown) + 0.8))
    axes = figure.subplots(len(outputs) * len(shown), TRANSIENTS, squeeze=False)
    for number, (item, values) in enumerate(zip(shown, inputs)):
        t = item['time']
        width = _transient_width(item)
        starts = _transients(np.asarray(values[:len(t)], dtype=float), TRANSIENTS, width)
        for slot in range(TRANSIENTS):
            for row, channel in enumerate(outputs):
                ax = axes[number * len(outputs) + row, slot]
                if slot >= len(starts):
                    ax.set_visible(False)
                    continue
                low = max(starts[slot] - width // 5, 0)
                part = slice(low, min(low + width, len(t)))
                change = int(starts[slot])
                ax.plot(t[part], item['measured'][channel][part], color=_COLOURS['measured'],
                        lw=1.4, label='measured')
                if item['before'] is not item['after']:
                    ax.plot(t[part], item['before'][channel][part], color=_COLOURS['before'],
                            lw=0.8, ls='--', label='base model')
                ax.plot(t[part], item['after'][channel][part], color=_COLOURS['after'],
                        lw=0.9, label='final model' if item['before'] is not item['after']
                        else 'model')
                ax.axvline(t[change], color='k', lw=0.9, ls=':')
                ax.set_ylabel(f'{channel} [{units.get(channel, "")}]', fontsize=8)
                ax.tick_params(labelsize=7)
                ax.xaxis.set_major_locator(MaxNLocator(4))
                ax.grid(True, lw=0.3)
                if row == 0:
                    ax.set_title(f'{_record_label(labels, number)}\n{input_name} change near '
                                 f'{t[change]:.4g} s', fontsize=8)
        if not starts:
            ax = axes[number * len(outputs), 0]
            ax.set_visible(True)
            ax.set_axis_off()
            ax.text(0, 0.5, f'{_record_label(labels, number)}: too short for a transient '
                    'window', fontsize=8, transform=ax.transAxes)
    handles, texts = next((ax.get_legend_handles_labels() for ax in axes.flat
                           if ax.get_legend_handles_labels()[0]), ([], []))
    _title_and_legend(figure, 'Transients: the largest input changes of each record (dotted '
                      'line), model run free from the start of the record', handles, texts)
    return _save(figure, directory, name)


def _pct(value):
    return 'n/a' if value is None else f'{value:.3g} %'


def _input(series, records, found, result):
    """Return the input's name and its values per record (not joined)."""
    mechanical = result['mode'] == 'mechanical'
    name = 'current' if mechanical else 'voltage'
    recs = found.final.records if found is not None else records
    values = [getattr(rec, name)[:len(item['time'])] for item, rec in zip(series, recs)]
    return ('torque input' if mechanical else name), values


#: Channels whose residual is not tested for whiteness (an integral of the speed error).
INTEGRATED = ('position',)


def _acf_axis(ax, acfs: Sequence[tuple[np.ndarray, str, str]], band: float) -> None:
    """Draw autocorrelations as bars with the white band; symlog when far outside it."""
    lags = np.arange(1, len(acfs[0][0]) + 1)
    width = 0.8 / len(acfs)
    for number, (acf, colour, label) in enumerate(acfs):
        ax.bar(lags + (number - (len(acfs) - 1) / 2) * width, acf, width=width, color=colour,
               label=label, zorder=2)
    ax.axhspan(-band, band, color=_COLOURS['band'], alpha=0.8, lw=0, zorder=0,
               label='99 % band of a white sequence')
    ax.axhline(0.0, color='k', lw=0.5)
    peak = max(float(np.max(np.abs(acf))) for acf, _, _ in acfs)
    if peak > 5 * band:
        # far outside the band: a linear scale would flatten the band to a line; the
        # linear part (the band) takes as much height as one decade outside it
        ax.set_yscale('symlog', linthresh=band, linscale=1.0)
        ax.set_ylim(-1.1, 1.1)
        marks = [1.0] + ([0.3] if 0.3 > 3 * band else [])
        ticks = sorted({0.0, band, -band} | set(marks) | {-value for value in marks})
        ax.set_yticks(ticks, [f'{value:.2g}' for value in ticks])
        ax.minorticks_off()
        ax.text(0.98, 0.03, 'symlog: linear inside the band', transform=ax.transAxes,
                ha='right', va='bottom', fontsize=7, color='0.3',
                bbox={'facecolor': 'white', 'edgecolor': 'none', 'alpha': 0.8, 'pad': 1})
    else:
        top = max(peak, band) * 1.25
        ax.set_ylim(-top, top)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float('nan')


def plot_residuals(series: list[dict], outputs: Sequence[str], directory: str,
                   input_name: str, inputs: Sequence[np.ndarray], max_lag: int = DEFAULT_LAGS,
                   units: Mapping[str, str] = CHANNEL_UNITS, name: str = 'residuals.png',
                   sides: Sequence[tuple[str, str]] = (('before', 'base'), ('after', 'final')),
                   labels: Sequence[str] | None = None) -> str:
    """
    Residual of every record on its own: the residual, its autocorrelation, input correlation.

    Records are never joined (a join would put a jump into the residual and mix records);
    each is analysed on its held-out part (the whole record when there is none). The
    position residual (an integral of the speed error, never white) is drawn but not tested.
    """
    shown = series[:MAX_RECORDS_DRAWN]
    figure = Figure(figsize=(13, 2.4 * len(outputs) * len(shown) + 0.9))
    axes = figure.subplots(len(outputs) * len(shown), 3, squeeze=False)
    for number, (item, values) in enumerate(zip(shown, inputs)):
        stop = item['stop'] if item['stop'] < len(item['time']) else 0
        part = slice(stop, None)
        time = item['time'][part]
        driving = np.asarray(values[:len(item['time'])], dtype=float)[part]
        label = _record_label(labels, number) + (' (held-out part)' if stop else '')
        for row, channel in enumerate(outputs):
            residuals = {side: item[side][channel][part] - item['measured'][channel][part]
                         for side, _ in sides}
            _residual_row(axes[number * len(outputs) + row], channel, units.get(channel, ''),
                          time, residuals, driving, sides, (label, f'record {number + 1}'),
                          input_name, max_lag)
    axes[-1, 0].set_xlabel('time [s]', fontsize=8)
    axes[-1, 1].set_xlabel('lag [samples]', fontsize=8)
    axes[-1, 2].set_xlabel('lag [samples]', fontsize=8)
    handles, texts = [], []
    for ax in axes.flat:
        for handle, text in zip(*ax.get_legend_handles_labels()):
            if text not in texts:
                handles.append(handle)
                texts.append(text)
    _title_and_legend(figure, 'Residual (model - measured) per record: structure left = bars '
                      'or dots outside the grey band', handles, texts)
    return _save(figure, directory, name)


def _residual_row(row_axes: Sequence[Any], channel: str, unit: str, time: np.ndarray,
                  residuals: Mapping[str, np.ndarray], driving: np.ndarray,
                  sides: Sequence[tuple[str, str]], names: tuple[str, str], input_name: str,
                  max_lag: int) -> None:
    """
    Draw one channel of one record: its residual, their autocorrelation, input correlation.

    ``names`` are the record's label (the title of the residual) and its short name.
    """
    label, record = names
    ax = row_axes[0]
    for side, text in sides:
        ax.plot(time, residuals[side], color=_COLOURS[side], lw=0.6, label=text)
    ax.set_ylabel(f'{channel} residual [{unit}]', fontsize=8)
    rms = ', '.join(f'{text} {_rms(residuals[side]):.3g}' for side, text in sides)
    ax.grid(True, lw=0.3)
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.tick_params(labelsize=7)
    if channel in INTEGRATED:
        # hidden axes are left out of the layout; a text beside would widen it
        for other in row_axes[1:]:
            other.set_visible(False)
        ax.set_title(f'{label}\nrms {rms} {unit} (not tested for whiteness: it '
                     'integrates the speed error)', fontsize=8, loc='left')
        return
    ax.set_title(f'{label}\nrms {rms} {unit}', fontsize=8)
    ax = row_axes[1]
    band = confidence_band(residuals[sides[-1][0]].size)
    _acf_axis(ax, [(autocorrelation(residuals[side], max_lag)[1:], _COLOURS[side],
                    text) for side, text in sides], band)
    ax.set_ylabel('autocorrelation', fontsize=8)
    ax.set_title(f'{record}, {channel}: whiteness (band +-{band:.2g})', fontsize=8)
    ax = row_axes[2]
    for side, text in sides:
        lag_axis, rho = cross_correlation(residuals[side], driving, max_lag)
        ax.plot(lag_axis, rho, marker='o', ms=2.0, lw=0.7, color=_COLOURS[side],
                label=text, zorder=2)
    ax.axhspan(-band, band, color=_COLOURS['band'], alpha=0.8, lw=0, zorder=0)
    ax.axhline(0.0, color='k', lw=0.5)
    ax.set_ylabel(f'corr(residual, {input_name})', fontsize=8)
    ax.set_title(f'{record}, {channel} residual vs {input_name}', fontsize=8)
    for ax in row_axes:
        ax.tick_params(labelsize=7)


def plot_steps(found: DiscoveryResult, outputs: Sequence[str], directory: str) -> str:
    """Held-out error after each round of the loop, per channel."""
    labels = ['base']
    values = {channel: [found.error_before.get(f'{channel}_nrmse_pct')] for channel in outputs}
    for step in found.steps:
        if step.get('added'):
            labels.append('+ ' + step['added']['name'])
            for channel in outputs:
                values[channel].append(step['error_after'].get(f'{channel}_nrmse_pct'))
    figure = Figure(figsize=(max(5.0, 1.6 * len(labels) + 2), 3.2))
    ax = figure.subplots()
    width = 0.8 / len(outputs)
    positions = np.arange(len(labels))
    for number, channel in enumerate(outputs):
        heights = [np.nan if v is None else v for v in values[channel]]
        bars = ax.bar(positions + (number - (len(outputs) - 1) / 2) * width, heights, width,
                      label=channel)
        for bar, height in zip(bars, heights):
            if np.isfinite(height):
                ax.annotate(f'{height:.3g}', (bar.get_x() + bar.get_width() / 2, height),
                            ha='center', va='bottom', fontsize=8)
    ax.set_xticks(positions, labels)
    ax.set_ylabel('held-out NRMSE [%]')
    ax.set_title('Simulation error on the held-out data, effect by effect', fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, axis='y', lw=0.3)
    return _save(figure, directory, 'steps.png')


def _table(header, rows):
    head = ''.join(f'<th>{html.escape(str(cell))}</th>' for cell in header)
    body = ''.join('<tr>' + ''.join(f'<td>{cell}</td>' for cell in row) + '</tr>'
                   for row in rows)
    return f'<table><tr>{head}</tr>{body}</table>'


def _number(value, digits=5):
    if value is None:
        return 'n/a'
    if isinstance(value, str):
        return html.escape(value)
    if not np.isfinite(value):
        return html.escape(str(value))
    return f'{value:.{digits}g}'


def _mentions(text: str, name: str) -> bool:
    """Return whether ``text`` names the parameter ``name`` as a word (not the b of by)."""
    return re.search(rf'(?<![\w.]){re.escape(name)}(?![\w])', text) is not None


def _parameter_flags(result: Mapping[str, Any], name: str) -> list[str]:
    """Return the flags of a parameter: not identifiable, an upper bound, warnings naming it."""
    flags = []
    reason = (result.get('not_identifiable') or {}).get(name)
    if reason:
        flags.append(f'not identifiable: {html.escape(str(reason))}')
    if name in (result.get('upper_bounds') or {}):
        flags.append('upper bound only')
    numbers = [f'W{number}' for number, text in enumerate(result.get('warnings') or [], 1)
               if _mentions(str(text), name)]
    if numbers:
        flags.append('see ' + ', '.join(numbers))
    return flags


def _parameter_rows(result):
    rows = []
    for name, value in result['parameters'].items():
        err = result['stderr'].get(name, float('nan'))
        low, high = value - Z95 * err, value + Z95 * err
        rel = abs(err / value) * 100 if value else float('nan')
        flags = _parameter_flags(result, name)
        rows.append([name, _number(value), _number(err, 3), f'[{_number(low)}, {_number(high)}]',
                     _number(rel, 3) + ' %', html.escape(result['units'].get(name, '')),
                     f'<span class="flag">{"; ".join(flags)}</span>' if flags else ''])
    return rows


def structure_parts(result: Mapping[str, Any]) -> list[str]:
    """
    HTML of the structure bootstrap (``structure_uncertainty``): what it did and added.

    A sentence when it was not asked for (the standard errors then leave the structure choice
    out, when discovery ran), a table of the structures chosen and one of the per-parameter
    part when it ran.
    """
    info = result.get('structure_uncertainty')
    if not result.get('discover'):
        return []
    head = '<h3>Choice of structure</h3>'
    if info is None:
        return [head, '<p>Not covered: the standard errors are those of the structure chosen. '
                'Rerun with <code>--structure-bootstrap 20</code> to include the spread from '
                'the choice of effects (20 more fits).</p>']
    if 'skipped' in info:
        return [head, f'<p>Not covered: {html.escape(str(info["skipped"]))}.</p>']
    rows = [[html.escape(' + '.join(item['effects']) or 'no effect'), str(item['count']),
             _pct(100 * item['share'])] for item in info['structures']]
    part = info.get('stderr_structure') or {}
    without = info.get('stderr_without_structure') or {}
    changed = [[name, _number(without.get(name, float('nan')), 3), _number(value, 3),
                _number(result['stderr'].get(name, float('nan')), 3)]
               for name, value in part.items() if value and np.isfinite(value)]
    text = (f'<p>Noise bootstrap: {info["completed"]} of {info["resamples"]} resamples '
            f'identified ({info["failed"]} refused), discovery rerun on each; the structure of '
            f'this result was chosen on {_pct(100 * info["chosen_share"])} of them. ' +
            ('The standard errors above include the spread between the structures.</p>'
             if info.get('included_in_stderr') else
             'Every resample chose one structure: the standard errors are unchanged.</p>'))
    out = [head, text, _table(['structure chosen', 'resamples', 'share'], rows)]
    if changed:
        out.append(_table(['parameter', 'std. error, one structure', 'structure part',
                           'std. error reported'], changed))
    return out


def _flags(result: Mapping[str, Any]) -> str:
    """HTML of the warnings and non-identifiable parameters (empty when there are none)."""
    items = [f'<b>W{number}</b> {html.escape(str(text))}'
             for number, text in enumerate(result.get('warnings') or [], 1)]
    items += [f'<b>{html.escape(str(name))}</b> not identifiable: {html.escape(str(reason))}'
              for name, reason in (result.get('not_identifiable') or {}).items()]
    items += [f'record {html.escape(str(source))}: {html.escape(str(text))}'
              for source, text in _record_errors(result)]
    if not items:
        return ''
    return ('<div class="verdict warn"><b>Warnings</b><ul>'
            + ''.join(f'<li>{item}</li>' for item in items) + '</ul></div>')


def _record_errors(result: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Per-record errors of the result, in whichever layout they come."""
    errors = result.get('record_errors') or result.get('errors_by_record') or []
    if isinstance(errors, Mapping):
        return [(str(source), str(text)) for source, text in errors.items()]
    out = []
    for entry in errors:
        if isinstance(entry, Mapping):
            out.append((str(entry.get('source', entry.get('record', ''))),
                        str(entry.get('error', entry.get('message', entry)))))
    return out


def _evidence_rows(found):
    rows = []
    for label, analysis in (('base', found.analysis_before), ('final', found.analysis_after)):
        for channel, item in analysis.items():
            inputs = ', '.join(f'{name} {value["max_abs"]:.3f} (band {value["band"]:.3f})'
                               for name, value in item['inputs'].items())
            one_step = item.get('one_step_nrmse_pct')
            rows.append([label, channel, _number(item['nrmse_pct'], 4) + ' %',
                         'n/a' if one_step is None else _number(one_step, 4) + ' %',
                         _number(item['ljung_box']['statistic'], 4),
                         _number(item['ljung_box']['p_value'], 3),
                         _number(item['predictable_fraction'], 3),
                         _number(item['acf_outside_band'] * 100, 3) + ' %', inputs])
    return rows


def _gain_text(value):
    """Return a gain in percent as text (n/a when the candidate was not refitted)."""
    return 'n/a' if value is None else _number(value, 3) + ' %'


def _step_rows(found):
    rows = []
    for number, step in enumerate(found.steps, start=1):
        tied = {item['name'] for item in step.get('equivalent', [])}
        for candidate in step['candidates']:
            added = step.get('added') and step['added']['name'] == candidate['name']
            gain = candidate['heldout_gain_pct']
            if added:
                verdict = 'added'
            elif candidate['name'] in tied:
                verdict = 'tie with the added effect (the same model on these data)'
            elif candidate.get('rejected'):
                verdict = 'rejected: ' + candidate['rejected']
            elif not candidate['refitted']:
                verdict = 'not refitted (screen below threshold)'
            else:
                verdict = ''
            inner = ', '.join(f'{k}={_number(v, 4)}' for k, v in candidate['inner'].items())
            rows.append([number, html.escape(candidate['name']), html.escape(inner),
                         _number(candidate['screen_explained_pct'], 3) + ' %',
                         _gain_text(candidate.get('insample_gain_pct')),
                         'n/a' if gain is None else _number(gain, 3) + ' %',
                         _gain_text(candidate.get('heldout_gain_noise_pct')),
                         _number(candidate['bic_delta'], 4), html.escape(verdict)])
    return rows


_STYLE = """
body { font-family: sans-serif; margin: 1.5em; max-width: 1250px; }
table { border-collapse: collapse; margin: 0.5em 0 1.2em 0; font-size: 0.9em; }
td, th { border: 1px solid #bbb; padding: 3px 8px; text-align: right; }
th { background: #eee; }
td:first-child, th:first-child { text-align: left; }
.verdict { font-size: 1.1em; padding: 0.6em; background: #f4f4f4; border-left: 4px solid #1f77b4; }
.warn { border-left-color: #d62728; }
.flag { color: #d62728; font-weight: bold; }
img { max-width: 100%; }
"""


def write_report(directory: str, result: dict[str, Any], found: DiscoveryResult | None = None,
                 records: Sequence[Record] | None = None,
                 channel_units: Mapping[str, str] | None = None,
                 title: str = 'DC motor identification: before / after',
                 validation: Validation | None = None) -> str:
    """
    Write ``index.html`` and its PNGs to ``directory``; return the page's path.

    Parameters
    ----------
    directory : str
        Output directory (created).
    result : dict
        The JSON result (:meth:`~dcmotor_id.identification.result.IdentificationResult.as_dict`).
    found : DiscoveryResult, optional
        The loop's result
        (:attr:`~dcmotor_id.identification.result.IdentificationResult.discovery_result`);
        without it the page shows the base model's fit on the whole record.
    records : list of Record, optional
        The prepared records (needed when ``found`` is None).
    channel_units : dict, optional
        Units of current, speed and voltage on the plots (e.g. m/s for a linear axis).
    title : str
        Page title.
    validation : Validation, optional
        A validation of the model on other records
        (:func:`dcmotor_id.identification.validate.validate`):
        its table and figures are added.

    """
    os.makedirs(directory, exist_ok=True)
    units = dict(CHANNEL_UNITS, **(channel_units or {}))
    series, outputs = _series(found, records, result)
    errors = {'before': result['error_before'], 'after': result['error_after']}
    images = _figures(directory, result, found, records, units, series, outputs, errors)
    parts = _summary_parts(title, result, found, errors, images)
    parts += _effect_parts(result)
    parts += _residual_parts(found, images)
    if validation is not None:
        parts += _validation_parts(directory, validation, units)
    return _write_page(directory, 'index.html', 'dcmotor_id report', parts)


def _figures(directory: str, result: dict[str, Any], found: DiscoveryResult | None,
             records: Sequence[Record] | None, units: Mapping[str, str], series: list[dict],
             outputs: Sequence[str], errors: dict[str, Any]) -> list[str]:
    """Draw the figures of the page; return fit, residuals, steps ('' if none), transients."""
    labels = [str(source) for source in result.get('records') or []]
    images = [plot_fit(series, outputs, directory, errors, units, labels=labels,
                       scores=_record_scores(result, outputs))]
    input_name, input_values = _input(series, records, found, result)
    sides = (('after', 'model'),) if found is None else (('before', 'base'), ('after', 'final'))
    images.append(plot_residuals(series, outputs, directory, input_name, input_values,
                                 units=units, labels=labels, sides=sides))
    images.append(plot_steps(found, outputs, directory) if found is not None and found.steps
                  else '')
    images.append(plot_transients(series, outputs, input_values, directory, input_name, units,
                                  labels=labels))
    return images


def _summary_parts(title: str, result: dict[str, Any], found: DiscoveryResult | None,
                   errors: dict[str, Any], images: list[str]) -> list[str]:
    """Return the page's head: the records, the verdict, the errors, fit and parameters."""
    verdict, verdict_class = _verdict(result, found, errors)
    where = '' if found is None else \
        f', on the held-out last {found.holdout_fraction * 100:.0f} % of each record'
    parts = [f'<h1>{html.escape(title)}</h1>',
             f'<p>{len(result["records"])} record(s): '
             f'{html.escape(", ".join(str(r) for r in result["records"]))}; '
             f'{result["n_samples"]} samples, dt {result["sample_period_s"]:.6g} s; mode '
             f'{html.escape(result["mode"])}; method {html.escape(result["method"])}; '
             f'criterion {html.escape(_criterion_text(result.get("criterion", "speed")))}.</p>',
             f'<p class="{verdict_class}">{verdict}</p>',
             '<h2>Simulation error</h2>',
             _table(['', 'current NRMSE', 'speed NRMSE'],
                    [['base model', _pct(errors['before']['current_nrmse_pct']),
                      _pct(errors['before']['speed_nrmse_pct'])],
                     ['final model', _pct(errors['after']['current_nrmse_pct']),
                      _pct(errors['after']['speed_nrmse_pct'])]]),
             '<p>NRMSE: root-mean-square of (simulated - measured) in percent of the measured '
             "signal's standard deviation" + where + '.</p>',
             f'<img src="{images[0]}" alt="measured vs model">',
             '<h2>Transients</h2>',
             f'<img src="{images[3]}" alt="transients">',
             '<h2>Parameters (final model, all data)</h2>',
             _flags(result),
             _table(['parameter', 'value', 'std. error', '95 % interval', 'rel. error',
                     'unit', 'flag'], _parameter_rows(result))]
    return parts + structure_parts(result)


def _verdict(result: dict[str, Any], found: DiscoveryResult | None,
             errors: dict[str, Any]) -> tuple[str, str]:
    """Return the page's verdict (HTML) on the effect search and its CSS class."""
    effects = result.get('effects', [])
    if found is None:
        reason = (result.get('discovery') or {}).get('skipped',
                                                     'effect discovery was switched off')
        verdict = f'No effect search: {html.escape(reason)}.'
        verdict_class = 'verdict'
    elif effects:
        names = ', '.join(effect['name'] for effect in effects)
        verdict = (f'Effects found: <b>{html.escape(names)}</b>. Held-out simulation error '
                   f'{_errors_text(errors["before"])} &rarr; {_errors_text(errors["after"])}.')
        verdict_class = 'verdict'
    else:
        verdict = ('No effect added: ' + html.escape(found.reason) + '. Held-out simulation '
                   f'error {_errors_text(errors["after"])}.')
        verdict_class = 'verdict'
    if result.get('unexplained'):
        verdict += (' <b>Structure remains in the residual that no candidate explains</b> '
                    '(see the whiteness test below): the model lacks something outside the '
                    'vocabulary.')
        verdict_class = 'verdict warn'
    return verdict, verdict_class


def _effect_parts(result: dict[str, Any]) -> list[str]:
    """Return the output-shaft values and the table of the effects found."""
    parts = []
    effects = result.get('effects', [])
    if result.get('output_shaft'):
        parts.append(f'<p>At the output shaft (gear ratio {result.get("gear_ratio")}): '
                     + html.escape(', '.join(f'{k} = {_number(v)}' for k, v in
                                             result['output_shaft'].items())) + '</p>')
    parts.append('<h2>Effects found</h2>')
    if effects:
        rows = [[html.escape(effect['name']),
                 html.escape(', '.join(f'{k} = {_number(v)}' for k, v in
                                       effect['parameters'].items()))] for effect in effects]
        parts.append(_table(['effect (in the order added)', 'parameters'], rows))
    else:
        parts.append('<p>none</p>')
    return parts


def _residual_parts(found: DiscoveryResult | None, images: list[str]) -> list[str]:
    """Return the residual analysis and, with a search, its evidence and rounds."""
    parts = ['<h2>Residual analysis (held-out part, each record on its own)</h2>',
             f'<img src="{images[1]}" alt="residuals and whiteness">']
    if found is None:
        return parts
    parts.append(_table(['model', 'channel', 'NRMSE', 'one-step NRMSE', 'Ljung-Box Q',
                         'p-value', 'AR-predictable share', 'lags outside 99 % band',
                         'max |corr| with input'], _evidence_rows(found)))
    parts.append('<p>White residual: Ljung-Box p-value above 0.01 (per channel, '
                 'Bonferroni). Structure that matters: not white and at least 5 % of the '
                 'residual predictable from its own past. The one-step error (the '
                 'measured state propagated over one sample by the model) localises '
                 'errors in time and ignores slow drifts of the simulation; n/a where the '
                 'model has an effect it does not represent.</p>')
    if found.steps:
        parts.append('<h2>Search rounds</h2>')
        parts.append(f'<img src="{images[2]}" alt="error per step">')
        parts.append(_table(['round', 'candidate', 'inner parameters',
                             'linearised screen', 'in-sample gain', 'held-out gain',
                             'held-out noise', 'BIC change', 'verdict'],
                            _step_rows(found)))
        parts.append(f'<p>A candidate is added when it lowers the held-out error by at '
                     f'least {found.min_gain * 100:.0f} % and by more than its noise (two '
                     'standard errors of the drop over blocks of the held-out part), and '
                     'the BIC of the training fit; in-sample gain: on the training part '
                     'it was fitted on. The loop stopped because '
                     f'{html.escape(found.reason)}.</p>')
    return parts


def _write_page(directory: str, name: str, title: str, parts: list[str]) -> str:
    """Write the page of body ``parts`` to ``directory/name`` (its head: ``title``, the style)."""
    head = (f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>{title}</title>'
            f'<style>{_STYLE}</style></head><body>')
    path = os.path.join(directory, name)
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join([head] + parts + ['</body></html>']))
    return path


def _score_text(errors: Mapping[str, Any], outputs: Sequence[str], prefix: str) -> str:
    """Return e.g. ``fit current 99 %, speed 98 %`` of one record's scores ('' if none)."""
    values = []
    for channel in outputs:
        value = (errors.get('fit_pct') or {}).get(channel) if prefix == 'fit' else \
            errors.get(f'{channel}_nrmse_pct')
        if value is not None and np.isfinite(value):
            values.append(f'{channel} {value:.3g} %')
    return f'{prefix} ' + ', '.join(values) if values else ''


def _record_scores(result: Mapping[str, Any], outputs: Sequence[str]) -> list[str]:
    """Per record: the final model's NRMSE over the whole record (as the CLI prints it)."""
    items = ((result.get('errors') or {}).get('records') or [])
    return [_score_text((item.get('after') or {}).get('whole_record') or {}, outputs,
                        'whole-record NRMSE') for item in items]


def _errors_text(errors):
    return ', '.join(f'{key.split("_")[0]} {value:.3g} %' for key, value in errors.items()
                     if value is not None)


def _validation_series(validation: Validation) -> tuple[list[dict], list[str]]:
    """Series of a validation (measured vs simulated over the scored samples)."""
    outputs = ['speed'] if validation.model.mechanical_only else ['current', 'speed']
    if all(item.record.position is not None for item in validation.records):
        outputs.append('position')
    series = []
    for item in validation.records:
        simulated = {channel: item.simulated[channel] for channel in outputs}
        series.append({'time': item.record.time_s, 'stop': len(item.record),
                       'measured': {channel: np.asarray(getattr(item.record, channel))
                                    for channel in outputs},
                       'before': simulated, 'after': simulated})
    return series, outputs


def _validation_parts(directory: str, validation: Validation,
                      units: Mapping[str, str]) -> list[str]:
    """HTML parts of a validation: the score table and its figures."""
    series, outputs = _validation_series(validation)
    scores = validation.as_dict()['records']
    worst = {'before': {}, 'after': {}}  # type: dict[str, dict[str, Any]]
    labels = [str(item['source']) for item in scores]
    fit = plot_fit(series, outputs, directory, worst, units, name='validation_fit.png',
                   labels=labels, scores=[_score_text(item, outputs, 'fit') for item in scores])
    name = 'current' if validation.model.mechanical_only else 'voltage'
    inputs = [getattr(item.record, name) for item in validation.records]
    shown = 'torque input' if name == 'current' else name
    residuals = plot_residuals(series, outputs, directory, shown, inputs,
                               units=units, name='validation_residuals.png',
                               sides=(('after', 'model'),), labels=labels)
    transients = plot_transients(series, outputs, inputs, directory, shown, units,
                                 name='validation_transients.png', labels=labels)
    rows = []
    for item in scores:
        fits = item['fit_pct']
        rows.append([html.escape(str(item['source'])), item['samples'],
                     _pct(item['current_nrmse_pct']), _pct(item['speed_nrmse_pct']),
                     _pct(fits['current']), _pct(fits['speed']), _pct(fits['position']),
                     _number(item['position_rmse'], 4)])
    notes = ''.join(f'<p class="verdict warn">{html.escape(text)}</p>'
                    for text in validation.warnings)
    return ['<h2>Validation on other records (open loop)</h2>', notes,
            _table(['record', 'samples', 'current NRMSE', 'speed NRMSE', 'fit current',
                    'fit speed', 'fit position', 'position RMSE'], rows),
            '<p>Each record simulated open loop from an initial state estimated on its first '
            f'{validation.records[0].init_samples} samples (not scored); fit as MATLAB '
            'compare: 100 (1 - |y - y_sim| / |y - mean y|).</p>',
            f'<img src="{fit}" alt="validation: measured vs simulated">',
            f'<img src="{transients}" alt="validation transients">',
            f'<img src="{residuals}" alt="validation residuals">']


def write_validation_report(directory: str, validation: Validation,
                            channel_units: Mapping[str, str] | None = None,
                            title: str = 'DC motor model: validation on new records') -> str:
    """Write ``validation.html`` and its PNGs (``validate --report DIR``); return its path."""
    os.makedirs(directory, exist_ok=True)
    units = dict(CHANNEL_UNITS, **(channel_units or {}))
    model = validation.model
    parameters = ', '.join(f'{name} = {_number(value)}' for name, value
                           in model.parameters.items())
    effects = ', '.join(effect['name'] for effect in model.effects) or 'none'
    parts = [f'<h1>{html.escape(title)}</h1>',
             f'<p>Model ({html.escape(model.mode)}): {html.escape(parameters)}; effects: '
             f'{html.escape(effects)}.</p>']
    parts += _validation_parts(directory, validation, units)
    return _write_page(directory, 'validation.html', 'dcmotor_id validation', parts)


#: What each fit criterion compares (the report's words).
CRITERION_TEXT = {'speed': 'speed (and current): output error on the measured speed',
                  'position': 'position (and current): output error on the measured position, '
                              'the integral of the simulated speed; the speed derived from it '
                              'is not compared',
                  'both': 'both: output error on the speed and the position (and current)'}


def _criterion_text(criterion: str) -> str:
    """Return the report's description of a fit criterion."""
    return CRITERION_TEXT.get(criterion, criterion)
