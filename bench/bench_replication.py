"""
Benchmark 1: the paper's Tables 2-3 replicated, beside the default (refined) method.

Table 1 motors, the paper's training sets (N1: 0.5 Hz 110 V sine, N2: 1 Hz 43 V sawtooth, 4 s
each), dT = 1e-4 s, exact (ZOH) noise-free simulation.  The paper method trains N1 on the sine
and N2 on the sawtooth, as the paper did; the refined method fits both records together.

Usage: ``.venv/bin/python bench/bench_replication.py [--duration S] [--sample-period S]``
"""

import argparse
import time

from common import (command_line, DURATION_S, environment, errors_pct, fit_paper, fit_refined,
                    make_records, markdown_table, MOTOR_LABELS, PAPER_REPORTED_PCT, pct,
                    TABLE_NAMES)

from dcmotor_id.core.model import PAPER_MOTORS, UNITS


def run(duration_s, sample_period_s):
    """Identify both motors with both methods; return the markdown report."""
    lines = [f'Command: `{command_line()}`  ', f'Machine: {environment()}', '']
    summary = []
    for motor, params in PAPER_MOTORS.items():
        records = make_records(params, 0.0, sample_period_s=sample_period_s,
                               duration_s=duration_s)
        start = time.perf_counter()
        paper = fit_paper(records)
        paper_s = time.perf_counter() - start
        start = time.perf_counter()
        refined = fit_refined(records)
        refined_s = time.perf_counter() - start
        paper_err = errors_pct(paper, params)
        refined_err = errors_pct(refined, params)
        truth = params.as_dict()
        rows = []
        for name in TABLE_NAMES:
            rows.append([name, f'{truth[name]:.6g} {UNITS[name]}',
                         pct(PAPER_REPORTED_PCT[motor][name]), pct(paper_err[name]),
                         pct(refined_err[name]),
                         pct(refined.stderr[name] / abs(refined.parameters[name]) * 100)])
        lines.append(f'### {MOTOR_LABELS[motor]}: relative error [%], dT = '
                     f'{sample_period_s:g} s, noise-free')
        lines.append('')
        lines.append(markdown_table(
            ['parameter', 'truth', 'paper, Table ' + ('2' if motor == 'paper1' else '3'),
             'paper method (ours)', 'refined', 'refined stderr'], rows))
        lines.append('')
        lines.append(f'Fit time: paper method {paper_s:.2f} s, refined {refined_s:.2f} s '
                     f'({sum(len(rec) for rec in records)} samples).')
        lines.append('')
        summary.append((motor, max(paper_err.values()), max(refined_err.values())))
    lines.append('Worst parameter error: ' + '; '.join(
        f'{MOTOR_LABELS[motor]}: paper method {pct(worst_paper)} %, refined '
        f'{pct(worst_refined)} %' for motor, worst_paper, worst_refined in summary) + '.')
    return '\n'.join(lines)


def main():
    """Parse the options and print the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=DURATION_S,
                        help='length of each training record [s]')
    parser.add_argument('--sample-period', type=float, default=1e-4, help='dT [s]')
    args = parser.parse_args()
    print(run(args.duration, args.sample_period))


if __name__ == '__main__':
    main()
