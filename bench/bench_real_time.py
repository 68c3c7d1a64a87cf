r"""
Run time of ``dcmotor-id identify`` on real records, paired against an earlier commit.

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

The MECH 467 ball-screw lab (``--mech467``) and EMPS (``--emps``) take the scorecard's
fits and reading options too (every record, all of Part C, its halves, all parts; EMPS each
record and both): their fits are on the position, where the identification may run twice
(:mod:`dcmotor_id.identification.pipeline.position_error`).  Their table gives J, b and Mc of both
trees and the largest relative difference of the parameters when not identical.

Set-up: the data as for ``bench_real.py`` (a work tree or a bare clone of
github malik-robert/HSM150-data at 35c3b1b, of github brucecui97/mech467 at 36dde45; the EMPS
files).  Run from the repository root::

    .venv/bin/python bench/bench_real_time.py --mech467 mech467 --emps data/emps \
        --before d373b3c --out bench/real_time_results.md

(the committed table; ``--hsm150 HSM150-data`` times the HSM150 fits the same way).
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


HSM150_OPTIONS = ['--column', 't=data:1', '--column', 'current=data:7', '--column',
                  'speed=data:4', '--torque-constant', f'{bench_real.HSM150_K:g}']


def identify(tree: str, files: list[str], out: str,
             options: Optional[list[str]] = None) -> dict[str, Any]:
    """Identify the records as the scorecard does; return the times and the result."""
    options = HSM150_OPTIONS if options is None else options
    result = run(tree, 'dcmotor_id.cli', ['identify', *files, *options, '--json', out])
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
    """Whether two runs gave the same parameters and standard errors (else how far apart)."""
    if a['json'] is None or b['json'] is None:
        return '-'
    keys = ('parameters', 'stderr', 'effects', 'initial_states')
    if all(a['json'].get(k) == b['json'].get(k) for k in keys):
        return 'yes'
    first, second = a['json']['parameters'], b['json']['parameters']
    names = [name for name in first if name in second]
    worst = max((abs(second[n] - first[n]) / max(abs(first[n]), 1e-300) for n in names),
                default=float('nan'))
    effects = [e['name'] for e in a['json'].get('effects', [])] == \
        [e['name'] for e in b['json'].get('effects', [])]
    return f'no: parameters within {worst:.1e} (relative)' + \
        ('' if effects else '; other effects')


def values_cell(result: dict[str, Any]) -> str:
    """J, b and Mc of a run (4 significant digits) and its effects, or its exit code."""
    data = result['json']
    if data is None:
        return f'exit {result["rc"]}'
    values = data['parameters']
    effects = ', '.join(effect['name'] for effect in data.get('effects', []))
    return ' / '.join(f'{values[name]:.4g}' for name in ('J', 'b', 'Mc')) + \
        (f' ({effects})' if effects else '')


def position_table(rows: list[dict[str, Any]]) -> list[str]:
    """Return the markdown table of the paired runs on the position (MECH 467, EMPS)."""
    lines = ['| data | fit | samples | before: wall s (CPU) | after: wall s (CPU) '
             '| CPU after / before | J / b / Mc before | J / b / Mc after | identical results |',
             '|---|---|---|---|---|---|---|---|---|']
    for row in rows:
        before, after = row['before'], row['after']
        ratio = after['cpu'] / max(before['cpu'], 1e-9)
        lines.append(f'| {row["data"]} | {row["label"]} | {row["samples"]} '
                     f'| {before["wall"]:.1f} ({before["cpu"]:.1f}) '
                     f'| {after["wall"]:.1f} ({after["cpu"]:.1f}) | {ratio:.2f} '
                     f'| {values_cell(before)} | {values_cell(after)} | {same(before, after)} |')
    return lines


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
    parser.add_argument('--hsm150', metavar='DIR', help='HSM150-data (work tree or bare clone)')
    parser.add_argument('--mech467', metavar='DIR', help='mech467 (work tree or bare clone)')
    parser.add_argument('--emps', metavar='DIR', help='the EMPS .mat files')
    parser.add_argument('--before', metavar='REV', required=True,
                        help='the commit to pair against')
    parser.add_argument('--out', metavar='FILE.md', help='also write the report here')
    parser.add_argument('--fits', nargs='+', metavar='LABEL',
                        help="only these fits (labels as in the table, e.g. 'all 12')")
    args = parser.parse_args(argv)
    if not (args.hsm150 or args.mech467 or args.emps):
        parser.error('give the data: --hsm150 DIR, --mech467 DIR and/or --emps DIR')
    return args


def fit_jobs(args: argparse.Namespace, work: str) -> list[dict[str, Any]]:
    """Every fit asked for: data, label, files, samples and reading options."""
    out: list[dict[str, Any]] = []
    if args.hsm150:
        records = bench_real._hsm150_records(bench_real.Repository(
            args.hsm150, bench_real.HSM150_COMMIT, os.path.join(work, 'HSM150-data')))
        out += [{'data': 'HSM150', 'label': label, 'names': names, 'records': records,
                 'options': HSM150_OPTIONS} for label, names in jobs(list(records))]
    if args.mech467:
        repo = bench_real.Repository(args.mech467, bench_real.MECH467_COMMIT,
                                     os.path.join(work, 'mech467'))
        stems = bench_real._mech467_stems(repo, False)
        records = bench_real._mech467_records(repo, stems)
        options = bench_real.MECH467_READING + [
            '--torque-constant', f'{bench_real.MECH467_K * bench_real.MECH467_GAIN:.6g}']
        out += [{'data': 'MECH 467', 'label': job.label, 'names': job.members,
                 'records': records, 'options': options}
                for job in bench_real._mech467_jobs(stems, False)]
    if args.emps:
        emps = bench_real.emps_set(args.emps, False)
        options = emps.reading + ['--torque-constant', f'{emps.torque_constant:.6g}']
        out += [{'data': 'EMPS', 'label': job.label, 'names': job.members,
                 'records': emps.records, 'options': options} for job in emps.jobs]
    return [job for job in out if not args.fits or job['label'] in args.fits]


def measure(args: argparse.Namespace, work: str) -> tuple[list[dict[str, Any]], dict, str]:
    """Warm both trees up, run every fit before and after; return rows, set-up, commit."""
    before_tree = os.path.join(work, 'before')
    os.makedirs(before_tree)
    commit = extract(args.before, before_tree)
    trees = {'before': before_tree, 'after': ROOT}
    setup = {side: run(tree, 'dcmotor_id.cli.warmup', []) for side, tree in trees.items()}
    rows = []
    for job in fit_jobs(args, work):
        records = job['records']
        row: dict[str, Any] = {'data': job['data'], 'label': job['label'],
                               'samples': sum(len(records[n].t) for n in job['names'])}
        for side, tree in trees.items():
            row[side] = identify(tree, [records[n].path for n in job['names']],
                                 os.path.join(work, f'{side}.json'), job['options'])
        bench_real.log(f'{job["data"]} {job["label"]}: CPU {row["before"]["cpu"]:.1f} -> '
                       f'{row["after"]["cpu"]:.1f} s')
        rows.append(row)
    return rows, setup, commit


def command(args: argparse.Namespace) -> str:
    """Return the command line of this run, as the report quotes it."""
    parts = ['.venv/bin/python bench/bench_real_time.py']
    parts += [f'--{name} {value}' for name, value in
              (('hsm150', 'HSM150-data' if args.hsm150 else None),
               ('mech467', 'mech467' if args.mech467 else None),
               ('emps', '../shared/data/emps' if args.emps else None),
               ('before', args.before), ('out', args.out)) if value]
    if args.fits:
        parts.append('--fits ' + ' '.join(f"'{label}'" for label in args.fits))
    return ' '.join(parts)


def summary(rows: list[dict[str, Any]]) -> list[str]:
    """How many fits ran under 30 s (wall clock, CPU) after."""
    over = [row['label'] for row in rows if row['after']['wall'] > 30.0]
    over_cpu = [row['label'] for row in rows if row['after']['cpu'] > 30.0]
    over_before = [row['label'] for row in rows if row['before']['cpu'] > 30.0]
    return ['', f'After: {len(rows) - len(over)}/{len(rows)} fits under 30 s of wall clock'
            + (f' (over: {", ".join(over)})' if over else '') + '; '
            f'{len(rows) - len(over_cpu)}/{len(rows)} under 30 s of CPU'
            + (f' (over: {", ".join(over_cpu)})' if over_cpu else '') + '.  Before: '
            f'{len(rows) - len(over_before)}/{len(rows)} under 30 s of CPU'
            + (f' (over: {", ".join(over_before)})' if over_before else '') + '.']


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
    data = ', '.join(sorted({row['data'] for row in rows}))
    lines = [f'# Run time of identify on real records ({data}), paired (issue 19)', '',
             f'Command: `{command(args)}`  ',
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
             'equal (else the largest relative difference of the parameters).', '']
    hsm = [row for row in rows if row['data'] == 'HSM150']
    position = [row for row in rows if row['data'] != 'HSM150']
    if hsm:
        lines += table(hsm) + ['']
    if position:
        lines += position_table(position)
    lines += summary(rows)
    text = '\n'.join(lines)
    bench_real.emit(text, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
