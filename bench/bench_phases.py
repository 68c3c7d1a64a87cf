"""
Where the time of one ``dcmotor-id identify`` process goes, for one or more checkouts.

Two measurements on one CSV record (e.g. ``dcmotor-id simulate --motor paper2 --excitation
paper --duration 60 --sample-period 0.001 --noise 0.01 --out r60.csv``), each checkout run
with its own ``PYTHONPATH``, in turn (A B A B ...), bytecode caching on:

* **phases**: a fresh interpreter timing with ``time.process_time()`` the import of numpy, the
  package's imports, reading the CSV, a first and a second ``identify`` call (default
  options), and saying whether numba and which scipy modules ended up loaded;
* **whole**: the command ``python -m dcmotor_id.cli.main identify RECORD --json OUT`` as a whole
  process: CPU (user + system, ``os.wait4``) and wall seconds, medians.

Usage: ``.venv/bin/python bench/bench_phases.py RECORD.csv CHECKOUT [CHECKOUT ...]
[--repeats N]``; prints a markdown report.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from common import command_line, markdown_table

_PHASES = """
import json, sys, time
c0 = time.process_time()
import numpy as np
c1 = time.process_time()
import dcmotor_id.cli.main
from dcmotor_id.formats import read_records
from dcmotor_id.identification.identify import identify, prepare_records
c2 = time.process_time()
records = read_records([sys.argv[1]])
c3 = time.process_time()
identify(prepare_records(records))
c4 = time.process_time()
identify(prepare_records(records))
c5 = time.process_time()
print(json.dumps({'numpy': c1 - c0, 'imports': c2 - c1, 'read': c3 - c2, 'first': c4 - c3,
                  'second': c5 - c4, 'numba': 'numba' in sys.modules,
                  'scipy': sum(name.startswith('scipy') for name in sys.modules)}))
"""


def _environment(checkout):
    env = dict(os.environ)
    env['PYTHONPATH'] = checkout
    env.pop('PYTHONDONTWRITEBYTECODE', None)
    return env


def phases(record, checkout):
    """Time the steps of one fresh process; return them as a dict."""
    out = subprocess.run([sys.executable, '-c', _PHASES, record], env=_environment(checkout),
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def whole(record, checkout):
    """Run one ``identify`` command; return its CPU and wall seconds."""
    with tempfile.TemporaryDirectory() as directory:
        begin = time.perf_counter()
        process = subprocess.Popen(
            [sys.executable, '-m', 'dcmotor_id.cli.main', 'identify', record, '--json',
             os.path.join(directory, 'out.json')], env=_environment(checkout),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _, status, usage = os.wait4(process.pid, 0)
        wall = time.perf_counter() - begin
    if os.waitstatus_to_exitcode(status):
        raise RuntimeError(f'identify failed in {checkout}')
    return usage.ru_utime + usage.ru_stime, wall


def _span(values):
    low, high = min(values), max(values)
    return f'{low:.2f}' if f'{low:.2f}' == f'{high:.2f}' else f'{low:.2f}-{high:.2f}'


def main():
    """Run both measurements and print the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('record')
    parser.add_argument('checkouts', nargs='+')
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args()
    record = os.path.abspath(args.record)
    steps = {checkout: [] for checkout in args.checkouts}
    runs = {checkout: [] for checkout in args.checkouts}
    loads = [os.getloadavg()[0]]
    for _ in range(args.repeats):
        for checkout in args.checkouts:
            steps[checkout].append(phases(record, checkout))
            runs[checkout].append(whole(record, checkout))
    loads.append(os.getloadavg()[0])
    names = [('numpy', '`import numpy`'), ('imports', "the package's imports"),
             ('read', 'reading the CSV'), ('first', 'first `identify` call'),
             ('second', 'second `identify` call')]
    rows = [[label] + [_span([item[key] for item in steps[checkout]])
                       for checkout in args.checkouts] for key, label in names]
    rows.append(['numba loaded, scipy modules'] + [
        f'{steps[checkout][-1]["numba"]}, {steps[checkout][-1]["scipy"]}'
        for checkout in args.checkouts])
    rows.append(['whole command, cpu (median)'] + [
        f'{statistics.median(cpu for cpu, _ in runs[checkout]):.2f}'
        for checkout in args.checkouts])
    rows.append(['whole command, wall (median)'] + [
        f'{statistics.median(wall for _, wall in runs[checkout]):.2f}'
        for checkout in args.checkouts])
    print(f'Command: `{command_line()}`  ')
    print(f'Load average {loads[0]:.2f} at the start, {loads[1]:.2f} at the end; '
          f'{args.repeats} rounds; CPU seconds (min-max over the rounds) unless said.')
    print()
    print(markdown_table(['step'] + args.checkouts, rows))


if __name__ == '__main__':
    main()
