"""
The quasi-static armature's honesty (issue 29): stated standard errors without and with its part.

When La/Ra is below the sample period (or La undetermined) ``identify`` fits the quasi-static
armature.  The data do not decide between it and the full equation (a speed averaged over the
sample or a delay passes for La), so the standard errors of Ra, CPhi, J, b and Mc cover both
(:func:`dcmotor_id.identification.pipeline.armature.structure_stderr`).  For every lab class of
:mod:`dcmotor_id.simulation.lab_scenarios` (seeds 0 and 1) and every random motor of
``bench_random_motors.py`` that ends quasi-static: the errors of Ra, CPhi and J against the
truth in stated standard errors, without that part (the standard errors the stage receives)
and with it (the answer's), and whether its warning names the parameter.  One run per case:
the stage is wrapped to record what it receives.  A La bound from an amplifier's current limit
(:mod:`dcmotor_id.identification.pipeline.current_limited`, ``small_motor_pwm_steps``) is
another path and not listed.

Run from the repository root (about 5 minutes on 2 cores)::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_armature.py --out bench/armature_results.md
"""

import argparse
import os
import sys
import time
import warnings

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline import stages
from dcmotor_id.simulation import lab_scenarios

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_random_motors  # noqa: E402,I100  (beside this script)
from common import markdown_table, write_report  # noqa: E402,I100

NAMES = ('Ra', 'CPhi', 'J')
#: What the stage received, for the run in progress (the wrapper fills it).
RECEIVED: dict = {}
ORIGINAL = stages.structure_stderr


def recording(inputs, fit, answer):
    """Run the stage; record the standard errors it received and what it returned."""
    out = ORIGINAL(inputs, fit, answer)
    if fit.quasi and fit.structure_spread:
        RECEIVED.update(before=dict(answer.stderr), after=dict(out.stderr))
    return out


def lab_cases():
    """Yield (name, truth, records, torque constant) of the lab classes, seeds 0 and 1."""
    for name, make in lab_scenarios.SCENARIOS.items():
        for seed in (0, 1):
            try:
                scenario = make(seed=seed)
            except TypeError:
                continue
            scenario = scenario[0] if isinstance(scenario, tuple) else scenario
            yield (f'lab {name}:{seed}', scenario.truth, scenario.records,
                   scenario.torque_constant)


def random_cases(count):
    """Yield the random motors of ``bench_random_motors.py`` the same way."""
    for index in range(count):
        motor, record, row = bench_random_motors.case(index)
        yield f"random {index} {row['kind']}", motor, [record], None


def judge(name, truth, records, constant):
    """Identify one case; return its row when it ended quasi-static with the stage's part."""
    RECEIVED.clear()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            result = identify(prepare_records(records, constant), torque_constant=constant)
    except DcMotorIdError:
        return None
    if 'La' not in result.upper_bounds or not RECEIVED or any(
            not np.isclose(RECEIVED['after'][key], result.stderr[key], equal_nan=True)
            for key in NAMES):
        return None
    said = [text.split(':')[0].split(', ') for text in result.warnings
            if 'armature equation is not decided' in text]
    named = set(said[0]) if said else set()
    row = {'case': name, 'named': named, 'not_identifiable': set(result.not_identifiable)}
    for key in NAMES:
        error = result.parameters[key] - getattr(truth, key)
        row[key] = (100.0 * error / getattr(truth, key), error / RECEIVED['before'][key],
                    error / result.stderr[key])
    return row


def honest(row, key, column):
    """Whether the truth is within 3 stated standard errors (column 1 without, 2 with)."""
    return abs(row[key][column]) <= 3.0 or (column == 2 and (
        key in row['named'] or key in row['not_identifiable']))


def summary_rows(rows):
    """Per group: quasi-static cases, and per parameter the honest ones without and with."""
    table = []
    for group in ('lab', 'random'):
        mine = [row for row in rows if row['case'].startswith(group)]
        table.append([group, str(len(mine))] + [
            f'{sum(honest(row, key, 1) for row in mine)} -> '
            f'{sum(honest(row, key, 2) for row in mine)}' for key in NAMES]
            + [str(sum(bool(row['named']) for row in mine))])
    return table


def detail_rows(rows):
    """One row per quasi-static case: errors, z without and with the part, named."""
    return [[row['case']] + [f'{row[key][0]:+.1f} ({row[key][1]:+.1f} / {row[key][2]:+.1f})'
                             for key in NAMES] + [', '.join(sorted(row['named'])) or '-']
            for row in rows]


def main(argv=None):
    """Run the cases; write the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--random-cases', type=int, default=120)
    parser.add_argument('--out', default='bench/armature_results.md')
    args = parser.parse_args(argv)
    stages.structure_stderr = recording
    load, started = os.getloadavg(), time.time()
    rows = []
    for case in [*lab_cases(), *random_cases(args.random_cases)]:
        row = judge(*case)
        rows += [row] if row else []
        print(f'[{time.time() - started:5.0f} s] {case[0]}: '
              f"{'quasi-static' if row else '-'}", file=sys.stderr, flush=True)
    lines = ['# The quasi-static armature: stated standard errors without and with the '
             "armature's part (issue 29)", '',
             f'Command: `bench/bench_armature.py --random-cases {args.random_cases}`  ',
             f'Load average at the start: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}; run '
             f'time {time.time() - started:.0f} s', '',
             'Cases that end quasi-static (La reported as an upper bound).  *Honest*: the '
             'truth within 3 stated standard errors, or (with the part) named by its warning '
             'or not identifiable; `a -> b`: without the part -> with it.  Errors in % '
             '(z without / z with: the error in stated standard errors).', '']
    lines += markdown_table(['cases', 'quasi-static'] + [f'{key} honest' for key in NAMES]
                            + ['warned'], summary_rows(rows)).splitlines()
    lines += ['', '## Every quasi-static case', '']
    lines += markdown_table(['case'] + [f'{key} % (z without / with)' for key in NAMES]
                            + ['named by the warning'], detail_rows(rows)).splitlines()
    write_report(lines, args.out)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
