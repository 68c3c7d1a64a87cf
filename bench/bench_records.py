"""
Standard errors of fits of several records: within-record figure against the record-level one.

Issue 19 (disjoint subsets of the HSM150 records disagree at z = 4.7-7.3): the batch-means
sandwich sums the scores over blocks *within* each record, so a parameter that differs from
record to record (each record's friction of its own) is invisible to it; the record-level
(cluster) sandwich of :mod:`dcmotor_id.identification.estimators.uncertainty` sees it.  Two
parts, both with discovery off (a fixed structure, what a standard error is about):

1. The laboratory scenarios of :mod:`dcmotor_id.simulation.lab_scenarios` with several records
   (the parameters shared exactly): over ``--seeds`` seeds the median stated ``stderr`` (with
   the record-level figure) and the median within-record figure (``between_records.
   stderr_within``, the figure before) against the standard deviation of the estimates.  The
   record-level part must add little here.
2. A simulated class like the HSM150 runs: ``2 x --records`` torque-step records of the servo
   (a long steady tail after each step, a quantised speed, a noisy current), each with its own
   viscous and Coulomb friction (``--friction-spread`` relative standard deviation), fitted as
   two disjoint halves; ``z = |a - b| / sqrt(sa^2 + sb^2)`` between the halves with the stated
   and with the within-record standard errors (RMS over seeds should be about 1), and the
   same with the frictions shared (spread 0).

Run from the repository root::

    .venv/bin/python bench/bench_records.py > bench/records_results.md
"""

import argparse
from dataclasses import replace
import os
import sys
import time

import numpy as np

from dcmotor_id.core.errors import NotIdentifiableError
from dcmotor_id.core.records import Record
from dcmotor_id.identification.identify import identify
from dcmotor_id.simulation.lab_scenarios import (SCENARIOS, SERVO_MOTOR, simulate_drive,
                                                 step_levels)

NAMES = ('J', 'b', 'Mc')
#: What the HSM150 part is.
HSM_TEXT = (
    'github malik-robert/HSM150-data at 35c3b1b, `Data/Identification/idf_*.mat`, fitted by '
    '`dcmotor-id identify` with the reading options of `bench/bench_real.py` (discovery on, '
    'as a user runs it): the six opposite pairs (one record per direction, so Mc and the load '
    'torque keep the cluster sandwich) and the three 4-record runs.  z and the Welch bound as '
    'above; t_95: `between_records.t_95` of each fit.')
#: What part 3's columns are.
FEW_TEXT = (
    "Per seed, `2 x size` torque-step records of the servo (both ways in turn, each record's "
    'viscous and Coulomb friction drawn with the given relative standard deviation), fitted as '
    'two disjoint subsets of `size` records with discovery off.  *z*: `|a - b| / sqrt(sa^2 + '
    'sb^2)` with the stated `stderr`; *|z| <= Welch t 95 %*: the share of seeds where z lies '
    "within the 95 % quantile of Student's t with the Welch-Satterthwaite degrees of freedom "
    'of the two stated errors (each `between_records.dof` where the record-level figure sets '
    'it, else infinite): what the statement claims is 95 %; *interval_95 covers the truth*: '
    'the share of fits whose `value +- t_95 x stderr` holds the population value (the '
    "simulator's mean friction), claimed 95 %; *stated / actual error*: the median stated "
    '`stderr` over the root mean square error about the population value (1 is right); '
    '*estimators*: `between_records.estimator` over the fits (and the seeds skipped because '
    'a subset was refused as not identifiable, the same before and after).')


def _within(result):
    """Return the within-record standard errors (the figure before), or the stated ones."""
    account = result.between_records
    return {name: (account['stderr_within'][name] if account else result.stderr[name])
            for name in NAMES}


def lab_rows(seeds):
    """Part 1: stated and within-record stderr against the spread over seeds."""
    lines = ['| scenario | records | parameter | spread (sd over seeds) | stated / spread | '
             'within-record / spread | stated / within (median) |',
             '|---|---|---|---|---|---|---|']
    for name, make in SCENARIOS.items():
        scenario = make(seed=0)
        if len(scenario.records) < 2:
            continue
        values, stated, within = [], [], []
        for seed in range(seeds):
            scenario = make(seed=seed)
            result = identify(scenario.records, torque_constant=scenario.torque_constant,
                              discover=False)
            values.append([result.parameters[key] for key in NAMES])
            stated.append([result.stderr[key] for key in NAMES])
            within.append([_within(result)[key] for key in NAMES])
            print(f'{name} seed {seed}', file=sys.stderr)
        spread = np.std(values, axis=0, ddof=1)
        for index, key in enumerate(NAMES):
            column = np.array(stated)[:, index]
            old = np.array(within)[:, index]
            lines.append(f'| {name} | {len(scenario.records)} | {key} | {spread[index]:.3g} | '
                         f'{np.median(column) / spread[index]:.2f} | '
                         f'{np.median(old) / spread[index]:.2f} | '
                         f'{np.median(column / old):.2f} |')
    return lines


def servo_records(count, spread, rng, dt=2e-3, dwell_s=5.0):
    """Torque-step records of the servo, both ways in turn, each with its own friction."""
    records = []
    for index in range(count):
        factor = 1.0 + spread * rng.normal(size=2)
        truth = replace(SERVO_MOTOR, b=SERVO_MOTOR.b * factor[0], Mc=SERVO_MOTOR.Mc * factor[1])
        sign = 1.0 if index % 2 == 0 else -1.0
        command = sign * step_levels([1.0, 1.4 + 0.03 * index, 1.15], dwell_s, dt)
        out = simulate_drive(truth, command, dt, torque_input=True)
        t = np.arange(command.shape[0]) * dt
        speed = np.round(out['speed'] / 0.1) * 0.1
        records.append(Record(t, current=out['current'] + rng.normal(0.0, 0.05, len(t)),
                              speed=speed, source=f'servo_{index}'))
    return records


def class_rows(seeds, per_half, spread):
    """Part 2: z between disjoint halves with the stated and the within-record stderr."""
    lines = ['| friction spread | records per half | parameter | RMS z stated | max z stated | '
             'RMS z within-record | max z within-record | stated / within (median) |',
             '|---|---|---|---|---|---|---|---|']
    for relative in (spread, 0.0):
        z_new, z_old, ratio = [], [], []
        for seed in range(seeds):
            rng = np.random.default_rng(1000 + seed)
            records = servo_records(2 * per_half, relative, rng)
            a, b = (identify(records[part * per_half:(part + 1) * per_half],
                             torque_constant=SERVO_MOTOR.CPhi, discover=False)
                    for part in (0, 1))
            z_new.append([abs(a.parameters[k] - b.parameters[k])
                          / np.hypot(a.stderr[k], b.stderr[k]) for k in NAMES])
            z_old.append([abs(a.parameters[k] - b.parameters[k])
                          / np.hypot(_within(a)[k], _within(b)[k]) for k in NAMES])
            ratio.append([a.stderr[k] / _within(a)[k] for k in NAMES])
            print(f'class spread {relative} seed {seed}', file=sys.stderr)
        z_new, z_old, ratio = np.array(z_new), np.array(z_old), np.array(ratio)
        for index, key in enumerate(NAMES):
            lines.append(f'| {relative:g} | {per_half} | {key} | '
                         f'{np.sqrt(np.mean(z_new[:, index] ** 2)):.2f} | '
                         f'{z_new[:, index].max():.2f} | '
                         f'{np.sqrt(np.mean(z_old[:, index] ** 2)):.2f} | '
                         f'{z_old[:, index].max():.2f} | {np.median(ratio[:, index]):.2f} |')
    return lines


def _welch_within(a, b, key):
    """Whether ``|a - b|`` lies within the Welch t test's 95 % bound of the stated errors."""
    from scipy.stats import t as student
    parts = []
    for result in (a, b):
        account = result.between_records or {}
        dof = account.get('dof') if key in account.get('dominant', []) else np.inf
        parts.append((result.stderr[key] ** 2, dof))
    total = parts[0][0] + parts[1][0]
    spread = sum(v ** 2 / dof for v, dof in parts)
    nu = total ** 2 / spread if spread > 0 else np.inf
    z = abs(a.parameters[key] - b.parameters[key]) / np.sqrt(total)
    return z, z <= student.ppf(0.975, nu)


def _covers(result, key, truth):
    """Whether the 95 % interval of a fit (``t_95`` times ``stderr``) covers the value."""
    factor = ((result.between_records or {}).get('t_95') or {}).get(key, 1.959964)
    return abs(result.parameters[key] - truth) <= factor * result.stderr[key]


def few_record_rows(seeds, spread, sizes=(2, 3)):
    """Part 3: fits of 2 and 3 records, z and 95 % statements between disjoint subsets."""
    lines = ['| friction spread | records per fit | parameter | RMS z | max z | '
             '\\|z\\| <= 1.96 | \\|z\\| <= Welch t 95 % | interval_95 covers the truth | '
             'stated / actual error (median / RMS) | median t_95 | estimators |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    truth = {key: getattr(SERVO_MOTOR, key) for key in NAMES}
    for relative in (spread, 0.0):
        for size in sizes:
            rows = {key: {'z': [], 'welch': [], 'cover': [], 'stated': [], 'error': [],
                          't': []} for key in NAMES}
            estimators, refused = [], 0
            for seed in range(seeds):
                rng = np.random.default_rng(2000 + seed)
                records = servo_records(2 * size, relative, rng)
                try:
                    fits = [identify(records[part * size:(part + 1) * size],
                                     torque_constant=SERVO_MOTOR.CPhi, discover=False)
                            for part in (0, 1)]
                except NotIdentifiableError:
                    refused += 1
                    continue
                estimators += [(fit.between_records or {}).get('estimator') for fit in fits]
                for key, row in rows.items():
                    z, within = _welch_within(fits[0], fits[1], key)
                    row['z'].append(z)
                    row['welch'].append(within)
                    for fit in fits:
                        row['cover'].append(_covers(fit, key, truth[key]))
                        row['stated'].append(fit.stderr[key])
                        row['error'].append(fit.parameters[key] - truth[key])
                        row['t'].append(((fit.between_records or {}).get('t_95') or {})
                                        .get(key, 1.959964))
                print(f'few records spread {relative} size {size} seed {seed}', file=sys.stderr)
            used = ', '.join(f'{name} {estimators.count(name)}' for name in sorted(
                set(map(str, estimators))))
            used += f'; seeds refused: {refused}' if refused else ''
            for key, row in rows.items():
                z = np.array(row['z'])
                ratio = np.median(row['stated']) / np.sqrt(np.mean(np.square(row['error'])))
                lines.append(f'| {relative:g} | {size} | {key} | '
                             f'{np.sqrt(np.mean(z ** 2)):.2f} | {z.max():.2f} | '
                             f'{100 * np.mean(z <= 1.959964):.0f} % | '
                             f'{100 * np.mean(row["welch"]):.0f} % | '
                             f'{100 * np.mean(row["cover"]):.0f} % | {ratio:.2f} | '
                             f'{np.median(row["t"]):.3g} | {used} |')
    return lines


def _real_z(results, key):
    """z, and whether within the Welch t 95 % bound, over the pairs of disjoint subsets."""
    from scipy.stats import t as student
    out = []
    for first in range(len(results)):
        for second in range(first + 1, len(results)):
            parts = []
            for result in (results[first], results[second]):
                account = result.get('between_records') or {}
                dof = account['dof'] if key in account.get('dominant', []) else np.inf
                parts.append((result['stderr'][key] ** 2, dof))
            total = parts[0][0] + parts[1][0]
            spread = sum(v ** 2 / dof for v, dof in parts)
            nu = total ** 2 / spread if spread > 0 else np.inf
            z = abs(results[first]['parameters'][key] - results[second]['parameters'][key]) \
                / np.sqrt(total)
            out.append((z, z <= student.ppf(0.975, nu)))
    return out


def hsm150_rows(path, work):
    """Part 4: the six HSM150 opposite pairs and the three runs, as the scorecard runs them."""
    import json
    from bench_real import hsm150_set, run_cli
    data = hsm150_set(path, work, quick=False)
    lines = ['| disjoint subsets | parameter | value +- stated stderr (estimator, t_95) | '
             'max z | RMS z | \\|z\\| <= Welch t 95 % |', '|---|---|---|---|---|---|']
    for family in ('pairs', 'runs'):
        results = []
        for job in (job for job in data.jobs if job.family == family):
            out = os.path.join(work, f'{family}_{len(results)}.json')
            run = run_cli(['identify', *[data.records[name].path for name in job.members],
                           *data.reading, '--torque-constant', f'{data.torque_constant:.6g}',
                           '--json', out])
            if run['rc'] != 0:
                raise SystemExit(f'{job.label}: exit {run["rc"]}: {run["message"]}')
            with open(out) as stream:
                results.append(json.load(stream))
            print(f'hsm150 {job.label}', file=sys.stderr)
        for key in NAMES:
            cells = '; '.join(
                f'{r["parameters"][key]:.3g} +- {r["stderr"][key]:.2g} '
                f'({r["between_records"]["estimator"]}, '
                f'{r["between_records"].get("t_95", {}).get(key, 1.959964):.3g})'
                for r in results)
            zs = _real_z(results, key)
            z = np.array([value for value, _ in zs])
            lines.append(f'| {family} ({len(results)}) | {key} | {cells} | {z.max():.2f} | '
                         f'{np.sqrt(np.mean(z ** 2)):.2f} | '
                         f'{sum(ok for _, ok in zs)}/{len(zs)} |')
    return lines


def main(argv=None):
    """Print the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--records', type=int, default=4, help='records per half (part 2)')
    parser.add_argument('--friction-spread', type=float, default=0.1)
    parser.add_argument('--few-seeds', type=int, default=40,
                        help='seeds of part 3 (2- and 3-record fits; 0: not run)')
    parser.add_argument('--only-few', action='store_true', help='part 3 only')
    parser.add_argument('--hsm150', metavar='DIR',
                        help='HSM150-data (work tree or bare clone, commit 35c3b1b): with '
                        '--only-few, also its opposite pairs and runs as bench_real.py fits them')
    args = parser.parse_args(argv)
    start = time.process_time()
    load = f'load average before: {" ".join(f"{v:.2f}" for v in os.getloadavg())}'
    if args.only_few:
        lines = ['# Standard errors of fits of two and three records', '',
                 f'`bench/bench_records.py --only-few --few-seeds {args.few_seeds} '
                 f'--friction-spread {args.friction_spread}'
                 f'{" --hsm150 HSM150-data" if args.hsm150 else ""}`; {load}', '', FEW_TEXT,
                 '']
        lines += few_record_rows(args.few_seeds, args.friction_spread)
        if args.hsm150:
            import tempfile
            lines += ['', '## HSM150: the opposite pairs and the runs (real records)', '',
                      HSM_TEXT, '']
            with tempfile.TemporaryDirectory() as work:
                lines += hsm150_rows(args.hsm150, work)
    else:
        lines = ['# Standard errors of fits of several records', '',
                 f'`bench/bench_records.py --seeds {args.seeds} --records {args.records} '
                 f'--friction-spread {args.friction_spread} --few-seeds 0`; {load}', '',
                 '## 1. Laboratory scenarios with several records (parameters shared '
                 'exactly)', '']
        lines += lab_rows(args.seeds)
        lines += ['', '## 2. Records with a friction of their own, disjoint halves', '']
        lines += class_rows(args.seeds, args.records, args.friction_spread)
        if args.few_seeds:
            lines += ['', '## 3. Two and three records with a friction of their own, '
                      'disjoint subsets', '', FEW_TEXT, '']
            lines += few_record_rows(args.few_seeds, args.friction_spread)
    lines += ['', f'CPU {time.process_time() - start:.0f} s; load average after: '
              f'{" ".join(f"{v:.2f}" for v in os.getloadavg())}']
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
