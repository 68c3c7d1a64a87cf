"""
The figures of the identification and validation reports (PNG files, matplotlib).

Measured vs simulated channels of the base and the final model with the held-out part marked
(:func:`plot_fit`), the largest transients close up (:func:`plot_transients`), the residuals
with their autocorrelation and cross-correlation with the input (:func:`plot_residuals`) and
the discovery's search rounds (:func:`plot_steps`). The page around them is
:mod:`dcmotor_id.reports.identification`.

Plots use matplotlib's object interface with the Agg canvas (no display, no global state).
"""

from __future__ import annotations

import os
from typing import Any, Mapping, Sequence, TYPE_CHECKING

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
import numpy as np

from dcmotor_id.identification.error_model.residuals import (autocorrelation, confidence_band,
                                                             cross_correlation, DEFAULT_LAGS,
                                                             output_channels, simulate_records)
from dcmotor_id.identification.estimators.refined import OutputErrorModel

if TYPE_CHECKING:
    from dcmotor_id.identification.discovery import DiscoveryResult

#: Units of the plotted channels.
CHANNEL_UNITS = {'current': 'A', 'speed': 'rad/s', 'voltage': 'V', 'position': 'rad'}
_COLOURS = {'measured': '0.55', 'before': '#d62728', 'after': '#1f77b4', 'band': '0.85',
            'zoom': '#ffe680'}


def _save(figure, directory, name):
    FigureCanvasAgg(figure)
    path = os.path.join(directory, name)
    figure.savefig(path, dpi=110, bbox_inches='tight')
    return name


def fit_series(found, records, result):
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
    Where a base and a final model differ (effects were found), a second row per channel
    zooms on the stretch where they differ most (:func:`zoom_window`, shaded on the whole
    record): over a whole record the two lines lie on top of each other.
    """
    shown = series[:MAX_RECORDS_DRAWN]
    zoom = any(item['before'] is not item['after'] for item in shown)
    rows_each = len(outputs) * (2 if zoom else 1)
    figure, axes, columns = _grid(len(shown), rows_each)
    for number, item in enumerate(shown):
        group, column = divmod(number, columns)
        window = zoom_window(item, outputs) if zoom else None
        for row, channel in enumerate(outputs):
            ax = axes[group * rows_each + row, column]
            _fit_panel(ax, item, channel, slice(None), units)
            if row == 0:
                title = _record_label(labels, number)
                if scores and number < len(scores) and scores[number]:
                    title += '\n' + scores[number]
                ax.set_title(title, fontsize=8)
            if window is not None:
                t = item['time']
                ax.axvspan(t[window.start], t[window.stop - 1], color=_COLOURS['zoom'],
                           alpha=0.6, lw=0, label='zoomed below')
                zoomed = axes[group * rows_each + len(outputs) + row, column]
                _fit_panel(zoomed, item, channel, window, units)
                if row == 0:
                    zoomed.set_title(f'zoom: where base and final differ most '
                                     f'({t[window.start]:.4g} to {t[window.stop - 1]:.4g} s)',
                                     fontsize=8)
        axes[group * rows_each + rows_each - 1, column].set_xlabel('time [s]', fontsize=8)
    for number in range(len(shown), axes.shape[1] * (axes.shape[0] // rows_each)):
        group, column = divmod(number, columns)
        for row in range(rows_each):
            axes[group * rows_each + row, column].set_visible(False)
    handles, texts = _unique_legend(axes)
    _title_and_legend(figure, _fit_title(series, shown, outputs, errors), handles, texts)
    return _save(figure, directory, name)


def _fit_panel(ax, item: dict, channel: str, part: slice, units: Mapping[str, str]) -> None:
    """Draw measured, base and final model of one channel over ``part`` of the record."""
    t = item['time'][part]
    ax.plot(t, item['measured'][channel][part], color=_COLOURS['measured'], lw=1.4,
            label='measured')
    if item['before'] is not item['after']:
        ax.plot(t, item['before'][channel][part], color=_COLOURS['before'], lw=0.8, ls='--',
                label='base model')
    ax.plot(t, item['after'][channel][part], color=_COLOURS['after'], lw=0.8,
            label='final model' if item['before'] is not item['after'] else 'model')
    stop = item['stop']
    if stop < len(item['time']) and item['time'][stop] <= t[-1]:
        ax.axvspan(max(item['time'][stop], t[0]), t[-1], color=_COLOURS['band'], alpha=0.5,
                   lw=0, label='held out')
    ax.set_ylabel(f'{channel} [{units.get(channel, "")}]', fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, lw=0.3)
    ax.xaxis.set_major_locator(MaxNLocator(5))


def _unique_legend(axes) -> tuple[list, list[str]]:
    """Return the legend entries of all panels, each label once."""
    handles, texts = [], []
    for ax in axes.flat:
        for handle, text in zip(*ax.get_legend_handles_labels()):
            if text not in texts:
                handles.append(handle)
                texts.append(text)
    return handles, texts


def _fit_title(series: list[dict], shown: list[dict], outputs: Sequence[str],
               errors: Mapping[str, Mapping[str, float | None]]) -> str:
    """Return the fit figure's title: what it shows and the held-out errors."""
    more = f' ({len(series) - len(shown)} more not drawn)' if len(series) > len(shown) else ''
    before = ', '.join(f'{c} {pct_text(errors["before"].get(f"{c}_nrmse_pct"))}' for c in outputs)
    after = ', '.join(f'{c} {pct_text(errors["after"].get(f"{c}_nrmse_pct"))}' for c in outputs)
    title = f'Every record: measured vs simulated (free run on the input){more}'
    held_out = any(item['stop'] < len(item['time']) for item in series)
    if any(errors.get('after', {}).values()) and held_out:
        title += f'.\nHeld-out NRMSE base {before}; final {after}'
    elif any(errors.get('after', {}).values()):
        title += f'.\nNRMSE {after}'
    return title


#: Share of a record the fit figure's zoom shows.
ZOOM_SHARE = 0.02


def zoom_window(item: dict, outputs: Sequence[str], share: float = ZOOM_SHARE) -> slice:
    """
    Return the stretch of a record where the base and the final model differ most.

    The squared difference of the two simulations, each channel scaled by the spread of its
    measurement, summed over a window of ``share`` of the record (at least 20 samples); the
    window with the largest sum.
    """
    n = len(item['time'])
    width = min(n, max(20, int(round(share * n))))
    gap = np.zeros(n)
    for channel in outputs:
        spread = float(np.std(item['measured'][channel])) or 1.0
        difference = (np.asarray(item['before'][channel][:n], dtype=float)
                      - np.asarray(item['after'][channel][:n], dtype=float)) / spread
        gap += np.where(np.isfinite(difference), difference, 0.0) ** 2
    total = np.concatenate([[0.0], np.cumsum(gap)])
    start = int(np.argmax(total[width:] - total[:-width]))
    return slice(start, start + width)


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


def pct_text(value):
    return 'n/a' if value is None else f'{value:.3g} %'


def input_series(series, records, found, result):
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
