"""
The text summary of an identification result: the CLI's table, the node's line and key-values.

One result (the dict of :func:`dcmotor_id.identification.identify.identify`) is rendered three
ways, all from
here: :func:`format_table` for ``dcmotor-id identify``, :func:`format_line` for the answer of
the identifier node's ``~/identify``, and :func:`result_key_values` (and
:func:`online_key_values` and :func:`online_text` for the online estimate) for its
``DiagnosticStatus`` messages.
Key-values carry numbers at full precision (:func:`format_value`), the texts at a few digits.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from dcmotor_id.core.model import DERIVED_NAMES, PARAMETER_NAMES, UNITS
from dcmotor_id.streaming.online.estimate import INTERVAL_SIGMAS

#: Keys of the result, in order.
RESULT_KEYS = PARAMETER_NAMES + DERIVED_NAMES

KeyValues = list[tuple[str, str]]


def format_value(value: Any) -> str:
    """Full-precision text of a number (``nan`` for None; other values as they print)."""
    if value is None:
        return 'nan'
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return repr(float(value))
    return str(value)


def format_errors(errors: Mapping[str, Any]) -> str:
    """Render simulation errors per channel: ``current 1.2 %, speed 0.8 %`` (None left out)."""
    return ', '.join(f"{key.split('_')[0]} {value:.3g} %" for key, value in errors.items()
                     if value is not None)


def _relative(value: float, stderr: float) -> str:
    """Return the standard error relative to the value in %, or '-' where it has none."""
    if not value or not math.isfinite(stderr):
        return '-'
    return f'{abs(stderr / value) * 100:.3g}%'


def format_table(result: Mapping[str, Any]) -> str:
    """Render a result dict as a readable table (the output of ``dcmotor-id identify``)."""
    lines = [f"method: {result['method']}   mode: {result['mode']}   records: "
             f"{len(result['records'])}   samples: {result['n_samples']}   "
             f"dt: {result['sample_period_s']:.6g} s"
             + (f"   criterion: {result['criterion']}"
                if result.get('criterion', 'speed') != 'speed' else '')]
    lines.append(f"{'parameter':<10}{'value':>16}{'stderr':>14}{'rel.':>10}  unit")
    bounds = result.get('upper_bounds') or {}
    missing = result.get('not_identifiable') or {}
    for name, value in result['parameters'].items():
        err = result['stderr'].get(name, float('nan'))
        err = float('nan') if err is None else err
        unit = result['units'].get(name, '')
        if name in bounds:
            lines.append(f"{name:<10}{'< ' + format(value, '.4g'):>16}{'upper bound':>24}  "
                         f'{unit}')
            continue
        flag = ''
        if name in missing:
            flag = '  (at zero)' if 'bound zero' in missing[name] else '  (see below)'
        shown = format(err, '.3g') if math.isfinite(err) else '-'
        lines.append(f'{name:<10}{value:>16.6g}{shown:>14}{_relative(value, err):>10}  '
                     f'{unit}{flag}')
    for effect in result.get('effects', []):
        parameters = ', '.join(f'{key} = {value:.4g}' if isinstance(value, float) else
                               f'{key} = {value}' for key, value in
                               effect['parameters'].items())
        lines.append(f"effect {effect['name']}: {parameters}")
    detail = result.get('errors') or {}
    if detail.get('records'):
        lines += _record_error_lines(detail, result)
    else:
        lines.append(f"simulation error before: {format_errors(result['error_before'])}")
        lines.append(f"simulation error after:  {format_errors(result['error_after'])}")
    if result.get('unexplained'):
        lines.append('structure remains in the residual that no candidate effect explains')
    if result.get('uncertainty_method'):
        lines.append(f"stderr: {result['uncertainty_method']}")
    for name, reason in missing.items():
        lines.append(f'not identifiable: {name}: {reason}')
    for text in result.get('warnings') or []:
        lines.append(f'warning: {text}')
    return '\n'.join(lines)


def _record_error_lines(detail: Mapping[str, Any], result: Mapping[str, Any]) -> list[str]:
    """Per-record simulation errors, each in percent of its own record, labelled by part."""
    lines = []
    fraction = detail.get('heldout_fraction')
    heldout = (f'held-out end carrying the last {fraction * 100:.0f} % of the excitation'
               if fraction is not None else None)
    lines.append('simulation error (NRMSE, % of the spread of each whole record; fit % = 100 - '
                 'NRMSE):')
    if heldout:
        lines.append(f"  all records, {heldout}: before {format_errors(result['error_before'])}"
                     f"; after {format_errors(result['error_after'])} (spread of all records)")
    for index, item in enumerate(detail['records']):
        name = item.get('source') or f'record {index + 1}'
        text = (f"  {name}: whole record {_metric_text(item['before']['whole_record'])} -> "
                f"{_metric_text(item['after']['whole_record'])}")
        if heldout:
            if item['after'].get('heldout') is None:
                text += '; held-out part holds steady (no excitation), not judged'
            else:
                segment = (item.get('heldout_segments') or [{}])[0]
                where = (f" from {segment['start_s']:.4g} s" if 'start_s' in segment else '')
                text += (f"; held-out{where} {_metric_text(item['before']['heldout'])} -> "
                         f"{_metric_text(item['after']['heldout'])}")
        lines.append(text)
    return lines


def _metric_text(metrics: Mapping[str, Any] | None) -> str:
    if not metrics:
        return 'n/a'
    return ', '.join(f'{channel} {metrics[f"{channel}_nrmse_pct"]:.3g} %'
                     for channel in ('current', 'speed')
                     if metrics.get(f'{channel}_nrmse_pct') is not None)


def format_line(result: Mapping[str, Any]) -> str:
    """
    Render a result as one line (the answer of ``~/identify``).

    Besides the keys of :func:`~dcmotor_id.identification.identify.identify` it reads ``paper``
    (the paper method's result, or why it failed), ``bags`` and ``record_errors`` when present.
    """
    values = result['parameters']
    text = f"{result['method']}: " + ', '.join(
        f'{key}={values[key]:.5g} {UNITS[key]}' for key in RESULT_KEYS if key in values)
    text += f" ({format_errors(result['error_after'])}; {result['n_samples']} samples in " \
        f"{len(result['records'])} window(s))"
    effects = result.get('effects') or []
    if effects:
        text += '; effects: ' + '; '.join(
            effect['name'] + ' ' + ', '.join(
                f'{k}={v:.4g}' if isinstance(v, (int, float)) else f'{k}={v}'
                for k, v in effect['parameters'].items())
            for effect in effects)
    paper = result.get('paper')
    if isinstance(paper, dict):
        text += '; paper: ' + ', '.join(
            f"{key}={paper['parameters'][key]:.5g}" for key in RESULT_KEYS
            if key in paper['parameters'])
    elif paper:
        text += f'; paper failed: {paper}'
    if result.get('bags'):
        text += '; bags: ' + ', '.join(result['bags'])
    if result.get('record_errors'):
        text += '; not recorded: ' + '; '.join(result['record_errors'])
    if result.get('upper_bounds'):
        text += '; upper bounds: ' + ', '.join(f'{key}<{value:.3g}' for key, value in
                                               result['upper_bounds'].items())
    if result.get('not_identifiable'):
        text += '; not identifiable: ' + ', '.join(result['not_identifiable'])
    if result.get('warnings'):
        text += '; warnings: ' + ' | '.join(result['warnings'])
    return text


def parameter_key_values(parameters: Mapping[str, Any]) -> KeyValues:
    """Key-values of the :data:`RESULT_KEYS` of ``parameters`` (nan where missing)."""
    return [(key, format_value(parameters.get(key, math.nan))) for key in RESULT_KEYS]


def result_key_values(result: Mapping[str, Any]) -> KeyValues:
    """
    Key-values of a result (the ``~/parameters`` message).

    Every key of :data:`RESULT_KEYS`, then ``<key>_stderr``, then
    ``effect.<name>.<parameter>`` of the effects found (nan for a value the result lacks).
    """
    stderr = result['stderr']
    pairs = parameter_key_values(result['parameters'])
    pairs += [(f'{key}_stderr', format_value(stderr.get(key, math.nan)))
              for key in RESULT_KEYS]
    for effect in result.get('effects') or []:
        pairs += [(f"effect.{effect['name']}.{name}", format_value(value))
                  for name, value in effect['parameters'].items()]
    return pairs


def online_key_values(estimate: Any, alarms: Sequence[tuple[str, str]] = ()) -> KeyValues:
    """
    Key-values of an online estimate (``WindowEstimator.estimate``).

    Parameters and ``<key>_stderr`` as in :func:`result_key_values`, then ``converged``
    (``true``/``false``), ``innovation_rms_current_A``, ``innovation_rms_speed_rad_s`` and
    ``n_updates``; then, for an :class:`~dcmotor_id.streaming.online.OnlineEstimate`, ``method``,
    ``status`` (why not converged), ``time_s`` and ``window_s`` (the data behind the
    estimate), ``load_torque_Nm`` and ``load_torque_Nm_stderr`` (nan when not estimated),
    ``fit_cpu_s`` and ``interval_sigmas`` (the published interval is ``value +-
    interval_sigmas * stderr``, simultaneous for the six parameters); last the key-values of
    the change alarms ``alarms`` (:func:`dcmotor_id.streaming.monitoring.alarm_key_values`).
    """
    pairs = [(key, format_value(estimate.parameters[key])) for key in RESULT_KEYS]
    pairs += [(f'{key}_stderr', format_value(estimate.stderr[key])) for key in RESULT_KEYS]
    pairs += [
        ('converged', str(estimate.converged).lower()),
        ('innovation_rms_current_A', format_value(estimate.innovation_rms.get(
            'current', math.nan))),
        ('innovation_rms_speed_rad_s', format_value(estimate.innovation_rms.get(
            'speed', math.nan))),
        ('n_updates', str(estimate.n_updates))]
    if hasattr(estimate, 'method'):
        effects = estimate.effects or {}
        pairs += [
            ('method', estimate.method), ('status', estimate.status),
            ('time_s', format_value(estimate.time_s)),
            ('window_s', format_value(estimate.window_s)),
            ('load_torque_Nm', format_value(effects.get('load_torque_Nm', math.nan))),
            ('load_torque_Nm_stderr', format_value(effects.get('load_torque_Nm_stderr',
                                                               math.nan))),
            ('fit_cpu_s', format_value(estimate.fit_cpu_s)),
            ('interval_sigmas', format_value(INTERVAL_SIGMAS))]
    return pairs + list(alarms)


def paper_status(result: Mapping[str, Any]) -> tuple[str, str, KeyValues] | None:
    """
    Return the level, message and key-values of the ``paper method`` status of a result.

    The paper method's parameters (:func:`parameter_key_values`) when it ran, a ``WARN``
    saying why when it failed, None when it was not asked for.
    """
    paper = result.get('paper')
    if isinstance(paper, dict):
        return ('OK', 'paper method on the same windows (comparison)',
                parameter_key_values(paper['parameters']))
    if paper is not None:
        return 'WARN', f'paper method failed: {paper}', []
    return None


def online_text(estimate: Any, condition: str = '', alarmed: bool = False) -> str:
    """
    Render an online estimate as the message of ``~/online_parameters``.

    ``converged after <n> samples`` (or ``not converged ...``), the estimate's ``status`` in
    parentheses when it has one, and, when ``alarmed``, the ``condition`` message of the
    change alarms (:meth:`dcmotor_id.streaming.monitoring.OnlineMonitor.condition`).
    """
    return (('converged' if estimate.converged else 'not converged') +
            f' after {estimate.n_updates} samples' +
            (f' ({estimate.status})' if estimate.status else '') +
            (f'; {condition}' if alarmed else ''))
