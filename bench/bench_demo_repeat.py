"""
``make demo`` several times in a row: the same data length every time, every parameter close.

Runs ``python -m dcmotor_id.nodes.demo`` (sim_motor and identifier as processes, 12 s
recorded, then ``~/identify``) ``--runs`` times one after the other, each in a ROS domain of
its own, and reads from each run's output the line ``fitted N samples ...`` and the table of
the identified parameters against the simulated motor's. The table gives, per run, the
samples and windows fitted, the wall time and the largest relative error of the identified
Ra, La, CPhi, J, b, Mc; then the error of each parameter per run. The issue's goal: the same
data length every time and every parameter within 0.1 %. Run it while the machine is loaded
(other jobs) to see whether load changes either.

Usage (from the repository root; writes bench/demo_repeat_results.md, about 1 minute a run)::

    .venv/bin/python bench/bench_demo_repeat.py [--runs 5] [--out FILE]
"""

import argparse
import datetime
import os
import platform
import re
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: The parameters whose error the goal bounds (the identified column of the demo's table).
KEYS = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
#: The goal: every parameter within this relative error [%].
GOAL_PERCENT = 0.1


def run_once(index: int, timeout_s: float) -> dict:
    """Run the demo once; return its exit code, samples, windows, errors [%] and wall time."""
    env = dict(os.environ, PYTHONPATH=ROOT, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               ROS_DOMAIN_ID=str(150 + (os.getpid() + index) % 80))
    start = time.monotonic()
    try:
        done = subprocess.run([sys.executable, '-m', 'dcmotor_id.nodes.demo'], cwd=ROOT,
                              env=env, capture_output=True, text=True, timeout=timeout_s)
        output, code = done.stdout + done.stderr, done.returncode
    except subprocess.TimeoutExpired as expired:
        output, code = str(expired.stdout or ''), -1
    return {'code': code, 'wall_s': time.monotonic() - start, **parse_output(output),
            'tail': output.strip().splitlines()[-3:]}


def parse_output(output: str) -> dict:
    """Read the samples and windows fitted and the identified column's errors [%]."""
    fitted = re.search(r'fitted (\d+) samples .* in (\d+) window', output)
    errors = {}
    for key in KEYS:
        row = re.search(rf'^{key}\s+(\S+)\s+(\S+)\s+(\S+)', output, re.MULTILINE)
        if row is not None and row.group(2) != '-':
            errors[key] = abs(float(row.group(2)) / float(row.group(1)) - 1) * 100
    return {'samples': int(fitted.group(1)) if fitted else None,
            'windows': int(fitted.group(2)) if fitted else None, 'errors': errors}


def table(runs: list[dict], load: str) -> str:
    """Return the Markdown page of the runs."""
    lengths = {run['samples'] for run in runs}
    worst = max((max(run['errors'].values(), default=float('inf')) for run in runs),
                default=float('inf'))
    ok = all(run['code'] == 0 for run in runs) and len(lengths) == 1 and worst <= GOAL_PERCENT
    lines = [
        '# `make demo` repeated (issue 32)', '',
        f'`bench/bench_demo_repeat.py --runs {len(runs)}`, '
        f'{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, '
        f'{platform.machine()}, {os.cpu_count()} cores; load average at the start: {load}.',
        'Each run is `python -m dcmotor_id.nodes.demo` (12 s recorded at 1 kHz, then '
        '`~/identify`), one after the other; errors are of the identified column against '
        'the simulated motor (paper motor 2), from the values the demo prints (5 digits).', '',
        '| run | exit | samples fitted | windows | wall [s] | worst error [%] |',
        '|---:|---:|---:|---:|---:|---:|']
    for number, run in enumerate(runs, 1):
        errors = run['errors']
        lines.append(f'| {number} | {run["code"]} | {run["samples"]} | {run["windows"]} | '
                     f'{run["wall_s"]:.0f} | '
                     f'{max(errors.values()) if errors else float("nan"):.4f} |')
    lines += ['', '| run | ' + ' | '.join(f'{key} [%]' for key in KEYS) + ' |',
              '|---:|' + '---:|' * len(KEYS)]
    for number, run in enumerate(runs, 1):
        lines.append(f'| {number} | ' + ' | '.join(
            f'{run["errors"].get(key, float("nan")):.4f}' for key in KEYS) + ' |')
    lines += ['', f'Same data length every run: {"yes" if len(lengths) == 1 else "no"} '
              f'({", ".join(str(length) for length in sorted(lengths, key=str))} samples); '
              f'worst parameter error {worst:.4f} % (goal {GOAL_PERCENT} %): '
              f'{"met" if ok else "NOT met"}.', '']
    return '\n'.join(lines)


def main() -> int:
    """Run the demo ``--runs`` times and write the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--runs', type=int, default=5)
    parser.add_argument('--timeout-s', type=float, default=600.0)
    parser.add_argument('--out', default=os.path.join(ROOT, 'bench', 'demo_repeat_results.md'))
    args = parser.parse_args()
    load = ', '.join(f'{value:.1f}' for value in os.getloadavg())
    runs = []
    for index in range(args.runs):
        runs.append(run_once(index, args.timeout_s))
        run = runs[-1]
        print(f'run {index + 1}: exit {run["code"]}, {run["samples"]} samples, '
              f'{run["wall_s"]:.0f} s, errors {run["errors"]}', flush=True)
        if run['code'] != 0:
            print('\n'.join(run['tail']), flush=True)
    text = table(runs, load)
    with open(args.out, 'w') as out:
        out.write(text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
