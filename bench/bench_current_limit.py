"""
The current-limit rule's false alarms and power (issue 29: a threshold is a measured test).

:func:`~dcmotor_id.identification.checks.identifiability.limited_samples` finds plateaus of
``|i|`` at its peak (the *detector*) and confirms them by a one-sided test of the physics
(:func:`~dcmotor_id.identification.checks.identifiability.limit_shortfall_p`: on the plateaus
the electrical equation, fitted where the current is below 80 % of its peak, predicts more
current than flows; block null of the fit's own residual).  For each set of records, the
table counts the records the detector flags and those the whole rule (detector and test)
flags:

* **size**, records without a limit: the random motors of ``bench/bench_random_motors.py``
  (its cases ``0..N``: steps, stairs, PRBS, SysId routines), a second draw of them (seeds
  1000 + i, kinds step / stairs / PRBS, periods 2, 1, 5 ms, speed or 4096-count encoder:
  ``sweep``), and the lab classes of ``simulation/lab_scenarios.py`` other than
  ``small_motor_pwm_steps`` at seeds 0-4 (those with a voltage and a current: the others
  are identified in the mechanical mode, where no limit is looked for), and the CSV records of
  ``bench/identify_equivalence.py``'s corpus but its ``small_motor_pwm_steps`` (``--corpus-data``);
* **power**: ``small_motor_pwm_steps`` through a current limit of 1.0-3.0 A, sample periods
  1-5 ms, seeds 0-9.

And what the default ``identify`` gives for Ra through the limit (``--ra-seeds``, table "Ra
through the limit": limits 1-2.5 A, periods 1, 2 and 5 ms), against the electrical regression
of an earlier revision on the same records (``--before REV``: its
``pipeline/current_limited.py`` read with ``git show``; Ra and its standard error come from
that regression alone on the limited path, so the pair is exact).

The records go through ``prepare_records`` and ``split_tests`` as ``identify`` does.  The real
recordings of the scorecard have no voltage with a current (HSM150, MECH 467, EMPS and the wheel
log give the current as the input; SysIdOpt and the QUBE-Servo give no current): no limit is
looked for on them.  Run from
the repository root (about a minute)::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_current_limit.py --corpus-data DATA --out FILE.md
"""

import argparse
import glob
import os
import subprocess
import sys
import time
import types
import warnings

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.records import Record
from dcmotor_id.formats.csv import read_csv
from dcmotor_id.identification.checks import identifiability
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline.segments import split_tests
from dcmotor_id.simulation.lab_scenarios import (SCENARIOS, simulate_drive,
                                                 small_motor_pwm_steps)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_random_motors import case, command_of, random_motor  # noqa: E402,I100
from common import markdown_table, write_report  # noqa: E402

LIMITS_A = (1.0, 1.5, 2.0, 2.5, 3.0)
PERIODS_S = (1e-3, 2e-3, 3e-3, 4e-3, 5e-3)
#: Limits and sample periods of the table "Ra through the limit".
RA_LIMITS_A = (1.0, 1.5, 2.0, 2.5)
RA_PERIODS_S = (1e-3, 2e-3, 5e-3)
#: The module whose regression ``--before`` reads at an earlier revision.
REGRESSION_PATH = 'dcmotor_id/identification/pipeline/current_limited.py'
#: Rows of the detail table (records without a limit the detector flags, smallest p first).
DETAIL_ROWS = 10


def sweep_case(index: int) -> Record:
    """Return record ``index`` of the second random draw (15 of 300 taken for limits)."""
    rng = np.random.default_rng(1000 + index)
    motor, volts, tau_m = random_motor(rng)
    kind = ('step', 'stairs', 'prbs')[index % 3]
    dt = (2e-3, 1e-3, 5e-3)[(index // 3) % 3]
    command = command_of(kind, volts, tau_m, dt, rng)
    out = simulate_drive(motor, command, dt)
    t = np.arange(command.size) * dt
    current = out['current'] + rng.normal(0.0, 0.005 * volts / motor.Ra, command.size)
    if (index // 9) % 2 == 0:
        speed = out['speed'] + rng.normal(0.0, 0.005 * volts / motor.CPhi, command.size)
        return Record(t, current=current, voltage=command, speed=speed, source=f'r{index}')
    angle = np.floor(out['angle'] * 4096 / (2 * np.pi)) * 2 * np.pi / 4096
    return Record(t, current=current, voltage=command, position=angle, source=f'r{index}')


def verdicts(records: list) -> tuple[bool, bool, float | None]:
    """Return whether the detector flags the records, whether the rule does, and the p-value."""
    if any(rec.voltage is None or rec.current is None for rec in records):
        return False, False, None  # the mechanical mode: no limit is looked for
    prepared = list(split_tests(prepare_records(records)).records)
    size = identifiability.LIMIT_TEST_SIZE
    identifiability.LIMIT_TEST_SIZE = 1.0  # the detector alone
    try:
        masks = identifiability.limited_samples(prepared)
    finally:
        identifiability.LIMIT_TEST_SIZE = size
    if masks is None:
        return False, False, None
    peak = max(float(np.max(np.abs(rec.current))) for rec in prepared)
    free_below = identifiability.LIMIT_FREE_SHARE * peak
    p_value = identifiability.limit_shortfall_p(prepared, masks, free_below)
    return True, identifiability.limited_samples(prepared) is not None, p_value


def corpus_cases(data: str | None) -> list:
    """Return the corpus records of ``bench/identify_equivalence.py`` but the limited one."""
    if not data:
        return []
    paths = sorted(glob.glob(os.path.join(data, '*.csv')))
    return [(os.path.basename(path), [read_csv(path)]) for path in paths
            if 'small_motor_pwm_steps' not in path]


def size_sets(random_n: int, sweep_n: int, corpus: str | None) -> dict:
    """Return, per set without a limit, its cases as (name, records) pairs."""
    lab = [(f'{name} seed {seed}', scenario(seed=seed).records)
           for name, scenario in SCENARIOS.items() if name != 'small_motor_pwm_steps'
           for seed in range(5)]
    return {'identify_equivalence corpus (but its small_motor_pwm_steps)':
            iter(corpus_cases(corpus)), f'bench_random_motors cases 0-{random_n - 1}':
            ((f'case {index}', [case(index)[1]]) for index in range(random_n)),
            f'sweep 0-{sweep_n - 1}':
            ((f'sweep {index}', [sweep_case(index)]) for index in range(sweep_n)),
            'lab classes without a limit, seeds 0-4': iter(lab)}


def size_rows(random_n: int, sweep_n: int, corpus: str | None) -> tuple[list, list]:
    """Return the size table's rows and the detail rows of every record the detector flags."""
    rows, details = [], []
    for title, cases in size_sets(random_n, sweep_n, corpus).items():
        total = detected = confirmed = 0
        p_values = []
        for name, records in cases:
            total += 1
            flagged, kept, p_value = verdicts(records)
            detected += flagged
            confirmed += kept
            if flagged:
                details.append([name, 'yes' if kept else 'no',
                                'n/a' if p_value is None else f'{p_value:.3g}'])
                p_values += [] if p_value is None else [p_value]
        print(f'size: {title}: {total} records, {detected} flagged by the detector, '
              f'{confirmed} by the rule', file=sys.stderr, flush=True)
        rows.append([title, str(total), str(detected), str(confirmed),
                     str(sum(p <= 0.05 for p in p_values)),
                     f'{min(p_values):.3g}' if p_values else 'n/a'])
    return rows, details


def power_rows(seeds: int) -> list:
    """Return the power table: per limit and period, records flagged of ``seeds``."""
    rows = []
    for limit in LIMITS_A:
        for period in PERIODS_S:
            found = [verdicts(small_motor_pwm_steps(seed=seed, sample_period_s=period,
                                                    current_limit_a=limit).records)
                     for seed in range(seeds)]
            worst = max((p for _, kept, p in found if p is not None), default=None)
            rows.append([f'{limit:g}', f'{period * 1e3:g}',
                         f'{sum(flag for flag, _, _ in found)} of {seeds}',
                         f'{sum(kept for _, kept, _ in found)} of {seeds}',
                         'n/a' if worst is None else f'{worst:.3g}'])
    return rows


def sweep_motor(index: int):
    """Return the motor of :func:`sweep_case` ``index`` (the same draw)."""
    return random_motor(np.random.default_rng(1000 + index))[0]


def identify_errors(records: list, motor, test_size: float) -> str:
    """Return the default ``identify``'s Ra, CPhi, J errors [%] with the test at a size."""
    size = identifiability.LIMIT_TEST_SIZE
    identifiability.LIMIT_TEST_SIZE = test_size
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            result = identify(prepare_records(records))
    except DcMotorIdError as error:
        return f'refused ({type(error).__name__})'
    finally:
        identifiability.LIMIT_TEST_SIZE = size
    return ', '.join(f'{name} {100 * (result.parameters[name] / getattr(motor, name) - 1):+.1f}'
                     for name in ('Ra', 'CPhi', 'J'))


def identify_rows(count: int) -> list:
    """Return, for the sweep records below ``count`` the detector flags, identify's errors."""
    rows = []
    for index in range(count):
        records = [sweep_case(index)]
        flagged, kept, _ = verdicts(records)
        if flagged and not kept:
            motor = sweep_motor(index)
            rows.append([f'sweep {index}', identify_errors(records, motor, 1.0),
                         identify_errors(records, motor, identifiability.LIMIT_TEST_SIZE)])
    return rows


def before_regression(revision: str):
    """Return the ``electrical_regression`` of ``revision`` (its module read by ``git show``)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    source = subprocess.run(['git', 'show', f'{revision}:{REGRESSION_PATH}'], cwd=root,
                            check=True, capture_output=True, text=True).stdout
    module = types.ModuleType(f'current_limited_{revision}')
    exec(compile(source, f'{revision}:{REGRESSION_PATH}', 'exec'), module.__dict__)
    return module.electrical_regression


def ra_cell(limit: float, period: float, seeds: int, before) -> list:
    """Return one row of "Ra through the limit": before and after over ``seeds`` seeds."""
    after, earlier = [], []
    for seed in range(seeds):
        scenario = small_motor_pwm_steps(seed=seed, sample_period_s=period,
                                         current_limit_a=limit)
        truth = scenario.truth.Ra
        records = prepare_records(scenario.records)
        masks = identifiability.limited_samples(records)
        if masks is not None and before is not None:
            values, robust = before(records, masks)
            earlier.append((values['Ra'] / truth - 1, (values['Ra'] - truth)
                            / robust['stderr'][0], False, robust['stderr'][0] / values['Ra']))
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            result = identify(scenario.records)
        warned = any("La's part" in text for text in result.warnings)
        error = result.parameters['Ra'] - truth
        after.append((error / truth, error / result.stderr['Ra'], warned,
                      result.stderr['Ra'] / result.parameters['Ra']))
    return [f'{limit:g}', f'{period * 1e3:g}', *ra_summary(earlier, seeds),
            *ra_summary(after, seeds)]


def ra_summary(rows: list, seeds: int) -> list:
    """Return Ra's error range, its stated error, the largest ratio and the goal's counts."""
    if not rows:
        return ['no limit found', '', '', '', '']
    errors = [100 * row[0] for row in rows]
    met = sum(abs(e) < 0.05 or (abs(z) <= 3 and warned) for e, z, warned, _ in rows)
    return [f'{min(errors):+.1f} .. {max(errors):+.1f}',
            f'{100 * float(np.median([row[3] for row in rows])):.2g}',
            f'{max(abs(row[1]) for row in rows):.2g}',
            f'{sum(abs(row[1]) <= 3 for row in rows)} of {len(rows)}',
            f'{met} of {seeds}']


def ra_rows(seeds: int, revision: str | None) -> list:
    """Return the table "Ra through the limit" (before: ``revision``'s regression)."""
    if seeds <= 0:
        return []
    before = before_regression(revision) if revision else None
    rows = []
    for period in RA_PERIODS_S:
        for limit in RA_LIMITS_A:
            print(f'Ra: {limit:g} A, {period * 1e3:g} ms ...', file=sys.stderr, flush=True)
            rows.append(ra_cell(limit, period, seeds, before))
    return rows


def ra_lines(rows: list, args: argparse.Namespace) -> list:
    """Return the section "Ra through the limit" of the report (none without rows)."""
    if not rows:
        return []
    head = ['Ra error [%], min .. max', 'stated error [% of Ra], median',
            'largest error [stated errors]',
            'within 3 stated errors', 'goal met']
    return ['## Ra through the limit', '',
            f'`small_motor_pwm_steps` (Ra {2.0:g} Ohm), seeds 0-{args.ra_seeds - 1}. Before: '
            f'the electrical regression of revision `{args.before}` on the same records (Ra '
            'and its standard error on the limited path come from it alone). After: the '
            'default `identify`. Goal: Ra within 5 %, or within 3 stated standard errors '
            "with the warning of La's part.", '',
            markdown_table(['limit [A]', 'period [ms]', *[f'before: {h}' for h in head],
                            *[f'after: {h}' for h in head]], rows), '']


def main(argv: list[str] | None = None) -> int:
    """Run the sets and write the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--random', type=int, default=600, help='bench_random_motors cases')
    parser.add_argument('--sweep', type=int, default=300, help='second-draw cases')
    parser.add_argument('--seeds', type=int, default=10, help='seeds per power cell')
    parser.add_argument('--corpus-data', default=None,
                        help="identify_equivalence.py's data directory (its CSV records)")
    parser.add_argument('--identify', type=int, default=0,
                        help='identify the sweep records below this the test turns down')
    parser.add_argument('--ra-seeds', type=int, default=10,
                        help='seeds per cell of the table "Ra through the limit" (0: none)')
    parser.add_argument('--before', default=None, metavar='REV',
                        help="the revision whose electrical regression is the table's before")
    parser.add_argument('--out', default=None, help='write the tables to this markdown file')
    args = parser.parse_args(argv)
    started, load = time.perf_counter(), os.getloadavg()
    size, details = size_rows(args.random, args.sweep, args.corpus_data)
    details = sorted(details, key=lambda row: (row[1] != 'yes', float(row[2].replace('n/a', '0'))))
    shown = [row for row in details if row[1] == 'yes' or row[2] == 'n/a'] + \
        [row for row in details if row[1] == 'no' and row[2] != 'n/a'][:DETAIL_ROWS]
    print('power: small_motor_pwm_steps over limits and periods ...', file=sys.stderr,
          flush=True)
    power = power_rows(args.seeds)
    print(f'identify: {args.identify} sweep records ...', file=sys.stderr, flush=True)
    effect = identify_rows(args.identify)
    ra_table = ra_rows(args.ra_seeds, args.before)
    lines = ['# Current limit: the detector and its confirming test', '',
             'Command: `PYTHONPATH=$PWD .venv/bin/python bench/bench_current_limit.py '
             f'--random {args.random} --sweep {args.sweep} --seeds {args.seeds} --identify '
             f'{args.identify} --ra-seeds {args.ra_seeds} --before {args.before} --corpus-data '
             'DATA` (DATA: `identify_equivalence.py data DATA`); load average '
             f"{load[0]:.2f} at the start, {time.perf_counter() - started:.0f} s. The test's "
             f'one-sided size {identifiability.LIMIT_TEST_SIZE:g} '
             f'({identifiability.LIMIT_NULL_DRAWS} null draws: the smallest p is '
             f'{1 / (1 + identifiability.LIMIT_NULL_DRAWS):.3g}).', '',
             '## Size: records without a limit', '',
             markdown_table(['set', 'records', 'detector flags', 'rule flags (detector + test)',
                             'p <= 0.05', 'smallest p'], size), '',
             '## Records without a limit the detector flags: any the rule flags, any the test '
             f'could not judge and the {DETAIL_ROWS} of smallest p', '',
             markdown_table(['record', 'rule flags', 'p'], shown), '',
             '## Power: small_motor_pwm_steps through a current limit', '',
             markdown_table(['limit [A]', 'period [ms]', 'detector flags', 'rule flags',
                             'largest p'], power), '',
             '## What the user gets: the sweep records the test turns down, identified', '',
             'Default `identify` (discovery on) with the plateaus taken for a limit (the detector '
             'alone: the test at size 1) and with the rule; errors against the truth [%].', '',
             markdown_table(['record', 'detector alone: Ra, CPhi, J', 'the rule: Ra, CPhi, J'],
                            effect), '', *ra_lines(ra_table, args)]
    write_report(lines, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
