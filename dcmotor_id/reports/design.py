"""
The design page of the report: ``design.html`` with step responses and Bode plots.

``dcmotor-id design RESULT.json --report DIR`` writes, into ``DIR``:

* ``design_steps.png``: unit-step responses of the closed current loop (``i_ref -> i``) and
  of the closed speed loop (``w_ref -> w``), nominal and with the motor at the ends of every
  parameter's 95 % interval and at the worst corner of the intervals' box;
* ``design_bode.png``: Bode plots of both open loops with the gain crossover and the phase
  margin (red) and the phase crossover and gain margin (green, when below 0.95 Nyquist);
* ``design.html``: the gains, the feedforward, the margins and bandwidths, the robustness table.

Plots use matplotlib's object interface with the Agg canvas (no display, no global state).
"""

from __future__ import annotations

import html
import math
import os

import control
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

from dcmotor_id.design.control import Gains, interval_motors, loops
from dcmotor_id.design.plant import Motor

_NOMINAL = '#1f77b4'
_ENDS = '0.65'
_WORST = '#d62728'


def _save(figure: Figure, directory: str, name: str) -> str:
    FigureCanvasAgg(figure)
    figure.savefig(os.path.join(directory, name), dpi=110, bbox_inches='tight')
    return name


def _step(system: control.LTI, duration: float, dt: float | None) -> tuple:
    times = np.linspace(0.0, duration, 600) if dt is None else np.arange(0.0, duration, dt)
    response = control.step_response(system, times)
    return response.time, np.squeeze(response.outputs)


def step_figure(motor: Motor, gains: Gains, result: dict) -> Figure:
    """Return the figure of the closed-loop step responses (nominal and interval ends)."""
    ends, corners, _ = interval_motors(motor)
    worst = result['robustness'].get('worst_corner')
    cases = [('nominal', motor, _NOMINAL, 2.0)]
    cases += [(f'{name} {side}', perturbed, _ENDS, 0.8) for name, side, perturbed in ends]
    if worst:
        cases.append(('worst corner', motor.with_values(**worst['parameters']), _WORST, 1.4))
    panels = [('speed', 'w_ref -> w', 3.0 / result['requested']['speed_bandwidth_hz'])]
    if motor.mode == 'full':
        panels.insert(0, ('current', 'i_ref -> i',
                          3.0 / result['requested']['current_bandwidth_hz']))
    figure = Figure(figsize=(10, 3.6))
    for k, (loop, label, duration) in enumerate(panels):
        axis = figure.add_subplot(1, len(panels), k + 1)
        for index, (name, perturbed, colour, width) in enumerate(cases):
            systems = loops(perturbed, gains)
            system = systems['current_closed'] if loop == 'current' else \
                systems['speed_closed'][0, 0]
            times, values = _step(system, duration, gains.dt)
            show = name if index < 2 or colour != _ENDS else None
            if colour == _ENDS and index == 1:
                show = 'interval ends (one at a time)'
            axis.plot(times * 1e3, values, color=colour, lw=width, label=show,
                      zorder=3 if colour != _ENDS else 2)
        axis.axhline(1.0, color='k', lw=0.6, ls=':')
        axis.set_title(f'{loop} loop step ({label})')
        axis.set_xlabel('time [ms]')
        axis.set_ylabel('response to a unit step')
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc='lower right')
    figure.tight_layout()
    return figure


def bode_figure(motor: Motor, gains: Gains, result: dict) -> Figure:
    """Return the Bode plots of the open loops with crossover and margins marked."""
    systems = loops(motor, gains)
    names = [('speed', systems['speed_open'])]
    if 'current_open' in systems:
        names.insert(0, ('current', systems['current_open']))
    figure = Figure(figsize=(10, 6))
    top = math.pi / gains.dt if gains.dt else None
    for k, (loop, system) in enumerate(names):
        metrics = result['nominal'][loop]
        crossover = 2 * math.pi * metrics['crossover_hz']
        high = crossover * 300 if top is None else top * 0.95
        omega = np.logspace(math.log10(crossover) - 3, math.log10(high), 800)
        response = system.frequency_response(omega)
        magnitude = 20 * np.log10(np.squeeze(response.magnitude))
        phase = np.degrees(np.unwrap(np.squeeze(response.phase)))
        frequency = omega / (2 * math.pi)
        gain_axis = figure.add_subplot(2, len(names), k + 1)
        phase_axis = figure.add_subplot(2, len(names), k + 1 + len(names), sharex=gain_axis)
        gain_axis.semilogx(frequency, magnitude, color=_NOMINAL)
        phase_axis.semilogx(frequency, phase, color=_NOMINAL)
        gain_axis.axhline(0.0, color='k', lw=0.6)
        phase_axis.axhline(-180.0, color='k', lw=0.6)
        for axis in (gain_axis, phase_axis):
            axis.axvline(metrics['crossover_hz'], color=_WORST, lw=0.8, ls='--')
            axis.grid(alpha=0.3, which='both')
        gm = metrics['gain_margin_db']
        gm_text = 'inf' if gm is None or not np.isfinite(gm) else f'{gm:.1f} dB'
        gain_axis.set_title(f"{loop} open loop: crossover {metrics['crossover_hz']:.4g} Hz, "
                            f"PM {metrics['phase_margin_deg']:.1f} deg, GM {gm_text}",
                            fontsize=9)
        gain_axis.set_ylabel('magnitude [dB]')
        phase_axis.set_ylabel('phase [deg]')
        phase_axis.set_xlabel('frequency [Hz]')
        crossing = metrics.get('phase_crossover_hz', float('nan'))
        if np.isfinite(crossing) and crossing <= frequency[-1]:
            at = np.argmin(np.abs(frequency - crossing))
            gain_axis.annotate('', xy=(frequency[at], 0.0), xytext=(frequency[at],
                                                                    magnitude[at]),
                               arrowprops={'arrowstyle': '<->', 'color': '#2ca02c'})
            phase_axis.axvline(crossing, color='#2ca02c', lw=0.8, ls='--')
        index = np.argmin(np.abs(frequency - metrics['crossover_hz']))
        phase_axis.annotate('', xy=(frequency[index], -180.0), xytext=(frequency[index],
                                                                       phase[index]),
                            arrowprops={'arrowstyle': '<->', 'color': _WORST})
    figure.tight_layout()
    return figure


def _row(cells: list, header: bool = False) -> str:
    tag = 'th' if header else 'td'
    return '<tr>' + ''.join(f'<{tag}>{html.escape(str(cell))}</{tag}>' for cell in cells) + \
        '</tr>'


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f'{value:.4g}' if np.isfinite(value) else ('inf' if value > 0 else str(value))
    return '' if value is None else str(value)


#: The page's style: a table wider than the page scrolls in its own box (``.wide``).
_STYLE = ('body{font-family:sans-serif;max-width:1100px;margin:auto}'
          'table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:2px 8px}'
          'th{font-weight:normal;background:#eee;vertical-align:bottom}'
          '.wide{max-width:100%;overflow-x:auto}img{max-width:100%}')


def metric_heading(key: str) -> str:
    """
    Return the robustness table's heading of a metric key, in words that wrap.

    ``speed.phase_margin_deg`` -> ``speed phase margin [deg]`` (a key is one unbreakable word
    that widened the table beyond the page).
    """
    loop, _, metric = key.partition('.')
    words = metric.split('_')
    unit = {'deg': 'deg', 'db': 'dB', 'hz': 'Hz'}.get(words[-1])
    name = ' '.join(words[:-1] if unit else words)
    return f'{loop} {name}' + (f' [{unit}]' if unit else '')


def write_design_report(directory: str, result: dict, motor: Motor, gains: Gains) -> str:
    """
    Write ``design.html`` and its PNGs into ``directory``; return the page's path.

    Parameters
    ----------
    directory : str
        Created when missing.
    result : dict
        The design (:func:`dcmotor_id.design.control.design`).
    motor, gains : Motor, Gains
        The motor and the gains of the design.

    """
    os.makedirs(directory, exist_ok=True)
    steps = _save(step_figure(motor, gains, result), directory, 'design_steps.png')
    bode = _save(bode_figure(motor, gains, result), directory, 'design_bode.png')
    parts = ['<!DOCTYPE html><html><head><meta charset="utf-8"><title>dcmotor_id design'
             f'</title><style>{_STYLE}</style></head><body><h1>Controller design</h1>']
    dt = result['sample_period_s']
    parts.append(f"<p>mode {result['mode']}, {result['shaft']} shaft, gear ratio "
                 f"{result['gear_ratio']:g}, "
                 + (f'sample period {dt:g} s (Tustin PIs, ZOH plant)' if dt else 'continuous')
                 + f"; source {html.escape(str(result.get('source', '')))}</p>")
    parts += _gain_rows(result)
    ff = result['feedforward']
    parts.append(f"<h2>Feedforward</h2><p>{html.escape(ff['convention'])}: kS = "
                 f"{ff['kS']:.5g} {ff['units']['kS']}, kV = {ff['kV']:.5g} {ff['units']['kV']}, "
                 f"kA = {ff['kA']:.5g} {ff['units']['kA']}</p>")
    parts.append(f'<h2>Step responses</h2><img src="{steps}" alt="step responses">')
    parts.append(f'<h2>Open loops</h2><img src="{bode}" alt="Bode plots">')
    parts += _robustness_rows(result['robustness'])
    if result['notes']:
        parts.append('<h2>Notes</h2><ul>' + ''.join(f'<li>{html.escape(note)}</li>'
                                                    for note in result['notes']) + '</ul>')
    parts.append('</body></html>')
    path = os.path.join(directory, 'design.html')
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(parts))
    return path


def _gain_rows(result: dict) -> list[str]:
    """Return the table of the gains and the nominal loop metrics."""
    parts = ['<h2>Gains</h2><table>' + _row(['loop', 'kp', 'ki', 'Ti [s]', 'asked [Hz]',
                                             'bandwidth [Hz]', 'crossover [Hz]',
                                             'phase margin [deg]', 'gain margin [dB]'],
                                            True)]
    for name, loop in (('current_loop', 'current'), ('speed_loop', 'speed')):
        if name not in result:
            continue
        gains_ = result[name]
        metrics = result['nominal'][loop]
        parts.append(_row([loop, f"{gains_['kp']:.5g} {gains_['units']['kp']}",
                           f"{gains_['ki']:.5g} {gains_['units']['ki']}", _fmt(gains_['ti_s']),
                           _fmt(result['requested'][f'{loop}_bandwidth_hz']),
                           _fmt(metrics['bandwidth_hz']), _fmt(metrics['crossover_hz']),
                           _fmt(metrics['phase_margin_deg']),
                           _fmt(metrics['gain_margin_db'])]))
    parts.append('</table>')
    return parts


def _robustness_rows(robust: dict) -> list[str]:
    """Return the table of the nominal gains' metrics across the 95 % intervals."""
    keys = list(robust['range'])
    parts = ['<h2>Robustness: the nominal gains across the 95 % intervals</h2>'
             '<div class="wide"><table>'
             + _row(['parameter', 'end', 'value'] + [metric_heading(key) for key in keys],
                    True)]
    for row in robust['one_at_a_time']:
        parts.append(_row([row['parameter'], row['end'], _fmt(row['value'])]
                          + [_fmt(row.get(key)) for key in keys]))
    parts.append(_row(['all', f"min over ends and {robust['corners']} corners", '']
                      + [_fmt(robust['range'][key][0]) for key in keys]))
    parts.append(_row(['all', f"max over ends and {robust['corners']} corners", '']
                      + [_fmt(robust['range'][key][1]) for key in keys]))
    parts.append('</table></div>')
    return parts
