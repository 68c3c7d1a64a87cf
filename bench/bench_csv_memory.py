"""
Peak memory of the readers per row and per byte of input: CSV, .mat, Parquet and MCAP.

Writes files of 100 k, 1 M and 10 M rows (five columns t, voltage, current, speed,
position at full precision; a CSV row is about 90 bytes: the 10 M-row file is the size of
issue 9's 756 MB one) in each format, reads each with
:func:`dcmotor_id.formats.read_record` in a fresh process under an address-space limit of
2 GiB, and records the process's peak resident memory over the baseline of a process that
imports the same modules, per row and as a multiple of the file's size (issue 21: the peak
memory of any input of size S is a documented multiple of S). MCAP bags hold the batched
samples topic (250 samples a message, as the identifier node records them), and, up to
1 M rows, the three Float64 topics (one message per sample and channel).

    python bench/bench_csv_memory.py [--rows 100000 1000000 10000000]
        [--formats csv mat parquet mcap mcap-float64] [--out FILE.md]
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
import scipy.io, pyarrow.parquet, rosbags.rosbag2  # the readers' imports, in the baseline
if sys.argv[1] == 'read':
    rows = len(read_record(sys.argv[2]))
print(rows, time.perf_counter() - start, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def write_file(path: str, rows: int) -> None:
    """Write a CSV of ``rows`` samples in blocks (the writer's own memory stays small)."""
    if path.endswith(('.mat', '.parquet')) or os.path.basename(path).startswith('bag'):
        write_binary(path, rows)
        return
    rng = np.random.default_rng(0)
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write('t,voltage,current,speed,position\n')
        block = 500_000
        for start in range(0, rows, block):
            n = min(block, rows - start)
            t = (start + np.arange(n)) * 1e-4
            table = np.column_stack([t, rng.normal(size=(n, 4))])
            np.savetxt(stream, table, delimiter=',', fmt='%.17g')


def _table(rows: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    columns = {'t': np.arange(rows) * 1e-4}
    for name in ('voltage', 'current', 'speed', 'position'):
        columns[name] = rng.normal(size=rows)
    return columns


def write_binary(path: str, rows: int) -> None:
    """Write ``rows`` samples as .mat (v5), Parquet or an MCAP bag (batched or Float64)."""
    columns = _table(rows)
    if path.endswith('.mat'):
        from scipy.io import savemat
        savemat(path, columns)
    elif path.endswith('.parquet'):
        import pyarrow as pa
        import pyarrow.parquet as pq
        pq.write_table(pa.table(columns), path)
    else:
        sys.path.insert(0, ROOT)
        from dcmotor_id.formats.bag import write_bag
        stamps = 1_700_000_000_000_000_000 + np.arange(rows, dtype=np.int64) * 100_000
        channels = {name: columns[name] for name in ('voltage', 'current', 'speed')}
        write_bag(path, stamps, channels, batch_samples=0 if path.endswith('float64') else 250)


#: File name of each format in the temporary directory.
FILES = {'csv': 'big.csv', 'mat': 'big.mat', 'parquet': 'big.parquet', 'mcap': 'bag_batched',
         'mcap-float64': 'bag_float64'}


def _size(path: str) -> int:
    if os.path.isdir(path):
        return sum(os.path.getsize(os.path.join(path, name)) for name in os.listdir(path))
    return os.path.getsize(path)


def _remove(path: str) -> None:
    if os.path.isdir(path):
        import shutil
        shutil.rmtree(path)
    elif os.path.exists(path):
        os.remove(path)


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
    parser.add_argument('--formats', nargs='+', default=list(FILES), choices=list(FILES))
    parser.add_argument('--out', default=os.path.join(HERE, 'csv_memory_results.md'))
    args = parser.parse_args()
    load = os.getloadavg()
    lines = []
    with tempfile.TemporaryDirectory() as directory:
        _, _, base = measure(os.path.join(directory, 'none'), 'baseline')
        for kind in args.formats:
            path = os.path.join(directory, FILES[kind])
            for rows in args.rows:
                if kind == 'mcap-float64' and rows > 1_000_000:
                    continue  # 3 messages a sample: 30 M messages take the writer an hour
                start = time.perf_counter()
                write_file(path, rows)
                written = time.perf_counter() - start
                size = _size(path)
                try:
                    count, seconds, peak = measure(path, 'read')
                except RuntimeError as error:
                    lines.append(f'| {kind} | {rows:,} | {size / 1e6:.0f} MB | refused or '
                                 f'over 2 GiB: {str(error).splitlines()[-1][:80]} | | | | |')
                    print(lines[-1], flush=True)
                    _remove(path)
                    continue
                assert count == rows, (count, rows)
                extra = (peak - base) * 1024
                lines.append(f'| {kind} | {rows:,} | {size / 1e6:.1f} MB | {seconds:.1f} s | '
                             f'{peak / 1024:.0f} MiB | {extra / 1024 ** 2:.0f} MiB | '
                             f'{extra / rows:.1f} B | {extra / (rows * 5 * 8):.2f} | '
                             f'{max(extra, 0) / size:.2f} |')
                print(lines[-1], f'(written in {written:.0f} s)', flush=True)
                _remove(path)
    text = ['# Readers: peak memory per row and per byte of input', '',
            f'Command: `python bench/bench_csv_memory.py --rows {" ".join(map(str, args.rows))}'
            f' --formats {" ".join(args.formats)}` '
            f'(load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} at the start; 2 '
            'shared cores). Each file has the columns t, voltage, current, speed, position '
            "(CSV written with '%.17g'; .mat version 5; Parquet; MCAP bags of the batched "
            'samples topic, 250 samples a message, or of the three Float64 topics, which hold '
            'no position); it is read by `dcmotor_id.formats.read_record` in a fresh '
            "process limited to 2 GiB of address space (RLIMIT_AS). Peak = the process's "
            f'maximum resident memory; the baseline (importing the readers, scipy.io, pyarrow '
            f'and rosbags, no reading) is {base / 1024:.0f} MiB. "x numbers" = the memory '
            'above the baseline over the 8 bytes x 5 columns x rows the record holds; "x file" '
            '= the memory above the baseline over the size of the input (the documented '
            'multiple of the input size S of issue 21; every reader also refuses, before '
            'allocating, what its metadata declares beyond --memory-budget, default 1 GB).', '',
            '| format | rows | file | read time | peak RSS | above baseline | per row | '
            'x numbers | x file |',
            '|---|---|---|---|---|---|---|---|---|'] + lines + [
            '', 'Before (the csv-module reader holding every row as a list of strings): 10.2 GB '
            'for the 10 M-row file (issue 9), about 1 kB a row.', '']
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write('\n'.join(text))
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
