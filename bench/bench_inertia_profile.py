"""
J's likelihood profile with the voltage as the input (issue 29): its false alarms and power.

:mod:`dcmotor_id.identification.checks.inertia_profile` says J is not determined when the data
do not reject, at the 1 % level, a J so small that the speed settles within a hundredth of a
sample (J's likelihood profile, on effective samples), and gives J's upper bound.  Every row
runs the default ``identify`` end to end and reads what it said:

* **Random motors**: the cases of ``bench/bench_random_motors.py`` (``--cases``): where the
  profile ran (the fitted model's slowest time constant below two samples), whether J was
  flagged, whether the truth lies below the bound; a false alarm is J flagged where J is
  within the goal (10 %).
* **Power**: the lab class ``sysid_fast_shaft`` (a SysId routine at 20 ms) over the mechanical
  time constant (J scaled), ``--seeds`` each: how often J is flagged, how often the bound
  covers the truth, J's error where it is not flagged.
* **Lab classes**: every class of :data:`~dcmotor_id.simulation.lab_scenarios.SCENARIOS`,
  ``--lab-seeds`` each: J flagged by the profile where its time constant spans samples is a
  false alarm.

Where J is flagged, La's profile (:mod:`dcmotor_id.identification.checks.armature_profile`)
asks the same of La: the columns "La flagged" and "La error" say whether La was said not
determined, and how far the fitted La is from the truth (a flag on an La within 10 % is a false
alarm; an La off by more than 10 % with neither a flag nor the truth within three stated
standard errors is silent).

Run from the repository root (about 15 minutes on 2 cores)::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_inertia_profile.py \
        --out bench/inertia_profile_results.md
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
import warnings

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.simulation import lab_scenarios

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_random_motors import case  # noqa: E402,I100  (beside this script)
from common import markdown_table, write_report  # noqa: E402,I100

#: Mechanical time constants of the power sweep, in 20 ms frames.
SWEEP_FRAMES = (0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0)


def judged(records, truth, torque_constant=None) -> dict:
    """Identify; return what the profile said of J, J's error and the run time."""
    start = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            result = identify(prepare_records(records), torque_constant=torque_constant)
    except DcMotorIdError as error:
        return {'refused': str(error)[:60], 'seconds': time.perf_counter() - start}
    info = (result.estimate.info if result.estimate is not None else {}).get('inertia_profile')
    error = 100.0 * (result.parameters['J'] / truth.J - 1.0)
    flagged = bool(info and info['unresolved'] and 'J' in result.not_identifiable)
    rejected = bool(info and info['fitted_rejected'] and 'J' in result.not_identifiable)
    bound = info.get('bound') if info else None
    return {'ran': info is not None, 'flagged': flagged, 'rejected': rejected,
            'ratio': info['ratio'] if info else None,
            'bound': bound, 'covered': bound is not None and truth.J <= bound,
            'error': error, 'seconds': time.perf_counter() - start,
            **_armature(result, truth),
            'said': flagged or 'J' in result.not_identifiable or (
                np.isfinite(result.stderr['J'])
                and abs(result.parameters['J'] - truth.J) <= 3.0 * result.stderr['J'])}


def _armature(result, truth) -> dict:
    """Return what La's profile said: flagged, La's error, silent (off 10 %, not said)."""
    info = (result.estimate.info if result.estimate is not None else {}).get(
        'armature_profile')
    flagged = bool(info and info['unresolved'] and 'La' in result.not_identifiable)
    la, stderr = result.parameters.get('La'), result.stderr.get('La', np.nan)
    if la is None or not truth.La:
        return {'la_flagged': flagged, 'la_error': np.nan, 'la_silent': False}
    error = 100.0 * (la / truth.La - 1.0)
    said = flagged or 'La' in result.not_identifiable or 'La' in result.upper_bounds or (
        np.isfinite(stderr) and abs(la - truth.La) <= 3.0 * stderr)
    return {'la_flagged': flagged, 'la_error': error,
            'la_silent': abs(error) > 10.0 and not said}


def _bound_cell(row: dict, truth_j: float) -> str:
    """Return the bound relative to the truth, or what there is instead."""
    if not row.get('flagged'):
        return '-'
    return f"{row['bound'] / truth_j:.2f} x truth" if row['bound'] else 'none'


def random_rows(cases: int) -> tuple[list[list[str]], dict]:
    """Return every random case where the profile ran, and the counts."""
    rows, counts = [], {'cases': 0, 'ran': 0, 'flagged': 0, 'false': 0, 'covered': 0,
                        'outside_silent': 0, 'la_flagged': 0, 'la_false': 0, 'la_silent': 0}
    for index in range(cases):
        motor, record, made = case(index)
        row = judged([record], motor)
        counts['cases'] += 1
        print(f'random {index}: {row}', file=sys.stderr, flush=True)
        if 'refused' in row:
            continue
        within = abs(row['error']) <= 10.0
        counts['false'] += int((row['flagged'] or row['rejected']) and within)
        counts['outside_silent'] += int(not within and not row['said'])
        if not row['ran']:
            continue
        counts['ran'] += 1
        counts['flagged'] += int(row['flagged'])
        counts['covered'] += int(row['flagged'] and row['covered'])
        counts['la_flagged'] += int(row['la_flagged'])
        counts['la_false'] += int(row['la_flagged'] and abs(row['la_error']) <= 10.0)
        counts['la_silent'] += int(row['la_silent'])
        rows.append([str(index), made['kind'], f"{made['dt'] * 1e3:g}", made['sensor'],
                     f"{made['tau_m'] / made['dt']:.2f}", f"{row['error']:+.1f}",
                     f"{row['ratio']:.3g}", 'yes' if row['flagged'] else 'no',
                     'yes' if row['rejected'] else 'no',
                     _bound_cell(row, motor.J), 'yes' if row['la_flagged'] else 'no',
                     f"{row['la_error']:+.3g}", f"{row['seconds']:.1f}"])
    return rows, counts


def sweep_rows(seeds: int) -> list[list[str]]:
    """Return the power curve: ``sysid_fast_shaft`` over the mechanical time constant."""
    base = lab_scenarios.FAST_SHAFT_MOTOR
    rows = []
    for frames in SWEEP_FRAMES:
        inertia = frames * 0.02 * base.CPhi ** 2 / base.Ra
        motor = dataclasses.replace(base, J=inertia)
        results = [judged(lab_scenarios.sysid_fast_shaft(seed=seed, motor=motor).records,
                          motor) for seed in range(seeds)]
        done = [row for row in results if 'refused' not in row]
        flagged = [row for row in done if row['flagged']]
        kept = [abs(row['error']) for row in done if not row['flagged']]
        rows.append([f'{frames:g}', f'{inertia:.3g}', f'{len(flagged)}/{len(done)}',
                     f"{sum(row['rejected'] for row in done)}/{len(done)}",
                     f"{sum(row['covered'] for row in flagged)}/{len(flagged)}",
                     f'{np.median(kept):.1f}' if kept else '-',
                     f"{sum(not row['said'] and abs(row['error']) > 10 for row in done)}",
                     f"{sum(row['la_flagged'] for row in done)}/{len(done)}",
                     f"{sum(row['la_silent'] for row in done)}",
                     f"{max(row['seconds'] for row in results):.1f}"])
        print(f'sweep {frames}: {rows[-1]}', file=sys.stderr, flush=True)
    return rows


def lab_rows(seeds: int) -> tuple[list[list[str]], int]:
    """Return every lab class over the seeds (voltage input only); also the false alarms."""
    rows, false = [], 0
    for name, make in lab_scenarios.SCENARIOS.items():
        results = []
        for seed in range(seeds):
            scenario = make(seed=seed)
            if scenario.torque_constant is not None or any(
                    rec.current is None for rec in scenario.records):
                break
            results.append(judged(scenario.records, scenario.truth))
        if not results:
            continue
        done = [row for row in results if 'refused' not in row]
        flagged = sum(row['flagged'] or row['rejected'] for row in done)
        if name != 'sysid_fast_shaft':
            false += flagged
        rows.append([name, str(len(done)), str(sum(row['ran'] for row in done)),
                     str(flagged), ', '.join(f"{row['error']:+.1f}" for row in done),
                     str(sum(row['la_flagged'] for row in done)),
                     str(sum(row['la_silent'] for row in done)),
                     f"{max(row['seconds'] for row in results):.1f}"])
        print(f'lab {name}: {rows[-1]}', file=sys.stderr, flush=True)
    return rows, false


def main(argv: list[str] | None = None) -> int:
    """Run the three parts; write the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--cases', type=int, default=120)
    parser.add_argument('--seeds', type=int, default=5)
    parser.add_argument('--lab-seeds', type=int, default=2)
    parser.add_argument('--out', default='bench/inertia_profile_results.md')
    args = parser.parse_args(argv)
    load, started = os.getloadavg(), time.time()
    random, counts = random_rows(args.cases)
    sweep = sweep_rows(args.seeds)
    lab, false_lab = lab_rows(args.lab_seeds)
    lines = ["# J's (and La's) likelihood profile with the voltage as the input (issue 29)", '',
             f'Command: `bench/bench_inertia_profile.py --cases {args.cases} --seeds '
             f'{args.seeds} --lab-seeds {args.lab_seeds}`  ',
             f'Load average at the start: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}; run '
             f'time {time.time() - started:.0f} s', '',
             'J is flagged (not determined) when the data do not reject, at the 1 % level, '
             'the J whose speed settles within a hundredth of a sample; its upper bound is '
             'the least J above the accepted ones that they reject.  The fitted J is rejected '
             '(J named not determined too, its standard error reaching the accepted range) when '
             'a point of the profile fits better beyond the same level (another optimum).', '',
             f"## Random motors ({counts['cases']} cases of bench_random_motors.py)", '',
             f"The profile ran on {counts['ran']}; J flagged on {counts['flagged']}, the truth "
             f"below the bound on {counts['covered']} of them; false alarms (J flagged or the "
             'fitted J rejected, J '
             f"within 10 %): {counts['false']}; J outside 10 % and not said: "
             f"{counts['outside_silent']}.  La flagged (La's profile, where J is flagged) on "
             f"{counts['la_flagged']}; false alarms (La flagged, La within 10 %): "
             f"{counts['la_false']}; La outside 10 % and not said: {counts['la_silent']}.", '']
    lines += markdown_table(['case', 'experiment', 'dt [ms]', 'sensor', 'tau_m / dt',
                             'J error [%]', 'ratio', 'J flagged', 'fitted J rejected',
                             'bound', 'La flagged', 'La error [%]', 's'],
                            random).splitlines()
    lines += ['', '## Power: sysid_fast_shaft over the mechanical time constant', '',
              f'{args.seeds} seeds each; tau_m = J Ra / CPhi^2 in 20 ms frames.', '']
    lines += markdown_table(['tau_m [frames]', 'J', 'J flagged', 'fitted J rejected',
                             'bound covers the truth',
                             'median |J error| not flagged [%]', 'J off > 10 % and not said',
                             'La flagged', 'La off > 10 % and not said', 'slowest s'],
                            sweep).splitlines()
    lines += ['', f'## Lab classes with the voltage as the input ({args.lab_seeds} seeds)', '',
              f'J flagged outside sysid_fast_shaft (false alarms): {false_lab}.', '']
    lines += markdown_table(['class', 'identified', 'profile ran', 'J flagged',
                             'J errors [%]', 'La flagged', 'La off > 10 % and not said',
                             'slowest s'], lab).splitlines()
    write_report(lines, args.out)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
