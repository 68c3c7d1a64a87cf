"""
The EMPS study's tables and the acceptance rules' verdicts on EMPS, as a committed results file.

Writes what ``python -m studies.emps`` prints (the published IDIM-LS reproduced, the force
equation and speed simulation errors of IDIM-LS and output error, the discovery loop on the
speed) and, for the discovery loop on the speed (``criterion='speed'``) and on the position
(the README command, through the command line in this process), the t test each acceptance
rule made of the winning candidate: its held-out gain, t, the effective samples (or
innovations) and the t needed, under the default rule and under ``heldout-t``, with the effects
each run added and, on the speed, the PULSES speed error of the result.  ``docs/emps.md``
quotes its numbers from this file (``tools/generate_docs.py``).

    EMPS_DATA_DIR=data/emps python bench/bench_emps_study.py [--out FILE.md]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
import time
from typing import Any
from unittest import mock

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from dcmotor_id.identification.discovery import judging  # noqa: E402
from dcmotor_id.identification.discovery.state import DEFAULT_ACCEPTANCE  # noqa: E402
from studies.emps import (emps_study, ESTIMATION_FILE, find_data_dir, format_study,  # noqa
                          load_emps, VALIDATION_FILE)

from common import judged_by  # noqa: E402,I100  (bench/common.py, beside this script)

#: The reading options of the README's EMPS command (``.mat`` variables, units).
READING = ['--column', 'current=vir', '--column', 'position=qm', '--position-unit', 'm']


def recording(log: list[dict[str, Any]]) -> Any:
    """
    Record every t test the loop makes of a winning candidate (patches ``judging``).

    Each entry: the rule, the candidate, its held-out gain [%], t, the effective samples (or
    innovations), the t needed and the verdict (``added`` or why not).
    """
    original = judging.unearned_heldout_t

    def wrapper(loop, current, candidate, test=None, spread=True):
        inner = test or judging.heldout_t
        entry = {'rule': loop.acceptance, 'candidate': candidate.name,
                 'gain_pct': 100.0 * float(candidate.gain or 0.0)}

        def captured(*args):
            t, effective = inner(*args)
            entry.update(t=t, effective=effective,
                         needed=judging.heldout_t_threshold(effective))
            return t, effective
        verdict = original(loop, current, candidate, captured, spread)
        entry['verdict'] = 'added' if verdict is None else 'not added'
        log.append(entry)
        return verdict
    return mock.patch.object(judging, 'unearned_heldout_t', wrapper)


def speed_loop(directory: str, rule: str) -> dict[str, Any]:
    """Run ``identify --criterion speed`` on DATA_EMPS under ``rule``; the tests and result."""
    from dcmotor_id.identification.identify import identify
    estimation, gtau = load_emps(os.path.join(directory, ESTIMATION_FILE))
    validation, _ = load_emps(os.path.join(directory, VALIDATION_FILE))
    log: list[dict[str, Any]] = []
    with judged_by(rule), recording(log):
        identified = identify([estimation], torque_constant=gtau, criterion='speed')
    pulses = identified.discovery_result.errors_on([validation])
    return {'tests': log, 'result': identified.as_dict(),
            'pulses_speed_pct': pulses['after']['speed_nrmse_pct']}


def position_loop(directory: str, gtau: float, rule: str) -> dict[str, Any]:
    """Run the README's identify command in this process under ``rule``; the tests, result."""
    from dcmotor_id.cli.main import main as cli
    log: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as work:
        out = os.path.join(work, 'model.json')
        with judged_by(rule), recording(log), contextlib.redirect_stdout(io.StringIO()):
            code = cli(['identify', os.path.join(directory, ESTIMATION_FILE), *READING,
                        '--torque-constant', f'{gtau:.10g}', '--extended-vocabulary',
                        '--max-time', '600', '--quiet', '--json', out])
        if code not in (0, None):
            raise RuntimeError(f'identify ended with {code}')
        with open(out, encoding='utf-8') as stream:
            result = json.load(stream)
    return {'tests': log, 'result': result}


def _effects(result: dict[str, Any]) -> str:
    """Return the effects of a result with their parameters, as text."""
    return '; '.join(f"{effect['name']} " + ', '.join(
        f'{key} {value:.4g}' for key, value in effect['parameters'].items())
        for effect in result['effects']) or 'none'


def rules_table(runs: dict[str, dict[str, Any]]) -> str:
    """Return the markdown table of the t tests of every run (criterion, rule, candidate)."""
    lines = ['| criterion | rule | candidate | held-out gain [%] | t | effective samples | '
             't needed | verdict |', '|---|---|---|---|---|---|---|---|']
    for (criterion, rule), run in runs.items():
        for test in run['tests']:
            lines.append(f"| {criterion} | {rule} | {test['candidate']} | "
                         f"{test['gain_pct']:.1f} | {test['t']:.2g} | {test['effective']:.0f} | "
                         f"{test['needed']:.3g} | {test['verdict']} |")
    return '\n'.join(lines)


def results_table(runs: dict[str, dict[str, Any]]) -> str:
    """Return the markdown table of what every run added (and PULSES' speed error)."""
    lines = ['| criterion | rule | effects added | PULSES speed error [%] |', '|---|---|---|---|']
    for (criterion, rule), run in runs.items():
        pulses = run.get('pulses_speed_pct')
        lines.append(f"| {criterion} | {rule} | {_effects(run['result'])} | "
                     f"{'' if pulses is None else f'{pulses:.2f}'} |")
    return '\n'.join(lines)


def commit() -> str:
    """Return the short hash of HEAD, with ``+`` when the tree has changes."""
    import subprocess
    root = os.path.dirname(HERE)
    head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=root, text=True,
                          capture_output=True, check=False).stdout.strip()
    dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'], cwd=root,
                           text=True, capture_output=True, check=False).stdout.strip()
    return head + ('+' if dirty else '')


def main() -> int:
    """Run the study and the rules' runs; write the results file."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('data_dir', nargs='?')
    parser.add_argument('--out', default=os.path.join(HERE, 'emps_study_results.md'))
    args = parser.parse_args()
    directory = find_data_dir(args.data_dir)
    load = os.getloadavg()
    start = time.perf_counter()
    study = emps_study(directory)
    runs: dict[tuple[str, str], dict[str, Any]] = {}
    for rule in (DEFAULT_ACCEPTANCE, 'heldout-t'):
        runs[('speed', rule)] = speed_loop(directory, rule)
    for rule in (DEFAULT_ACCEPTANCE, 'heldout-t'):
        runs[('position', rule)] = position_loop(directory, study['gtau'], rule)
    seconds = time.perf_counter() - start
    text = ['# EMPS: the study (studies/emps.py) and the acceptance rules', '',
            'Command: `EMPS_DATA_DIR=data/emps python bench/bench_emps_study.py` '
            f'(code: commit {commit()}; {seconds:.0f} s; load average {load[0]:.2f}, '
            f'{load[1]:.2f}, {load[2]:.2f} at '
            'the start, 2 shared cores).', '',
            '## The study', '',
            'What `python -m studies.emps` prints: the published IDIM-LS reproduced, each '
            "parameter set's force-equation and speed simulation errors, the discovery loop "
            'on the speed (criterion `speed`, default rule).', '',
            format_study(study), '',
            '## The acceptance rules on EMPS', '',
            'The t test of every winning candidate (`discovery/judging.py`): on the speed '
            '(`identify --criterion speed`) and on the position (the README command, '
            '`--extended-vocabulary`, run through the command line in this process), under the '
            f'default rule `{DEFAULT_ACCEPTANCE}` (t on the innovations of an AR(1) error '
            "model of each structure's held-out residual: effective innovations) and under "
            '`heldout-t` (t on the residual itself: effective samples).', '',
            rules_table(runs), '',
            '### What each run added', '',
            results_table(runs), '']
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(text))
    print(f'wrote {args.out} ({seconds:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
