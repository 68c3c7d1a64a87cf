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

The figures are drawn by :mod:`dcmotor_id.reports.identification_plots`; this module writes
the page around them.
"""

from __future__ import annotations

import html
import os
import re
from typing import Any, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.reports.identification_plots import (CHANNEL_UNITS, fit_series, input_series,
                                                     pct_text, plot_fit, plot_residuals,
                                                     plot_steps, plot_transients)

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.discovery import DiscoveryResult
    from dcmotor_id.identification.validate import Validation

#: z of the two-sided 95 % interval of the parameter table.
Z95 = 1.959964


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
             pct_text(100 * item['share'])] for item in info['structures']]
    part = info.get('stderr_structure') or {}
    without = info.get('stderr_without_structure') or {}
    changed = [[name, _number(without.get(name, float('nan')), 3), _number(value, 3),
                _number(result['stderr'].get(name, float('nan')), 3)]
               for name, value in part.items() if value and np.isfinite(value)]
    text = (f'<p>Noise bootstrap: {info["completed"]} of {info["resamples"]} resamples '
            f'identified ({info["failed"]} refused), discovery rerun on each; the structure of '
            f'this result was chosen on {pct_text(100 * info["chosen_share"])} of them. ' +
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
    if result.get('mode') == 'voltage_speed':  # kS, kV, kA: a page of its own
        from dcmotor_id.reports.voltage_speed import write_voltage_speed_report
        return write_voltage_speed_report(directory, result, records or [],
                                          validation=validation)
    os.makedirs(directory, exist_ok=True)
    units = dict(CHANNEL_UNITS, **(channel_units or {}))
    series, outputs = fit_series(found, records, result)
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
    input_name, input_values = input_series(series, records, found, result)
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
             _units_paragraph(result, outputs_of(result)),
             f'<p class="{verdict_class}">{verdict}</p>',
             '<h2>Simulation error</h2>',
             _table(['', 'current NRMSE', 'speed NRMSE'],
                    [['base model', pct_text(errors['before']['current_nrmse_pct']),
                      pct_text(errors['before']['speed_nrmse_pct'])],
                     ['final model', pct_text(errors['after']['current_nrmse_pct']),
                      pct_text(errors['after']['speed_nrmse_pct'])]]),
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


def outputs_of(result: Mapping[str, Any]) -> list[str]:
    """Return the channels of the records the report speaks of: the input and the outputs."""
    channels = {'mechanical': ['current', 'speed'],
                'voltage_speed': ['voltage', 'speed']}.get(str(result.get('mode')),
                                                           ['voltage', 'current', 'speed'])
    if (result.get('position_error') or result.get('criterion') in ('position', 'both')):
        channels.append('position')
    return channels


def _units_paragraph(result: Mapping[str, Any], channels: Sequence[str]) -> str:
    """
    Return the paragraph that says in which units the file gave each channel ('' if unknown).

    From the result's ``input_units`` (written by ``dcmotor-id identify``): a channel given
    in other units than SI is named with its unit and factor, so that a plot in rad/s of a
    column written in rpm is not read as wrong.
    """
    units = result.get('input_units')
    if not units:
        return ''
    converted, as_given = [], []
    for channel in channels:
        unit = units.get(channel)
        if unit is None:
            continue
        flipped = ' (sign flipped)' if unit.get('negated') else ''
        if unit['given'] == unit['si'] and unit['factor'] == 1.0:
            as_given.append(f'{channel} in {unit["si"]}{flipped}')
        else:
            factor = '' if unit['factor'] is None else f', x {unit["factor"]:.6g}'
            converted.append(f'{channel} from {unit["given"]} to {unit["si"]}{factor}{flipped}')
    parts = []
    if converted:
        parts.append('converted on reading: ' + '; '.join(converted))
    if as_given:
        parts.append(('read as given: ' if converted else 'the file gave ')
                     + ', '.join(as_given) + ('' if converted else ' (SI, nothing converted)'))
    return ('<p class="units"><b>Units of the input</b>: ' + html.escape('; '.join(parts))
            + '. Every number and plot of this page is in SI units.</p>')


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
    outputs = list(validation.model.outputs)  # (a voltage-to-speed model: the speed alone)
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
                     pct_text(item['current_nrmse_pct']), pct_text(item['speed_nrmse_pct']),
                     pct_text(fits['current']), pct_text(fits['speed']),
                     pct_text(fits['position']), _number(item['position_rmse'], 4)])
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
                            title: str = 'DC motor model: validation on new records',
                            input_units: Mapping[str, Any] | None = None) -> str:
    """
    Write ``validation.html`` and its PNGs (``validate --report DIR``); return its path.

    ``input_units`` (:meth:`~dcmotor_id.formats.mapping.ReadOptions.input_units`): the units
    the files gave each channel in, said under the title.
    """
    os.makedirs(directory, exist_ok=True)
    units = dict(CHANNEL_UNITS, **(channel_units or {}))
    model = validation.model
    parameters = ', '.join(f'{name} = {_number(value)}' for name, value
                           in model.parameters.items())
    effects = ', '.join(effect['name'] for effect in model.effects) or 'none'
    parts = [f'<h1>{html.escape(title)}</h1>',
             f'<p>Model ({html.escape(model.mode)}): {html.escape(parameters)}; effects: '
             f'{html.escape(effects)}.</p>']
    channels = ['current', 'speed'] if model.mechanical_only else ['voltage', 'current',
                                                                   'speed']
    if all(item.record.position is not None for item in validation.records):
        channels.append('position')
    parts.append(_units_paragraph({'input_units': input_units}, channels))
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
