"""
The report of a voltage-to-speed result (records without a current): kS, kV, kA on one page.

``dcmotor-id identify --report DIR`` on voltage and speed alone writes ``index.html`` here
(:func:`dcmotor_id.reports.identification.write_report` hands such a result over): what was
identified and what cannot be without the current, the speed simulated under the measured
voltage against the measured one (the model as the JSON holds it, the armature lag included
when one was found) and its error, the parameters with their 95 % intervals and what each is
made of (the effects found among them, in volts), and the warnings.  The error is the
regression start's against the fitted model's; the discovery's rounds are in the JSON.
"""

from __future__ import annotations

import html
import os
from typing import Any, Mapping, Sequence, TYPE_CHECKING

from dcmotor_id.reports.identification import (_table, _validation_parts, _write_page,
                                               CHANNEL_UNITS, pct_text, Z95)

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.validate import Validation

#: The model, in words, at the top of the page.
MODEL_TEXT = ('No current was recorded: the voltage-to-speed model <code>u = kS sgn(w) + kV w '
              "+ kA dw/dt</code> (WPILib's SimpleMotorFeedforward convention) was fitted by "
              'output error on the speed simulated under the measured voltage.')


def _rows(result: Mapping[str, Any]) -> list[list[str]]:
    """Return the parameter rows: kS, kV, kA, then the armature lag's entries when found."""
    rows = []
    for name, entry in (result.get('combined') or {}).items():
        value, error = entry.get('value'), entry.get('stderr')
        if not isinstance(value, (int, float)) or not isinstance(error, (int, float)):
            continue
        rows.append([html.escape(name), f'{value:.5g}', f'{error:.3g}',
                     f'[{value - Z95 * error:.5g}, {value + Z95 * error:.5g}]',
                     pct_text(100.0 * abs(error / value)) if value else 'n/a',
                     html.escape(str(entry.get('unit', ''))),
                     html.escape(str(entry.get('of', '')))])
    return rows


def _figures(directory: str, result: Mapping[str, Any],
             records: Sequence[Record]) -> list[str]:
    """Draw measured against simulated speed and their difference; return the PNG names."""
    from dcmotor_id.identification.figures import result_figures  # matplotlib on drawing
    names = []
    for figure, name in zip(result_figures(result, records), ('fit.png', 'residuals.png')):
        figure.savefig(os.path.join(directory, name), dpi=90)
        names.append(name)
    return names


def write_voltage_speed_report(directory: str, result: dict[str, Any],
                               records: Sequence[Record],
                               title: str = 'DC motor identification: voltage to speed',
                               validation: Validation | None = None) -> str:
    """
    Write ``index.html`` and its PNGs for a result of mode ``voltage_speed``; return its path.

    Parameters
    ----------
    directory : str
        Output directory (created).
    result : dict
        The JSON result (mode ``voltage_speed``).
    records : list of Record
        The records identified (the result's initial states are theirs).
    title : str
        Page title.
    validation : Validation, optional
        A validation on other records: its table and figures are added.

    """
    os.makedirs(directory, exist_ok=True)
    images = _figures(directory, result, records)
    before, after = result['error_before'], result['error_after']
    not_separable = ''.join(f'<p class="verdict warn">{html.escape(key)}: '
                            f'{html.escape(str(text))}</p>'
                            for key, text in (result.get('not_identifiable') or {}).items())
    warnings = ''.join(f'<li>W{number}: {html.escape(str(text))}</li>'
                       for number, text in enumerate(result.get('warnings') or [], 1))
    parts = [f'<h1>{html.escape(title)}</h1>',
             f'<p>{len(result["records"])} record(s): '
             f'{html.escape(", ".join(str(r) for r in result["records"]))}; '
             f'{result["n_samples"]} samples, dt {result["sample_period_s"]:.6g} s; mode '
             f'{html.escape(result["mode"])}.</p>',
             f'<p>{MODEL_TEXT}</p>', not_separable,
             '<h2>Simulation error of the speed</h2>',
             _table(['', 'speed NRMSE'],
                    [['regression start', pct_text(before.get('speed_nrmse_pct'))],
                     ['fitted model', pct_text(after.get('speed_nrmse_pct'))]]),
             '<p>NRMSE: root-mean-square of (simulated - measured) speed in percent of the '
             "measured speed's range, over the whole of every record.</p>",
             f'<img src="{images[0]}" alt="measured vs simulated speed">',
             f'<img src="{images[1]}" alt="speed error">',
             '<h2>Parameters</h2>',
             _table(['parameter', 'value', 'std. error', '95 % interval', 'rel. error',
                     'unit', "of the motor's parameters"], _rows(result)),
             f'<p>Standard errors: {html.escape(str(result.get("uncertainty_method", "")))}.'
             '</p>']
    if warnings:
        parts += ['<h2>Warnings</h2>', f'<ul>{warnings}</ul>']
    if validation is not None:
        parts += _validation_parts(directory, validation, dict(CHANNEL_UNITS))
    return _write_page(directory, 'index.html', 'dcmotor_id report', parts)
