r"""
Run time of ``dcmotor-id identify`` on the HSM150 records, paired against an earlier commit.

Issue 19 asks for any record up to 300k samples in under 30 s.  The scorecard
(``bench_real.py``) found idf_pos_0.065_1 alone at 56 s of CPU and all 12 records at 58 s.
This benchmark runs the same command lines (the reading options of the scorecard, the
README's ``identify FILE... --torque-constant K --json OUT``) with the package of this
checkout ("after") and with the package of an earlier commit ("before", extracted with
``git archive`` into a temporary directory), one after the other for every fit, so that both
see the same load.  Before the first fit each tree runs the set-up's warm-up
(``python -m dcmotor_id.cli.warmup``, as ``make demo`` does at install), timed on its own:
without it the first fit of a fresh tree pays for compiling the numba kernels (about a
minute of CPU), which is what the scorecard's 56 s for idf_pos_0.065_1 was.

Fits: every single record, the three runs (4 records each) and all 12 records.  For each:
wall-clock and CPU seconds of the process, whether the time budget (``--max-time``, default
120 s; wall clock in trees before the budget counted CPU seconds of the process, see
``dcmotor_id.core.progress.budget_clock``) ran out, J and b of both, and whether the results
are identical.

Set-up: the HSM150 data as for ``bench_real.py`` (a work tree or a bare clone of
github malik-robert/HSM150-data at 35c3b1b).  Run from the repository root::

    .venv/bin/python bench/bench_real_time.py --hsm150 HSM150-data --before 1b9de8a \
        --out bench/real_time_results.md
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any, Optional

import bench_real

ROOT = bench_real.ROOT


def extract(revision: str, target: str) -> str:
    """Write the package of ``revision`` into ``target``; return its short commit."""
    archive = subprocess.run(['git', '-C', ROOT, 'archive', revision, 'dcmotor_id'],
                             capture_output=True, check=True).stdout
    subprocess.run(['tar', '-x', '-C', target], input=archive, check=True)
    return subprocess.run(['git', '-C', ROOT, 'rev-parse', '--short', revision],
                          capture_output=True, text=True, check=True).stdout.strip()


def run(tree: str, module: str, args: list[str]) -> dict[str, Any]:
    """Run ``python -m module ARGS`` with ``tree`` first on the path; return rc and times."""
    env = dict(os.environ, PYTHONPATH=tree)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, '-m', module, *args], cwd=tree, env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {'rc': done.returncode, 'wall': wall, 'cpu': cpu,
            'stderr': done.stderr.strip().splitlines()[-1:] if done.returncode else []}


def identify(tree: str, files: list[str], out: str) -> dict[str, Any]:
    """Identify the records as the scorecard does; return the times and the result."""
    hsm = ['--column', 't=data:1', '--column', 'current=data:7', '--column', 'speed=data:4',
           '--torque-constant', f'{bench_real.HSM150_K:g}']
    result = run(tree, 'dcmotor_id.cli', ['identify', *files, *hsm, '--json', out])
    result['json'] = None
    if result['rc'] == 0 and os.path.isfile(out):
        with open(out) as stream:
            result['json'] = json.load(stream)
    return result


def jobs(names: list[str]) -> list[tuple[str, list[str]]]:
    """Every single record, the three runs and all 12 (label, record names)."""
    out = [(name, [name]) for name in sorted(names)]
    for run_number in ('1', '2', '3'):
        out.append((f'run {run_number} (4 records)',
                    [n for n in sorted(names) if n.endswith('_' + run_number)]))
    out.append(('all 12', sorted(names)))
    return out


def cells(result: dict[str, Any]) -> tuple[str, str, str]:
    """Return the time, budget and J/b cells of one run."""
    data = result['json']
    if data is None:
        return f'{result["wall"]:.1f} ({result["cpu"]:.1f})', f'exit {result["rc"]}', '-'
    # the warning, or the discovery loop's reason (it keeps its best structure so far)
    ran_out = any('time budget' in text for text in data.get('warnings', [])) or \
        'time budget' in str((data.get('discovery') or {}).get('reason', ''))
    refs = bench_real.HSM150_REFS
    values = data['parameters']
    jb = (f'{100 * (values["J"] / refs["J"] - 1):+.0f} / '
          f'{100 * (values["b"] / refs["b"] - 1):+.0f}')
    return f'{result["wall"]:.1f} ({result["cpu"]:.1f})', 'ran out' if ran_out else '-', jb


def same(a: dict[str, Any], b: dict[str, Any]) -> str:
    """Whether two runs gave the same parameters and standard errors."""
    if a['json'] is None or b['json'] is None:
        return '-'
    keys = ('parameters', 'stderr', 'effects', 'initial_states')
    return 'yes' if all(a['json'].get(k) == b['json'].get(k) for k in keys) else 'no'


def table(rows: list[dict[str, Any]]) -> list[str]:
    """Return the markdown table of the paired runs."""
    lines = ['| fit | samples | before: wall s (CPU) | after: wall s (CPU) | CPU after / before '
             '| budget ran out (before, after) | J / b % vs catalog (before; after) '
             '| identical results |', '|---|---|---|---|---|---|---|---|']
    for row in rows:
        time_b, budget_b, jb_b = cells(row['before'])
        time_a, budget_a, jb_a = cells(row['after'])
        ratio = row['after']['cpu'] / max(row['before']['cpu'], 1e-9)
        lines.append(f'| {row["label"]} | {row["samples"]} | {time_b} | {time_a} | {ratio:.2f} '
                     f'| {budget_b}, {budget_a} | {jb_b}; {jb_a} '
                     f'| {same(row["before"], row["after"])} |')
    return lines


def parse(argv: Optional[list[str]]) -> argparse.Namespace:
    """Parse the command line."""
    parser = argparse.ArgumentParser(description=__doc__.strip().split('\n')[0])
    parser.add_argument('--hsm150', metavar='DIR', required=True,
                        help='HSM150-data (work tree or bare clone)')
    parser.add_argument('--before', metavar='REV', required=True,
                        help='the commit to pair against')
    parser.add_argument('--out', metavar='FILE.md', help='also write the report here')
    parser.add_argument('--fits', nargs='+', metavar='LABEL',
                        help="only these fits (labels as in the table, e.g. 'all 12')")
    return parser.parse_args(argv)


def measure(args: argparse.Namespace, work: str) -> tuple[list[dict[str, Any]], dict, str]:
    """Warm both trees up, run every fit before and after; return rows, set-up, commit."""
    before_tree = os.path.join(work, 'before')
    os.makedirs(before_tree)
    commit = extract(args.before, before_tree)
    trees = {'before': before_tree, 'after': ROOT}
    setup = {side: run(tree, 'dcmotor_id.cli.warmup', []) for side, tree in trees.items()}
    records = bench_real._hsm150_records(bench_real.Repository(
        args.hsm150, bench_real.HSM150_COMMIT, os.path.join(work, 'HSM150-data')))
    rows = []
    for label, names in jobs(list(records)):
        if args.fits and label not in args.fits:
            continue
        row: dict[str, Any] = {'label': label,
                               'samples': sum(len(records[n].t) for n in names)}
        for side, tree in trees.items():
            row[side] = identify(tree, [records[n].path for n in names],
                                 os.path.join(work, f'{side}.json'))
        bench_real.log(f'{label}: CPU {row["before"]["cpu"]:.1f} -> {row["after"]["cpu"]:.1f} s')
        rows.append(row)
    return rows, setup, commit


def main(argv: Optional[list[str]] = None) -> int:
    """Run the paired fits; print the report (and write it with --out)."""
    args = parse(argv)
    load = os.getloadavg()
    work = tempfile.mkdtemp(prefix='bench_real_time_')
    try:
        rows, setup, commit = measure(args, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    end = os.getloadavg()
    over = [row['label'] for row in rows if row['after']['wall'] > 30.0]
    lines = ['# Run time of identify on the HSM150 records, paired (issue 19)', '',
             f'Command: `.venv/bin/python bench/bench_real_time.py --hsm150 HSM150-data '
             f'--before {args.before}' + (f' --out {args.out}' if args.out else '')
             + (' --fits ' + ' '.join(f"'{label}'" for label in args.fits)
                if args.fits else '') + '`  ',
             f'Before: commit {commit}; after: commit {bench_real.code_version()}  ',
             f'Machine: {os.cpu_count()} CPUs, Python {sys.version.split()[0]}; load average '
             f'(1, 5, 15 min) at the start {", ".join(f"{v:.2f}" for v in load)}, at the end '
             f'{", ".join(f"{v:.2f}" for v in end)}  ',
             'Set-up warm-up (`python -m dcmotor_id.cli.warmup`, in no row): '
             + ', '.join(f'{side} {s["wall"]:.0f} s wall ({s["cpu"]:.0f} s CPU, exit {s["rc"]})'
                         for side, s in setup.items()), '',
             'Each fit ran before, then after, as separate processes (imports included). '
             '*budget ran out*: the time budget (120 s: of wall clock in a tree without '
             '`dcmotor_id.core.progress.budget_clock`, of CPU time of the process in one with '
             'it) ran out (a warning, or the discovery loop kept its best structure so far), so '
             'that run did less work and its result differs. '
             '*identical results*: parameters, standard errors, effects and initial states '
             'equal.', '']
    lines += table(rows)
    over_cpu = [row['label'] for row in rows if row['after']['cpu'] > 30.0]
    lines += ['', f'After: {len(rows) - len(over)}/{len(rows)} fits under 30 s of wall clock'
              + (f' (over: {", ".join(over)})' if over else '') + '; '
              f'{len(rows) - len(over_cpu)}/{len(rows)} under 30 s of CPU'
              + (f' (over: {", ".join(over_cpu)})' if over_cpu else '') + '.']
    text = '\n'.join(lines)
    bench_real.emit(text, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
