"""
Peak memory of the CSV reader per row: large files read without several copies in memory.

Writes CSV files of 100 k, 1 M and 10 M rows (five columns t, voltage, current, speed,
position at full precision, about 90 bytes a row: the 10 M-row file is the size of the
issue's 756 MB one), reads each with :func:`dcmotor_id.formats.read_record` in a fresh
process under an address-space limit of 2 GiB, and records the process's peak resident
memory over the baseline of a process that imports the same modules, per row.

    python bench/bench_csv_memory.py [--rows 100000 1000000 10000000] [--out FILE.md]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
#: Address-space limit of the reading process [bytes].
LIMIT_BYTES = 2 * 1024 ** 3
CHILD = r"""
import resource, sys, time
limit = int(sys.argv[3])
resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
from dcmotor_id.formats import read_record
start = time.perf_counter()
rows = 0
if sys.argv[1] == 'read':
    rows = len(read_record(sys.argv[2]))
print(rows, time.perf_counter() - start, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def write_file(path: str, rows: int) -> None:
    """Write a CSV of ``rows`` samples in blocks (the writer's own memory stays small)."""
    rng = np.random.default_rng(0)
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write('t,voltage,current,speed,position\n')
        block = 500_000
        for start in range(0, rows, block):
            n = min(block, rows - start)
            t = (start + np.arange(n)) * 1e-4
            table = np.column_stack([t, rng.normal(size=(n, 4))])
            np.savetxt(stream, table, delimiter=',', fmt='%.17g')


def measure(path: str, mode: str) -> tuple[int, float, int]:
    """Run the child; return rows, seconds and peak RSS [KiB]."""
    env = dict(os.environ, PYTHONPATH=ROOT, OPENBLAS_NUM_THREADS='1', OMP_NUM_THREADS='1')
    out = subprocess.run([sys.executable, '-c', CHILD, mode, path, str(LIMIT_BYTES)],
                         env=env, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-2000:])
    rows, seconds, peak = out.stdout.split()
    return int(rows), float(seconds), int(peak)


def main() -> int:
    """Run the benchmark and write the markdown table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--rows', type=int, nargs='+', default=[100_000, 1_000_000, 10_000_000])
    parser.add_argument('--out', default=os.path.join(HERE, 'csv_memory_results.md'))
    args = parser.parse_args()
    load = os.getloadavg()
    lines = []
    with tempfile.TemporaryDirectory() as directory:
        path = os.path.join(directory, 'big.csv')
        _, _, base = measure(path, 'baseline')
        for rows in args.rows:
            start = time.perf_counter()
            write_file(path, rows)
            written = time.perf_counter() - start
            size = os.path.getsize(path)
            count, seconds, peak = measure(path, 'read')
            assert count == rows
            extra = (peak - base) * 1024
            lines.append(f'| {rows:,} | {size / 1e6:.0f} MB | {seconds:.1f} s | '
                         f'{peak / 1024:.0f} MiB | {extra / 1024 ** 2:.0f} MiB | '
                         f'{extra / rows:.1f} B | {extra / (rows * 5 * 8):.2f} |')
            print(lines[-1], f'(written in {written:.0f} s)', flush=True)
            os.remove(path)
    text = ['# CSV reader: peak memory per row', '',
            'Command: `python bench/bench_csv_memory.py` '
            f'(load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} at the start; 2 '
            'shared cores). Each file has the columns t, voltage, current, speed, position '
            "written with '%.17g'; it is read by `dcmotor_id.formats.read_record` in a fresh "
            "process limited to 2 GiB of address space (RLIMIT_AS). Peak = the process's "
            f'maximum resident memory; the baseline (the same imports, no reading) is '
            f'{base / 1024:.0f} MiB. "x numbers" = the memory above the baseline over the '
            '8 bytes x 5 columns x rows the record holds.', '',
            '| rows | file | read time | peak RSS | above baseline | per row | x numbers |',
            '|---|---|---|---|---|---|---|'] + lines + [
            '', 'Before (the csv-module reader holding every row as a list of strings): 10.2 GB '
            'for the 10 M-row file (issue 9), about 1 kB a row.', '']
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(text))
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
