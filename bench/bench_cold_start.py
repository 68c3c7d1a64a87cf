"""
Cold start of ``dcmotor-id identify``: the first and second run after a fresh clone.

The numba kernels are compiled with ``cache=True``: the first process that needs one compiles
it and writes it next to the source (``dcmotor_id/**/__pycache__/*.nbi, *.nbc``).  The
install step (``make`` runs ``python -m dcmotor_id.cli.warmup`` after ``pip install``) fills that
cache so that the user's first identification costs what the second does.  This measures it:

1. ``git clone`` of the repository's committed HEAD into a temporary directory; the clone's
   sources are used through ``PYTHONPATH`` with this interpreter (no new virtual environment);
2. one simulated record, ``dcmotor-id simulate --noise 0.01`` (motor 2, 8 s at 1e-4 s);
3. per scenario and repeat: numba cache files of the clone deleted, then (scenario "with the
   warm-up") the install's warm-up, then ``dcmotor-id identify record.csv --json OUT`` twice
   (the default command: refined method with effect discovery), each a new process.

Each step is timed from outside: wall time around the subprocess and CPU time (user + system)
from ``resource.getrusage(RUSAGE_CHILDREN)``; "kernels compiled" counts the cache files the
step added (0: everything came from the cache).  The load average is printed before and after
(2 shared cores: the wall times move with the other jobs, the CPU times much less).

Usage (from the repository root)::

    .venv/bin/python bench/bench_cold_start.py [--repeats N] [--out FILE]
"""

import argparse
import glob
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

from common import command_line, environment, markdown_table

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENARIOS = ('without the warm-up', 'with the warm-up')


def cache_files(clone):
    """Return the numba cache files of the clone's package."""
    pattern = os.path.join(clone, 'dcmotor_id', '**', '__pycache__', '*.nb[ic]')
    return sorted(glob.glob(pattern, recursive=True))


def clear_cache(clone):
    """Delete the numba cache files of the clone (the state right after a clone)."""
    for path in cache_files(clone):
        os.remove(path)


def timed(args, env, clone):
    """Run one process; return (wall [s], CPU [s], cache files added)."""
    before_files = len([path for path in cache_files(clone) if path.endswith('.nbc')])
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(args, env=env, cwd=clone, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    added = len([path for path in cache_files(clone) if path.endswith('.nbc')]) - before_files
    return wall, cpu, added


def run(repeats):
    """Measure every scenario; return the report lines."""
    load_start = os.getloadavg()
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix='dcmotor-id-cold-') as scratch:
        clone = os.path.join(scratch, 'dcmotor_id')
        subprocess.run(['git', 'clone', '--quiet', ROOT, clone], check=True)
        commit = subprocess.run(['git', '-C', clone, 'rev-parse', '--short', 'HEAD'],
                                check=True, capture_output=True, text=True).stdout.strip()
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            filter(None, [clone, os.environ.get('PYTHONPATH')])))
        where = subprocess.run([sys.executable, '-c', 'import dcmotor_id; '
                                'print(dcmotor_id.__file__)'], env=env, cwd=clone, check=True,
                               capture_output=True, text=True).stdout.strip()
        if not where.startswith(clone):
            raise RuntimeError(f'the clone is not the package imported: {where}')
        cli = [sys.executable, '-m', 'dcmotor_id.cli.main']
        record = os.path.join(scratch, 'record.csv')
        subprocess.run(cli + ['simulate', '--noise', '0.01', '--out', record], env=env,
                       cwd=clone, check=True, stdout=subprocess.DEVNULL)
        identify = cli + ['identify', record, '--json', os.path.join(scratch, 'result.json')]
        steps = {}
        for _ in range(repeats):
            for scenario in SCENARIOS:
                clear_cache(clone)
                if scenario == 'with the warm-up':
                    steps.setdefault((scenario, 'warm-up (the install step)'), []).append(
                        timed([sys.executable, '-m', 'dcmotor_id.cli.warmup', '--quiet'], env,
                              clone))
                for label in ('first identify', 'second identify'):
                    steps.setdefault((scenario, label), []).append(timed(identify, env, clone))
    load_end = os.getloadavg()
    rows = []
    for (scenario, label), values in steps.items():
        walls, cpus, added = zip(*values)
        rows.append([scenario, label, _spread(walls), _spread(cpus),
                     '/'.join(str(count) for count in added)])
    rows.sort(key=lambda row: SCENARIOS.index(row[0]))

    def median_wall(scenario, label):
        return statistics.median(value[0] for value in steps[(scenario, label)])

    first = {scenario: median_wall(scenario, 'first identify') for scenario in SCENARIOS}
    second = median_wall(SCENARIOS[1], 'second identify')
    return [
        f'Command: `{command_line()}`  ',
        f'Machine: {environment()}; load average {load_start[0]:.2f} at the start, '
        f'{load_end[0]:.2f} at the end ({time.perf_counter() - started:.0f} s in all)',
        '',
        f'Fresh clone of commit {commit}; record: `dcmotor-id simulate --noise 0.01` (motor 2, '
        '8 s at 1e-4 s, 80000 samples); identify: `dcmotor-id identify record.csv --json OUT` '
        f'(refined method with effect discovery).  Median over {repeats} repeats '
        '(min-max in brackets); kernels compiled: cache files the step wrote, per repeat.',
        '',
        markdown_table(['scenario', 'step', 'wall [s]', 'CPU [s]', 'kernels compiled'], rows),
        '',
        f'First identify: {first[SCENARIOS[0]]:.2f} s without the warm-up, '
        f'{first[SCENARIOS[1]]:.2f} s with it; second identify {second:.2f} s.',
    ]


def _spread(values):
    """Median with the range, e.g. ``3.41 (3.30-3.52)``."""
    if len(values) == 1:
        return f'{values[0]:.2f}'
    return f'{statistics.median(values):.2f} ({min(values):.2f}-{max(values):.2f})'


def main():
    """Print (and with ``--out`` also write) the cold-start table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--repeats', type=int, default=2, help='repeats of each scenario')
    parser.add_argument('--out', metavar='FILE', help='also write the markdown here')
    args = parser.parse_args()
    text = '\n'.join(['# Cold start: first and second `dcmotor-id identify` after a clone', '',
                      'Generated by `bench/bench_cold_start.py` (its docstring says how).', '']
                     + run(args.repeats)) + '\n'
    print(text, end='')
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as stream:
            stream.write(text)


if __name__ == '__main__':
    main()
