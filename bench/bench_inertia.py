r"""
The inertia check's size and power (issue 29): how often a record is said not to determine J.

:mod:`dcmotor_id.identification.checks.inertia` says J is not determined (records with the
current as the input) when the half range ``h`` of J between the current at the start and at
the end of each sample exceeds 0.5 at the one-sided 1 % level.  This script measures how often
it says so:

* **Power curve**: the robot wheel class (:func:`~dcmotor_id.simulation.lab_scenarios.
  wheel_speed_steps_current_magnitude`, signed current, 30 ms) over a sweep of J, so that the
  mechanical time constant ``J Ra / CPhi^2`` runs from a tenth of a sample to several samples;
  ``--seeds`` noise draws each.  The authors' J of the real log (1.14e-6) is in the sweep.
* **Lab classes**: every scenario of :data:`~dcmotor_id.simulation.lab_scenarios.SCENARIOS`,
  ``--seeds`` draws each, with its true ``b / CPhi`` (the statistic on every record with a
  measured speed and current, also where the pipeline fits the voltage as input and does not
  apply it: the stricter count).
* **Corpus**: every case of ``bench/identify_equivalence.py`` with a CSV of current and speed,
  with the ``b`` and ``CPhi`` (or torque constant) of that case's answer in ``--corpus-out``.
* **Real records**: the wheel log (``--wheels``, the bare clone of BrOleg5/research-wheel-
  slippage), each motor with the current given the sign of the speed (as its authors do) and as
  logged, through ``identify`` end to end (is J flagged, its standard error against the
  authors' J); the HSM150 servo's 12 records (``--hsm150``) singly and together with the
  catalog's ``b``.  MECH 467 and EMPS log a position: their speed is derived and not judged.

Run from the repository root (about a minute)::

    .venv/bin/python bench/bench_inertia.py --corpus-data CORPUS_DATA --corpus-out CORPUS_OUT \
        --wheels .../research-wheel-slippage --hsm150 .../HSM150-data \
        --out bench/inertia_results.md
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from dcmotor_id.core.records import Record  # noqa: E402
from dcmotor_id.formats.csv import read_csv  # noqa: E402
from dcmotor_id.identification.checks.inertia import (inertia_half_range,  # noqa: E402
                                                      inertia_unresolved)
from dcmotor_id.identification.identify import identify, prepare_records  # noqa: E402
from dcmotor_id.simulation import lab_scenarios  # noqa: E402

from common import markdown_table  # noqa: E402,I100  (bench/common.py, beside this script)

#: The sweep of J for the wheel class [kg m^2] (the authors' value among them).
SWEEP_J = (2.5e-7, 5e-7, lab_scenarios.WHEEL_J_AUTHORS, 2.5e-6, 5e-6, 1e-5, 2e-5, 4e-5, 8e-5)
WHEELS_COMMIT = '59fc082'
WHEELS_FILE = 'scripts/dc_motor_kalman_filter/data/data_for_identification_without_integral.csv'
WHEELS_PERIOD_S = 0.03064
WHEELS_K = 0.0514
HSM150_COMMIT = '35c3b1b'
HSM150_K = 0.0458
HSM150_B = 7.03e-5


def _cell(half) -> tuple[str, str, bool]:
    """Return the half range, its z and the flag of one statistic (None: not judged)."""
    if half is None:
        return '-', '-', False
    return f'{half.ratio:.3f} +/- {half.ratio_stderr:.3f}', f'{half.z:.1f}', \
        inertia_unresolved(half)


def sweep_rows(seeds: int) -> list[list[str]]:
    """Return the power curve: the wheel class at 30 ms over J."""
    rows = []
    for inertia in SWEEP_J:
        motor = dataclasses.replace(lab_scenarios.WHEEL_MOTOR, J=inertia)
        tau = inertia * motor.Ra / motor.CPhi ** 2
        halves = [inertia_half_range(lab_scenarios.wheel_speed_steps_current_magnitude(
            seed=seed, signed=True, motor=motor).records, motor.b / motor.CPhi)
            for seed in range(seeds)]
        ratios = [half.ratio for half in halves if half is not None]
        flags = sum(inertia_unresolved(half) for half in halves)
        rows.append([f'{inertia:.3g}', f'{tau * 1e3:.2f}', f'{tau / 0.03:.2f}',
                     f'{np.median(ratios):.3f}', f'{min(half.z for half in halves):.1f} .. '
                     f'{max(half.z for half in halves):.1f}', f'{flags}/{seeds}'])
    return rows


def lab_rows(seeds: int) -> tuple[list[list[str]], int, int]:
    """Return every lab class over the seeds; also the totals judged and flagged."""
    rows, judged_all, flagged_all = [], 0, 0
    for name, make in lab_scenarios.SCENARIOS.items():
        halves = []
        for seed in range(seeds):
            scenario = make(seed=seed)
            truth = scenario.truth
            halves.append(inertia_half_range(scenario.records, truth.b / truth.CPhi))
        judged = [half for half in halves if half is not None]
        flagged = sum(inertia_unresolved(half) for half in judged)
        judged_all += len(judged)
        flagged_all += flagged
        if not judged:
            rows.append([name, '0', '-', '-', '-'])
            continue
        rows.append([name, str(len(judged)), f'{np.median([h.ratio for h in judged]):.3f}',
                     f'{max(h.z for h in judged):.1f}', f'{flagged}/{len(judged)}'])
    return rows, judged_all, flagged_all


def _answer_constants(answer: dict) -> tuple[float, float] | None:
    """Return ``(b, CPhi)`` of a case's answer, None when it refused."""
    if 'parameters' not in answer:
        return None
    parameters = answer['parameters']
    constant = answer.get('torque_constant') or parameters.get('CPhi')
    return (parameters['b'], constant) if constant else None


def corpus_rows(data: Path, out: Path) -> list[list[str]]:
    """Return every corpus case with a CSV of current and speed (its answer's b and CPhi)."""
    sys.path.insert(0, os.path.join(ROOT, 'bench'))
    from identify_equivalence import _cases
    rows = []
    for name, arguments in sorted(_cases(data).items()):
        result = out / f'{name}.json'
        if not arguments[0].endswith('.csv') or not result.exists() \
                or not os.path.exists(arguments[0]):
            continue
        answer = json.loads(result.read_text())['identify']
        constants = _answer_constants(answer)
        record = read_csv(arguments[0])
        mode = 'current input' if '--torque-constant' in arguments else 'voltage input'
        if constants is None:
            rows.append([name, mode, 'refused', '-', '-', 'no'])
            continue
        ratio, z, flag = _cell(inertia_half_range([record], constants[0] / constants[1]))
        said = any(text.startswith('J is not determined') for text in answer['warnings'])
        rows.append([name, mode, ratio, z, 'yes' if flag else 'no', 'yes' if said else 'no'])
    return rows


def _wheel_records(repo: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Return the speed and the logged current of each wheel motor."""
    import subprocess
    text = subprocess.run(['git', '--git-dir', repo, 'show', f'{WHEELS_COMMIT}:{WHEELS_FILE}'],
                          capture_output=True, text=True, check=True).stdout
    lines = text.splitlines()
    header = lines[0].rstrip(';').split(';')
    values = np.array([line.rstrip(';').split(';') for line in lines[3:]], dtype=float)
    return {number: (values[:, header.index(f'{number} motor velocity')],
                     values[:, header.index(f'{number} motor current')])
            for number in ('1st', '2nd', '3rd')}


def wheel_rows(repo: str) -> list[list[str]]:
    """Return each wheel motor through ``identify``: J flagged, its stderr, the statistic."""
    rows = []
    for number, (speed, current) in _wheel_records(repo).items():
        for label, signed in (('sign of speed', current * np.sign(speed)), ('as logged', current)):
            record = Record(np.arange(speed.size) * WHEELS_PERIOD_S, current=signed, speed=speed)
            try:
                result = identify(prepare_records([record], WHEELS_K), torque_constant=WHEELS_K)
            except Exception as error:  # a refusal is a row too
                half = inertia_half_range([record], 2.4e-5 / WHEELS_K)
                ratio, z, flag = _cell(half)
                rows.append([f'motor {number[0]}, {label}', f'refused ({type(error).__name__})',
                             ratio, z, 'yes' if flag else 'no', '-'])
                continue
            j, stderr = result.parameters['J'], result.stderr['J']
            half = inertia_half_range([record], result.parameters['b'] / WHEELS_K)
            ratio, z, flag = _cell(half)
            rows.append([f'motor {number[0]}, {label}', f'{j:.3g} +/- {stderr:.2g}', ratio, z,
                         'yes' if 'J' in result.not_identifiable and flag else 'no',
                         f'{abs(j - lab_scenarios.WHEEL_J_AUTHORS) / stderr:.2f}'])
    return rows


def hsm150_rows(repo: str) -> list[list[str]]:
    """Return the HSM150 servo's 12 records singly and together, with the catalog's b."""
    import subprocess
    from scipy.io import loadmat
    names = subprocess.run(['git', '--git-dir', repo, 'ls-tree', '-r', '--name-only',
                            HSM150_COMMIT, '--', 'Data/Identification'], capture_output=True,
                           text=True, check=True).stdout.split()
    records = {}
    for name in sorted(n for n in names if n.endswith('.mat')):
        blob = subprocess.run(['git', '--git-dir', repo, 'show', f'{HSM150_COMMIT}:{name}'],
                              capture_output=True, check=True).stdout
        import io
        data = np.asarray(loadmat(io.BytesIO(blob))['data'], dtype=float)
        records[os.path.basename(name)[:-4]] = Record(
            data[:, 0] - data[0, 0], current=data[:, 6], speed=data[:, 3])
    rows = []
    for label, group in [(stem, [record]) for stem, record in records.items()] + [
            ('all 12', list(records.values()))]:
        ratio, z, flag = _cell(inertia_half_range(group, HSM150_B / HSM150_K))
        rows.append([label, ratio, z, 'yes' if flag else 'no'])
    return rows


def main(argv: list[str] | None = None) -> int:
    """Measure the check on every source given; write the markdown tables."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--corpus-data', type=Path)
    parser.add_argument('--corpus-out', type=Path)
    parser.add_argument('--wheels', help='bare clone of BrOleg5/research-wheel-slippage')
    parser.add_argument('--hsm150', help='bare clone of malik-robert/HSM150-data')
    parser.add_argument('--out', type=Path, default=Path('bench/inertia_results.md'))
    args = parser.parse_args(argv)
    started, load = time.time(), os.getloadavg()
    lines = ['# The inertia check: size and power (issue 29)', '',
             f'Command: `bench/bench_inertia.py --seeds {args.seeds}'
             + (' --corpus-data DATA --corpus-out OUT' if args.corpus_out else '')
             + (' --wheels research-wheel-slippage' if args.wheels else '')
             + (' --hsm150 HSM150-data' if args.hsm150 else '') + '`  ',
             f'Load average at the start: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}', '',
             'J is not determined (flagged) when the half range h of J between the current '
             'at the start and at the end of each sample is above 0.5 at the one-sided 1 % '
             'level (z > 2.33).', '',
             '## Power curve: the wheel class (signed current, 30 ms) over J', '',
             'tau: the mechanical time constant J Ra / CPhi^2 (the voltage drives the motor; '
             'the current is logged as the input).', '']
    lines += markdown_table(
        ['J [kg m^2]', 'tau [ms]', 'tau [samples]', 'median h', 'z (min .. max)', 'flagged'],
        sweep_rows(args.seeds)).splitlines()
    rows, judged, flagged = lab_rows(args.seeds)
    lines += ['', f'## Lab classes ({args.seeds} seeds each, true b/CPhi)', '',
              f'Judged {judged} records (a measured speed and current), flagged {flagged}.', '']
    lines += markdown_table(
        ['class', 'judged', 'median h', 'largest z', 'flagged'],
        rows).splitlines()
    if args.corpus_data and args.corpus_out:
        rows = corpus_rows(args.corpus_data, args.corpus_out)
        count = sum(row[4] == 'yes' for row in rows)
        said = sum(row[5] == 'yes' for row in rows)
        lines += ['', '## Corpus (bench/identify_equivalence.py)', '',
                  f'{len(rows)} cases with a CSV of current and speed; the statistic flags '
                  f'{count}; `identify` says J is not determined in {said} (only current-input '
                  'fits are judged).', '']
        lines += markdown_table(
            ['case', 'fit', 'h', 'z', 'flagged', 'identify says so'],
            rows).splitlines()
    if args.wheels:
        lines += ['', '## Real: the wheel log (BrOleg5/research-wheel-slippage, 30.6 ms)', '',
                  "Through `identify` (`--torque-constant 0.0514`); h with the answer's b "
                  "(a refusal: the authors' b).  |J - J_authors| / stderr: how many stated "
                  "standard errors the authors' J 1.14e-6 lies from the tool's.", '']
        lines += markdown_table(
            ['motor', 'J (tool) +/- stderr', 'h', 'z', 'J flagged',
             '|J - J_authors| / stderr'],
            wheel_rows(args.wheels)).splitlines()
    if args.hsm150:
        lines += ['', '## Real: HSM150 (1 kHz, current steps), catalog b', '']
        lines += markdown_table(
            ['record', 'h', 'z', 'flagged'],
            hsm150_rows(args.hsm150)).splitlines()
    lines += ['', 'MECH 467 and EMPS log a position (the speed is derived): not judged.', '',
              f'Run time {time.time() - started:.0f} s.', '']
    args.out.write_text('\n'.join(lines))
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
