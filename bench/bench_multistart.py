"""
Several starts of the base fit (issue 19) on real records: before and after, row by row.

Every HSM150 single record and opposite pair (github malik-robert/HSM150-data, commit
35c3b1b) and every MECH 467 Part C record (github brucecui97/mech467, commit 36dde45) is
identified through the command line exactly as ``bench_real.py`` does (the original ``.mat``
files with the reading options), once by a checkout of the code before the change (``--before
DIR``, e.g. ``git worktree add /tmp/before 9c8e725``) and once by this checkout, one right
after the other on each row (paired under the same load), after the warm-up of each
(``python -m dcmotor_id.cli.warmup``, in no row).  The table gives J, b and Mc against
the references, the start the further starts chose (JSON ``start_check.starts_chosen``) and
their cost (``starts_cpu_s``), the process's CPU time, and the warnings.  Set-up as in
``bench_real.py``::

    .venv/bin/python bench/bench_multistart.py --before /tmp/before --hsm150 HSM150-data \
        --mech467 mech467 --out bench/multistart_results.md
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from typing import Any, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from bench_real import (HSM150_COMMIT, HSM150_K, HSM150_REFS, MECH467_COMMIT,  # noqa: E402
                        MECH467_GAIN, MECH467_K, MECH467_READING, MECH467_REFS, Repository,
                        ROOT, shorten)

HSM150_READING = ['--column', 't=data:1', '--column', 'current=data:7', '--column',
                  'speed=data:4']


def run_tree(tree: str, args: list[str], out: str) -> dict[str, Any]:
    """Run ``python -m dcmotor_id.cli identify ARGS`` from ``tree``; return the row's values."""
    env = dict(os.environ, PYTHONPATH=tree)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, '-m', 'dcmotor_id.cli', 'identify', *args,
                           '--json', out, '--quiet'], cwd=tree, env=env, capture_output=True,
                          text=True, timeout=900)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    row: dict[str, Any] = {'rc': done.returncode, 'wall': time.perf_counter() - start,
                           'cpu': (after.ru_utime - before.ru_utime)
                           + (after.ru_stime - before.ru_stime)}
    if done.returncode != 0:
        lines = [line for line in done.stderr.splitlines() if line.strip()]
        row['message'] = shorten((lines or ['(no message)'])[-1])
        return row
    with open(out, encoding='utf-8') as stream:
        result = json.load(stream)
    check = result.get('start_check') or {}
    row.update({name: result['parameters'].get(name) for name in ('J', 'b', 'Mc')})
    row.update(warnings=len(result.get('warnings') or []), chosen=check.get('chosen'),
               starts_chosen=check.get('starts_chosen'), starts_cpu=check.get('starts_cpu_s'),
               ambiguous=check.get('starts_ambiguous') or [],
               effects=[effect['name'] for effect in result.get('effects') or []])
    return row


def jobs(hsm150: Optional[str], mech467: Optional[str], cache: str
         ) -> list[tuple[str, str, list[str]]]:
    """Return the rows ``(data set, label, CLI arguments)``."""
    rows = []
    if hsm150:
        repo = Repository(hsm150, HSM150_COMMIT, os.path.join(cache, 'HSM150-data'))
        names = {os.path.basename(name)[:-4]: repo.local(name)
                 for name in repo.files('Data/Identification')}
        options = [*HSM150_READING, '--torque-constant', f'{HSM150_K:.6g}']
        rows += [('hsm150', stem, [names[stem], *options]) for stem in sorted(names)]
        pos = sorted(stem for stem in names if '_pos_' in stem)
        neg = sorted(stem for stem in names if '_neg_' in stem)
        rows += [('hsm150', f'{a[4:]} + {b[4:]}', [names[a], names[b], *options])
                 for a, b in zip(pos, neg)]
    if mech467:
        repo = Repository(mech467, MECH467_COMMIT, os.path.join(cache, 'mech467'))
        options = [*MECH467_READING, '--torque-constant', f'{MECH467_K * MECH467_GAIN:.6g}']
        files = repo.files('lab1/Group2/Part_C')
        files.sort(key=lambda name: int(os.path.basename(name)[:-4]))
        rows += [('mech467', f'C/{os.path.basename(name)[:-4]}', [repo.local(name), *options])
                 for name in files]
    return rows


def pct(value: Optional[float], ref: Optional[float]) -> str:
    """Format a value with its error against the reference."""
    if value is None:
        return '-'
    if ref is None:
        return f'{value:.3g}'
    return f'{value:.3g} ({100 * (value - ref) / ref:+.0f} %)'


def cell(row: dict[str, Any], name: str, ref: Optional[float]) -> str:
    """Return the value of a parameter with its error, or the refusal's exit code."""
    return pct(row.get(name), ref) if row['rc'] == 0 else f'exit {row["rc"]}'


def table(results: list[dict[str, Any]]) -> list[str]:
    """Return the rows of the markdown table."""
    lines = ['| data | row | J before | J after | b before | b after | Mc before | Mc after '
             '| start chosen (after) | further starts CPU s | CPU s before | CPU s after '
             '| warnings before, after |', '|' + '---|' * 13]
    for entry in results:
        before, after = entry['before'], entry['after']
        refs = HSM150_REFS if entry['data'] == 'hsm150' else MECH467_REFS
        chosen = after.get('starts_chosen') or '(no further starts)'
        if after.get('ambiguous'):
            chosen += ' (ambiguous with ' + ', '.join(after['ambiguous']) + ')'
        extra = after.get('starts_cpu')
        lines.append(
            f'| {entry["data"]} | {entry["label"]} | {cell(before, "J", refs.get("J"))} '
            f'| {cell(after, "J", refs.get("J"))} | {cell(before, "b", refs.get("b"))} '
            f'| {cell(after, "b", refs.get("b"))} | {cell(before, "Mc", None)} '
            f'| {cell(after, "Mc", None)} | {chosen} '
            f'| {"-" if extra is None else f"{extra:.2f}"} | {before["cpu"]:.1f} '
            f'| {after["cpu"]:.1f} '
            f'| {before.get("warnings", "-")}, {after.get("warnings", "-")} |')
    return lines


def git_commit(tree: str) -> str:
    """Return the short commit of a checkout ('unknown' without git)."""
    done = subprocess.run(['git', '-C', tree, 'rev-parse', '--short', 'HEAD'],
                          capture_output=True, text=True)
    return done.stdout.strip() or 'unknown'


def main() -> None:
    """Run every row before and after; write the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--before', required=True, metavar='DIR',
                        help='a checkout of the code before the change')
    parser.add_argument('--before-label', default=None,
                        help='the commit of --before when it is no git checkout')
    parser.add_argument('--after', default=ROOT, metavar='DIR',
                        help='a checkout of the code after the change (default: this one)')
    parser.add_argument('--after-label', default=None,
                        help='the commit of --after when it is no git checkout')
    parser.add_argument('--hsm150', metavar='DIR')
    parser.add_argument('--mech467', metavar='DIR')
    parser.add_argument('--out', required=True)
    args = parser.parse_args()
    load_start = os.getloadavg()
    began = time.perf_counter()
    results = []
    for tree in (args.before, args.after):
        # The set-up step of a user (`make demo`): the compiled kernels' cache, in no row.
        subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.warmup'], cwd=tree,
                       env=dict(os.environ, PYTHONPATH=tree), capture_output=True, check=True)
    with tempfile.TemporaryDirectory() as work:
        for data, label, cli in jobs(args.hsm150, args.mech467, work):
            entry = {'data': data, 'label': label}
            for tag, tree in (('before', args.before), ('after', args.after)):
                entry[tag] = run_tree(tree, cli, os.path.join(work, f'{tag}.json'))
            print(f'{data} {label}: CPU {entry["before"]["cpu"]:.1f} -> '
                  f'{entry["after"]["cpu"]:.1f} s', file=sys.stderr, flush=True)
            results.append(entry)
    load_end = os.getloadavg()
    cpu = {tag: sum(entry[tag]['cpu'] for entry in results) for tag in ('before', 'after')}
    extra = sum(entry['after'].get('starts_cpu') or 0.0 for entry in results)
    lines = [
        '# Several starts of the base fit (issue 19): real records before and after', '',
        'Command: `.venv/bin/python bench/bench_multistart.py --before BEFORE --hsm150 '
        'HSM150-data --mech467 mech467 --out bench/multistart_results.md`  ',
        f'Code: before {args.before_label or git_commit(args.before)}, after '
        f'{args.after_label or git_commit(args.after)}  ',
        f'Machine: {os.cpu_count()} CPUs, Python {platform.python_version()}; load average '
        f'(1, 5, 15 min) at the start {", ".join(f"{x:.2f}" for x in load_start)}, at the end '
        f'{", ".join(f"{x:.2f}" for x in load_end)} (other work shared the machine: compare '
        'CPU, not wall-clock, times)  ',
        f'Run time: {time.perf_counter() - began:.0f} s wall clock; identify CPU over all '
        f'rows {cpu["before"]:.1f} s before, {cpu["after"]:.1f} s after, of which the further '
        f'starts {extra:.1f} s', '',
        'Data: HSM150 (github malik-robert/HSM150-data at 35c3b1b, '
        '`Data/Identification/idf_*.mat`, read as in `bench_real.py`, `--torque-constant '
        '0.0458`): every single record and the six opposite pairs; J and b against the catalog '
        '(1.2e-4 kg m^2, 7.03e-5 N m s/rad), Mc as fitted (on one direction the total '
        'friction of that direction).  MECH 467 (github brucecui97/mech467 at 36dde45, '
        '`lab1/Group2/Part_C/*.mat`, the reading options of `bench_real.py`): J against '
        "7e-4 kg m^2 (Mc: the group's Coulomb friction is about 0.22 N m).  *start chosen*: "
        'the start whose base fit the rest started from (`start_check.starts_chosen`; '
        '*default* when no further start explained the data better), *further starts CPU s*: '
        'their cost (`start_check.starts_cpu_s`), *CPU s*: the whole `identify` process.', '',
        *table(results), '']
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(lines))
    print(f'wrote {args.out}', file=sys.stderr)


if __name__ == '__main__':
    main()
