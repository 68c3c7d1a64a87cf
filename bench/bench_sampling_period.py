"""
Benchmark 2: error against the sample period dT (the paper's Figs. 9-10), both methods.

Both motors of Table 1, the paper's two training records (0.5 Hz 110 V sine for N1, 1 Hz 43 V
sawtooth for N2) of the same duration at every dT, exact (ZOH) noise-free simulation.  The
paper method's Euler discretisation biases La and J by about ``x / (1 - exp(-x))`` with
``x = dT / Ta`` (resp. ``dT b / J``); the refined method simulates the exact ZOH solution.

Usage: ``.venv/bin/python bench/bench_sampling_period.py [--duration S] [--periods S S ...]``
"""

import argparse
import sys
import time

from common import (command_line, DURATION_S, environment, errors_pct, fit_paper, fit_refined,
                    make_records, markdown_table, MOTOR_LABELS, pct, TABLE_NAMES)

from dcmotor_id.core.model import PAPER_MOTORS

PERIODS_S = (1e-5, 2e-5, 5e-5, 1e-4, 2e-4, 5e-4, 1e-3, 2e-3)


def run(periods_s, duration_s):
    """Sweep the sample period for both motors; return the markdown report."""
    lines = [f'Command: `{command_line()}`  ', f'Machine: {environment()}', '',
             f'Two records of {duration_s:g} s each at every dT (noise-free).', '']
    for motor, params in PAPER_MOTORS.items():
        rows = []
        for period in periods_s:
            records = make_records(params, 0.0, sample_period_s=period, duration_s=duration_s)
            paper = errors_pct(fit_paper(records), params)
            start = time.perf_counter()
            refined = errors_pct(fit_refined(records), params)
            refined_s = time.perf_counter() - start
            worst = max(refined, key=refined.get)
            rows.append([f'{period:g}'] + [pct(paper[name]) for name in TABLE_NAMES]
                        + [f'{pct(refined[worst])} ({worst})', f'{refined_s:.1f}'])
            print(f'  {motor} dT {period:g} s done', flush=True, file=sys.stderr)
        lines.append(f'### {MOTOR_LABELS[motor]}: relative error [%] against dT')
        lines.append('')
        lines.append(markdown_table(
            ['dT [s]'] + [f'paper {name}' for name in TABLE_NAMES]
            + ['refined, worst', 'refined fit [s]'], rows))
        lines.append('')
    return '\n'.join(lines)


def main():
    """Parse the options and print the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=DURATION_S,
                        help='length of each training record [s]')
    parser.add_argument('--periods', type=float, nargs='+', default=PERIODS_S,
                        help='sample periods to sweep [s]')
    args = parser.parse_args()
    print(run(args.periods, args.duration))


if __name__ == '__main__':
    main()
