"""
Figures and an HTML summary of an identification result, for notebooks.

:func:`result_figures` draws, with matplotlib's object interface (no pyplot state), the
measured channels of every record against the identified model simulated from its initial
state, and the residual; :func:`result_html` is the table a notebook shows for the result.
matplotlib is imported when a figure is drawn, never by the identification itself.
"""

from __future__ import annotations

import html
from typing import Any, Mapping, Sequence, TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from dcmotor_id.core.records import Record

#: Records drawn at most (one row each).
MAX_RECORDS = 4
#: Channel -> its unit on the axes.
AXIS_UNITS = {'current': 'A', 'speed': 'rad/s'}


def simulated_channels(result: Mapping[str, Any], record: Record,
                       initial_state: Sequence[float]) -> dict[str, np.ndarray]:
    """
    Return the identified model's channels simulated over ``record`` (an identify JSON).

    The voltage-to-speed model is simulated with its armature lag when one was found (the
    ``model`` block's ``armature_lag``, its current starting quasi-static).
    """
    from dcmotor_id.identification.validate import model_from_dict, simulate
    return simulate(model_from_dict(result), record, initial_state)


def result_figures(result: Mapping[str, Any], records: Sequence[Record],
                   speeds: Sequence[np.ndarray] | None = None) -> list[Figure]:
    """
    Return two figures: measured against simulated channels, and their difference.

    Parameters
    ----------
    result : dict
        The identify JSON (``IdentificationResult.as_dict()``).
    records : list of Record
        The records identified (their initial states are the result's).
    speeds : list of numpy.ndarray, optional
        The fit's own simulated speed of every record (the voltage-to-speed model with its
        armature lag); None: simulated here from the JSON.

    """
    from matplotlib.figure import Figure
    shown = list(records)[:MAX_RECORDS]
    channels = [name for name in ('current', 'speed')
                if any(getattr(rec, name) is not None for rec in shown)]
    if result.get('mode') in ('mechanical', 'voltage_speed'):
        channels = ['speed']
    fit = Figure(figsize=(9.0, 2.6 * len(shown) * len(channels)), layout='constrained')
    residual = Figure(figsize=(9.0, 2.6 * len(shown) * len(channels)), layout='constrained')
    axes_fit = fit.subplots(len(shown) * len(channels), 1, squeeze=False)[:, 0]
    axes_res = residual.subplots(len(shown) * len(channels), 1, squeeze=False)[:, 0]
    states = result.get('initial_states') or [[0.0, 0.0]] * len(shown)
    row = 0
    for index, record in enumerate(shown):
        simulated = (simulated_channels(result, record, states[index]) if speeds is None
                     else {'speed': speeds[index]})
        name = record.source or f'record {index + 1}'
        for channel in channels:
            measured = getattr(record, channel)
            axes_fit[row].plot(record.time_s, measured, lw=0.8, label='measured')
            axes_fit[row].plot(record.time_s, simulated[channel], lw=0.8, label='model')
            axes_res[row].plot(record.time_s, measured - simulated[channel], lw=0.6)
            for axes, what in ((axes_fit[row], channel), (axes_res[row], f'{channel} error')):
                axes.set_ylabel(f'{what} [{AXIS_UNITS[channel]}]')
                axes.set_title(name, fontsize=9)
            row += 1
    axes_fit[0].legend(loc='upper right', fontsize=8)
    for axes in (axes_fit[-1], axes_res[-1]):
        axes.set_xlabel('t [s]')
    title = f"{result.get('method')} ({result.get('mode')})"
    fit.suptitle(f'measured and simulated, {title}', fontsize=10)
    residual.suptitle(f'measured minus simulated, {title}', fontsize=10)
    return [fit, residual]


def result_html(result: Mapping[str, Any]) -> str:
    """Return an HTML table of the parameters, effects and warnings of an identify JSON."""
    units = result.get('units') or {}
    stderr = result.get('stderr') or {}
    rows = []
    for name, value in (result.get('parameters') or {}).items():
        error = stderr.get(name)
        rows.append(f'<tr><td>{html.escape(name)}</td><td>{_number(value)}</td>'
                    f'<td>{_number(error)}</td><td>{html.escape(str(units.get(name, "")))}'
                    '</td></tr>')
    parts = [f"<p><b>dcmotor_id</b> {html.escape(str(result.get('method')))}, mode "
             f"{html.escape(str(result.get('mode')))}, {result.get('n_samples')} samples</p>",
             '<table><tr><th>parameter</th><th>value</th><th>stderr</th><th>unit</th></tr>'
             + ''.join(rows) + '</table>']
    for effect in result.get('effects') or []:
        parts.append(f"<p>effect {html.escape(str(effect.get('name')))}: "
                     f"{html.escape(str(effect.get('parameters')))}</p>")
    lists = (('not identifiable', [f'{key}: {text}' for key, text in
                                   (result.get('not_identifiable') or {}).items()]),
             ('warning', list(result.get('warnings') or [])))
    for label, texts in lists:
        parts.extend(f'<p>{label}: {html.escape(str(text))}</p>' for text in texts)
    return '<div>' + ''.join(parts) + '</div>'


def _number(value: Any) -> str:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value):
        return f'{value:.6g}'
    return 'n/a'
