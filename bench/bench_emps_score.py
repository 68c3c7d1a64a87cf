"""
EMPS scored as the benchmark community scores it: position RMSE on DATA_EMPS_PULSES.

Trains on DATA_EMPS and simulates DATA_EMPS_PULSES open loop from the force ``gtau * vir``;
the score is the position RMSE in mm after the first 20 samples. The published IDIM-LS
parameters, the 4-parameter rigid-model output-error fits and the extensions tried are computed
in the same run (:func:`studies.emps.emps_score`), with the friction of each record and two
diagnosis fits on PULSES that show what limits the score.

    EMPS_DATA_DIR=data/emps python bench/bench_emps_score.py [--out FILE.md]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from typing import Any, Mapping

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from studies.emps import emps_score, find_data_dir, format_score  # noqa: E402

#: The reading options of the README's EMPS commands (``.mat`` variables, units).
READING = ['--column', 'current=vir', '--column', 'position=qm', '--position-unit', 'm']
#: The README's identify commands, by row label: extra options after the reading ones.
PRODUCT_COMMANDS = {
    'identify, the loop with --extended-vocabulary (the README command)':
        ['--extended-vocabulary', '--max-time', '600'],
    'identify, the loop with the standard vocabulary': ['--max-time', '600'],
    'identify --no-discover': ['--no-discover', '--max-time', '600'],
}


def _cli(arguments: list[str]) -> tuple[int, str, float]:
    """Run ``python -m dcmotor_id.cli``; return the exit code, stderr and its CPU time [s]."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([sys.executable, '-m', 'dcmotor_id.cli', *arguments],
                          capture_output=True, text=True, cwd=os.path.dirname(HERE),
                          check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return done.returncode, done.stderr, (after.ru_utime - before.ru_utime
                                          + after.ru_stime - before.ru_stime)


def product_rows(data_dir: str | None, gtau: float) -> list[dict[str, Any]]:
    """
    EMPS through the product path: the README's identify commands, then validate on PULSES.

    Every row runs ``dcmotor-id identify DATA_EMPS.mat ... --torque-constant GTAU --json`` and
    ``dcmotor-id validate MODEL.json DATA_EMPS_PULSES.mat ... --json`` as a user would and
    reads the position RMSE from validate's JSON.
    """
    directory = find_data_dir(data_dir)
    estimation = os.path.join(directory, 'DATA_EMPS.mat')
    validation = os.path.join(directory, 'DATA_EMPS_PULSES.mat')
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for label, extra in PRODUCT_COMMANDS.items():
            model, scores = os.path.join(work, 'model.json'), os.path.join(work, 'scores.json')
            start = time.perf_counter()
            code, err, cpu = _cli(['identify', estimation, *READING, '--torque-constant',
                                   f'{gtau:.10g}', *extra, '--json', model, '--quiet'])
            wall = time.perf_counter() - start
            row: dict[str, Any] = {'model': label, 'command': extra, 'exit': code,
                                   'wall_s': wall, 'cpu_s': cpu}
            if code != 0:
                row['error'] = err.strip()
                rows.append(row)
                continue
            code, err, _ = _cli(['validate', model, validation, *READING, '--json', scores])
            with open(model, encoding='utf-8') as stream:
                result = json.load(stream)
            with open(scores, encoding='utf-8') as stream:
                record = json.load(stream)['records'][0]
            row.update(result=result, position_rmse_mm=1e3 * record['position_rmse'],
                       fit_position_pct=record['fit_pct']['position'])
            rows.append(row)
    return rows


def _effects_text(result: Mapping[str, Any]) -> str:
    """Return the effects of a result as text."""
    return '; '.join(f"{effect['name']} " + ', '.join(
        f'{key} {value:.4g}' for key, value in effect['parameters'].items())
        for effect in result['effects']) or 'none'


def product_table(rows: list[dict[str, Any]], score: Mapping[str, Any]) -> str:
    """Return the markdown table of the product rows beside the baselines of the same run."""
    lines = ['| model (trained on DATA_EMPS) | criterion | M [kg] | Fv [N s/m] | Fc [N] | effects '
             '| PULSES position RMSE [mm] | PULSES fit position | identify time (wall / CPU) |',
             '|---|---|---|---|---|---|---|---|---|']
    for row in rows:
        if row['exit'] != 0:
            lines.append(f"| {row['model']} | | | | | refused: {row.get('error', '')} | | | |")
            continue
        result = row['result']
        p = result['parameters']
        lines.append(f"| {row['model']} | {result['criterion']} | {p['J']:.2f} | {p['b']:.1f} "
                     f"| {p['Mc']:.2f} | {_effects_text(result)} | "
                     f"**{row['position_rmse_mm']:.2f}** | {row['fit_position_pct']:.2f} % | "
                     f"{row['wall_s']:.0f} s / {row['cpu_s']:.0f} s |")
    for start in ('published IDIM-LS', '4-parameter rigid model, output error on position'):
        base = _row(score, start)
        p = base['parameters']
        lines.append(f"| baseline: {base['model']} | | {p['J']:.2f} | {p['b']:.1f} | "
                     f"{p['Mc']:.2f} | {_effects_text(base)} | "
                     f"**{base['validation']['position_rmse_mm']:.2f}** | "
                     f"{base['validation']['fit_position_pct']:.2f} % | |")
    return '\n'.join(lines)


def rounds_text(rows: list[dict[str, Any]]) -> str:
    """Return what the loop decided in each round: per candidate, the gains that decided."""
    out = []
    for row in rows:
        discovery = (row.get('result') or {}).get('discovery') or {}
        if not discovery.get('steps'):
            continue
        out.append(f"{row['model']} (stopped: {discovery.get('reason')}):")
        for number, step in enumerate(discovery['steps'], 1):
            added = step.get('added')
            parts = []
            for candidate in step['candidates']:
                if candidate['heldout_gain_pct'] is None:
                    continue
                refused = f", refused: {candidate['rejected']}" if candidate['rejected'] else ''
                parts.append(f"{candidate['name']} in-sample "
                             f"{candidate['insample_gain_pct']:.1f} %, held-out "
                             f"{candidate['heldout_gain_pct']:.1f} % (noise "
                             f"{candidate['heldout_gain_noise_pct']:.1f} %){refused}")
            out.append(f"- round {number}: added {added['name'] if added else 'nothing'}; "
                       + '; '.join(parts))
    return '\n'.join(out)


def _row(score: Mapping[str, Any], start: str) -> Mapping[str, Any]:
    """Return the first row whose label starts with ``start``."""
    return next(row for row in score['rows'] if row['model'].startswith(start))


def difference_text(score: Mapping[str, Any]) -> str:
    """Return the paragraph on the friction difference between the two records."""
    before, after = score['friction']['estimation'], score['friction']['validation']
    speed = 0.1
    forward = (after['Fc_pos'] - before['Fc_pos']) + speed * (after['Fv_pos'] - before['Fv_pos'])
    backward = (after['Fc_neg'] - before['Fc_neg']) + speed * (after['Fv_neg']
                                                               - before['Fv_neg'])
    best = _row(score, 'position output error + viscous_asymmetry')
    diagnosis = _row(score, 'diagnosis, not a score: position output error')
    level = before['Fc_pos'] + speed * before['Fv_pos']
    drift_mm = 1e3 * 1.0 / best['parameters']['b'] * 2.0
    return ("What limits the score: the friction of the two records differs. The benchmark's "
            'direction-dependent IDIM-LS on each record (table above) gives the PULSES record '
            f'{after["Fc_pos"] - before["Fc_pos"]:+.2f} N / '
            f'{after["Fc_neg"] - before["Fc_neg"]:+.2f} N of Coulomb friction (forward / '
            f'backward) and {after["Fv_pos"] - before["Fv_pos"]:+.1f} / '
            f'{after["Fv_neg"] - before["Fv_neg"]:+.1f} N s/m of viscous friction more than '
            f'DATA_EMPS: {forward:+.2f} N forward and {backward:+.2f} N backward at '
            f'{speed:g} m/s ({100 * forward / level:.0f} % of the forward friction there), '
            'on the same trajectory. Integrated over a 2 s move at the fitted Fv '
            f"{best['parameters']['b']:.0f} N s/m, 1 N is {drift_mm:.0f} mm of position. The "
            'best structure fitted on PULSES reaches '
            f'{diagnosis["validation"]["position_rmse_mm"]:.2f} mm there and '
            f'{diagnosis["estimation"]["position_rmse_mm"]:.2f} mm on DATA_EMPS, the mirror of '
            f'{best["validation"]["position_rmse_mm"]:.2f} mm / '
            f'{best["estimation"]["position_rmse_mm"]:.2f} mm fitted on DATA_EMPS: the model '
            'structure reproduces a record it was fitted on, and the 4 mm goal is out of reach '
            "of any model fitted on DATA_EMPS alone unless it guesses the other record's "
            f'friction. {extensions_text(score)}')


def _effect(row: Mapping[str, Any], name: str) -> Mapping[str, Any]:
    """Return the parameters of one effect of a row."""
    return next(e['parameters'] for e in row['effects'] if e['name'] == name)


def _pulses_mm(row: Mapping[str, Any]) -> str:
    """Return a row's PULSES score as text."""
    return f"{row['validation']['position_rmse_mm']:.2f} mm"


def extensions_text(score: Mapping[str, Any]) -> str:
    """Return what each extension fitted (the values behind the judgement of the README)."""
    best = _row(score, 'position output error + viscous_asymmetry')
    stribeck = _row(score, 'position output error + viscous_asymmetry + stribeck')
    drag = _row(score, 'position output error + viscous_asymmetry + quadratic_drag')
    cogging = _row(score, 'position output error + viscous_asymmetry + force periodic in '
                          'position (cogging, period 58')
    again = _row(score, 'diagnosis, not a score: + force periodic')
    lag = _row(score, 'position output error + viscous_asymmetry + first-order lag')
    halves = [_row(score, f'position output error + viscous_asymmetry, {half} half')
              for half in ('first', 'second')]
    spread = max(abs(half['parameters'][name] / best['parameters'][name] - 1)
                 for half in halves for name in ('J', 'b', 'Mc'))
    found, refit = _effect(cogging, 'cogging'), _effect(again, 'cogging')
    strib = _effect(stribeck, 'stribeck')
    coefficient = _effect(drag, 'quadratic_drag')['coefficient_Nm_s2']
    phase = float(np.angle(np.exp(1j * found['phase_rad'])))
    phase_again = float(np.angle(np.exp(1j * refit['phase_rad'])))
    return ('The extensions, fitted on DATA_EMPS: Stribeck friction (excess '
            f"{strib['excess_Nm']:.1f} N, velocity {strib['velocity_rad_s']:.3g} m/s) "
            f'{_pulses_mm(stribeck)}; quadratic drag (coefficient {coefficient:.0f} N s^2/m^2 '
            f"with Fv {drag['parameters']['b']:.1f} N s/m) {_pulses_mm(drag)}; a force periodic "
            f'in position with the 58 mm period the discovery loop finds {_pulses_mm(cogging)} '
            f"(amplitude {found['amplitude_Nm']:.2f} N, phase {phase:.2f} rad, M "
            f"{cogging['parameters']['J']:.1f} kg; fitted on PULSES: amplitude "
            f"{refit['amplitude_Nm']:.2f} N, phase {phase_again:.2f} rad, M "
            f"{again['parameters']['J']:.1f} kg); a first-order lag of the force (time "
            f"constant {lag['input_lag_s'] * 1e3:.2f} ms) {_pulses_mm(lag)}. Stribeck, drag and "
            'the periodic force lower the DATA_EMPS error and none carries over: the Stribeck '
            f"fit moves friction from Coulomb to viscous (Fc {stribeck['parameters']['Mc']:.1f} "
            f"N, Fv {stribeck['parameters']['b']:.0f} N s/m), the drag fit drives the viscous "
            'coefficient below zero, and a ripple whose amplitude and phase change between two '
            'records of the same machine (with a mass that moves with it) fits the shared '
            'trajectory, not a property of the drive. The same structure as the best row fitted '
            f'on either half of DATA_EMPS scores {_pulses_mm(halves[0])} and '
            f'{_pulses_mm(halves[1])} with M, Fv, Fc within {100 * spread:.1f} % of the full '
            'fit: the score moves by several mm with the training data, so differences of about '
            '1 mm between rows do not rank the models.')


def main() -> int:
    """Run the score and write the markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('data_dir', nargs='?')
    parser.add_argument('--out', default=os.path.join(HERE, 'emps_score_results.md'))
    args = parser.parse_args()
    load = os.getloadavg()
    start = time.perf_counter()
    score = emps_score(args.data_dir)
    products = product_rows(args.data_dir, score['gtau'])
    seconds = time.perf_counter() - start
    pulses = score['pulses']
    text = ['# EMPS: position RMSE on the PULSES validation record', '',
            'Command: `EMPS_DATA_DIR=data/emps python bench/bench_emps_score.py` '
            f'({seconds:.0f} s; load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} at '
            'the start, 2 shared cores). Every model is trained on DATA_EMPS and simulated '
            'open loop on DATA_EMPS_PULSES from the force gtau * vir (exact simulation, '
            'stick-slip included), initial speed estimated on the first 20 samples; score = '
            'position RMSE after those 20 samples (`dcmotor_id.identification.validate`). '
            'The two rows '
            'marked "diagnosis" are fitted on PULSES itself: they are not scores, they measure '
            'how far the two records differ.', '',
            '## Through the product path', '',
            'As the README tells a user: `dcmotor-id identify DATA_EMPS.mat --column '
            'current=vir --column position=qm --position-unit m --torque-constant '
            f"{score['gtau']:.10g} [options] --json model.json`, then `dcmotor-id validate "
            'model.json DATA_EMPS_PULSES.mat` with the same reading options (its '
            '`position_rmse`; initial state from the first 20 samples, not scored). The '
            'position is the only measured motion channel, so the criterion is `position` '
            '(auto). Baselines from the same run below.', '',
            product_table(products, score), '', 'The loop, round by round (gains of the '
            'candidates refitted; in-sample: training part, held-out: the last 30 % of the '
            'motion, open-loop simulation; an effect is added when its held-out drop is '
            'significant by the default rule, the held-out t test on the innovations of an '
            "AR(1) error model of each structure's held-out residual (a drifting "
            'position residual judged on its increments), `discovery/judging.py`):', '',
            rounds_text(products), '',
            '## The study (studies/emps.py)', '',
            format_score(score), '', difference_text(score), '',
            f'The force pulses: {pulses["pulses"]} onsets of `pulses_N` (height '
            f'{pulses["pulse_height"]:g}); at each onset the recorded `vir` of the PULSES '
            'record jumps against the DATA_EMPS one by a median '
            f'{pulses["median_jump_of_vir_at_onset"]:.3f} V in one sample, i.e. the pulse is '
            'in the recorded input (a step no position loop produces within one sample), and '
            'the position loop then pulls it back (the carriage moves at most '
            f'{pulses["max_position_difference_m"] * 1e3:.3f} mm off the DATA_EMPS path). '
            'The open-loop model therefore sees the pulses as force, and they are not what '
            'limits the score: away from the pulses (pulse off, 200 ms after its last change) '
            'the PULSES record still needs '
            f"{pulses['settled_force_difference_N']['forward']:+.2f} N moving forward and "
            f"{pulses['settled_force_difference_N']['backward']:+.2f} N moving backward against "
            'DATA_EMPS on the same trajectory (more friction both ways): the friction difference '
            'above.',
            '']
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(text))
    print('\n'.join(text))
    return 0


if __name__ == '__main__':
    sys.exit(main())
