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

from dcmotor_id.core.records import Record
from dcmotor_id.identification.identify import identify
from dcmotor_id.simulation.lab_scenarios import (SCENARIOS, SERVO_MOTOR, simulate_drive,
                                                 step_levels)

NAMES = ('J', 'b', 'Mc')


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


def main(argv=None):
    """Print the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    parser.add_argument('--seeds', type=int, default=20)
    parser.add_argument('--records', type=int, default=4, help='records per half (part 2)')
    parser.add_argument('--friction-spread', type=float, default=0.1)
    args = parser.parse_args(argv)
    start = time.process_time()
    lines = ['# Standard errors of fits of several records', '',
             f'`bench/bench_records.py --seeds {args.seeds} --records {args.records} '
             f'--friction-spread {args.friction_spread}`; load average before: '
             f'{" ".join(f"{v:.2f}" for v in os.getloadavg())}', '',
             '## 1. Laboratory scenarios with several records (parameters shared exactly)', '']
    lines += lab_rows(args.seeds)
    lines += ['', '## 2. Records with a friction of their own, disjoint halves', '']
    lines += class_rows(args.seeds, args.records, args.friction_spread)
    lines += ['', f'CPU {time.process_time() - start:.0f} s; load average after: '
              f'{" ".join(f"{v:.2f}" for v in os.getloadavg())}']
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
