"""
Benchmark 4: time, growth and memory of identification, against a plain fit and the old path.

Data: motor 2 of Table 1, the ``paper`` excitation (the 0.5 Hz 110 V sine for the first half,
the 1 Hz 43 V sawtooth for the second), exact simulation, 1 % white noise on current and speed,
at each ``duration@rate`` of ``--sizes``.  Every measurement is a whole process (a fresh
interpreter: import, load the record from ``.npz``, identify), timed by the operating system
(``os.wait4``: user + system CPU seconds) and by the wall clock; the child reports the time
of the call and its own peak resident memory (``VmHWM`` of ``/proc/self/status``, before the
call and at the end: ``getrusage``'s ``ru_maxrss`` of a child starts from the parent's size).

Contenders, run in turn (A B C A B C ...) so that a drift of the machine's speed hits all:

* **new**: this checkout's :func:`~dcmotor_id.identification.identify.identify`, default (effect
  discovery on) and ``discover=False``;
* **previous**: the same call from another checkout (``--previous DIR``, e.g. a
  ``git worktree add /tmp/prev 21c2dec``), run with its own ``PYTHONPATH`` after a warm-up
  run that compiles its kernels;
* **plain**: :func:`scipy.optimize.least_squares` with its defaults (``trf``, ``2-point``
  Jacobian) on the output error of a straightforward ZOH simulation written in Python
  (``Ad = expm(A dT)``, ``Gamma = A^-1 (Ad - I)``, one update per sample with the Coulomb
  term ``-Mc sgn(w[k])`` held over the sample), started from the refined method's own start
  point (its search is inside the timed process); up to ``--plain-max-samples``.

Bytecode caching is on in every child (``PYTHONDONTWRITEBYTECODE`` removed from its
environment), as an installed package has it (``pip`` and ``colcon`` compile the sources when
installing; numpy's and scipy's are compiled in the venv): one untimed process per checkout
imports what the contenders import before the first timed run.  An environment that
exported ``PYTHONDONTWRITEBYTECODE=1`` otherwise made every timed process of this package
compile its ~800 kB of sources (about 0.09 s of CPU) while scipy's came compiled.
``--no-bytecode-cache`` keeps the caller's environment as it is (the sources compiled in
every process when it sets the variable).

Also measured: the cold start (a fresh numba cache and no ahead-of-time kernels, both made by
``python -m dcmotor_id.cli.warmup``, then the first whole process against the following ones) and
the growth exponent of the call's CPU time with the number of samples.

Usage: ``.venv/bin/python bench/bench_speed.py [--sizes 60@1000,600@1000] [--repeats N]
[--previous DIR] [--plain-max-samples N] [--previous-max-samples N]``
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from common import command_line, environment, markdown_table, PHYSICAL_NAMES
import numpy as np
from scipy.linalg import expm

from dcmotor_id.core.model import PAPER_MOTORS, relative_errors_pct
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

NOISE = 0.01
MOTOR = 'paper2'
DEFAULT_SIZES = '60@1000,600@1000,3600@1000,600@10000,3600@10000'
HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

_HWM = """
def hwm():
    # Peak resident memory of this process image (not inherited from the parent across fork
    # and exec, unlike getrusage's ru_maxrss).
    with open('/proc/self/status') as status:
        for line in status:
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) * 1024
"""

_CHILD = _HWM + """
import json, sys, time
start = time.perf_counter()
import numpy as np
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.core.records import Record
data = np.load(sys.argv[1])
record = Record(data['t'], data['current'], data['voltage'], data['speed'])
del data
before = hwm()
loaded = time.perf_counter()
cpu = time.process_time()
result = identify(prepare_records([record]), discover=sys.argv[2] == 'default')
call_cpu = time.process_time() - cpu
call = time.perf_counter() - loaded
again = again_cpu = None
if len(sys.argv) > 3:
    begin = time.perf_counter()
    cpu = time.process_time()
    identify(prepare_records([record]), discover=sys.argv[2] == 'default')
    again = time.perf_counter() - begin
    again_cpu = time.process_time() - cpu
print(json.dumps({'call_s': call, 'call_cpu_s': call_cpu, 'setup_s': loaded - start,
                  'rss_before': before, 'peak_own': hwm(), 'again_s': again,
                  'again_cpu_s': again_cpu,
                  'parameters': result.parameters, 'stderr': result.stderr}))
"""


def make_data(duration_s, rate_hz, path, seed=0):
    """Simulate the record of one size and save it as ``.npz``; return the sample count."""
    params = PAPER_MOTORS[MOTOR]
    dt = 1.0 / rate_hz
    t, voltage = make_excitation('paper', duration_s, dt)
    current, speed = simulate_motor(params, voltage, dt)
    rng = np.random.default_rng(seed)
    np.savez(path, t=t, current=add_sensor_noise(current, NOISE, rng), voltage=voltage,
             speed=add_sensor_noise(speed, NOISE, rng))
    return len(t)


def run_reaped(argv, env):
    """Run one whole process reaping it with ``os.wait4`` (CPU time, peak memory)."""
    load = os.getloadavg()[0]
    begin = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        process = subprocess.Popen(argv, env=env, stdout=out, stderr=err)
        _, status, usage = os.wait4(process.pid, 0)
        process.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - begin
        out.seek(0)
        err.seek(0)
        text, error = out.read().decode(), err.read().decode()
    if process.returncode != 0:
        raise RuntimeError(f'{argv[:3]} failed: {error[-2000:]}')
    report = json.loads(text.strip().splitlines()[-1])
    # ru_maxrss of a child starts from the parent's resident size at the fork (Linux keeps the
    # high-water mark across exec): the child's own VmHWM is the figure when it reports one.
    report.update(wall_s=wall, cpu_s=usage.ru_utime + usage.ru_stime,
                  peak_bytes=report.get('peak_own', usage.ru_maxrss * 1024), load=load)
    return report


#: OPENBLAS_NUM_THREADS of every child when set (``--blas-threads``).
BLAS_THREADS = []
#: Set by ``--no-bytecode-cache``: the children keep the caller's PYTHONDONTWRITEBYTECODE.
NO_BYTECODE_CACHE = []

#: What the contenders import, imported once per checkout before the timed runs (bytecode).
_IMPORTS = ('import numpy, scipy.optimize, scipy.linalg, common; '
            'import dcmotor_id.identification.identify, dcmotor_id.core.records, '
            'dcmotor_id.identification.estimators.refined, dcmotor_id.simulation.excitation')


def environment_for(path, cache_dir=None):
    """Environment of a child that imports ``dcmotor_id`` from ``path``."""
    env = dict(os.environ)
    env['PYTHONPATH'] = path
    if not NO_BYTECODE_CACHE:
        env.pop('PYTHONDONTWRITEBYTECODE', None)
    if BLAS_THREADS:
        env['OPENBLAS_NUM_THREADS'] = str(BLAS_THREADS[0])
    if cache_dir is not None:
        env['NUMBA_CACHE_DIR'] = cache_dir
    return env


def compile_sources(path):
    """Import what the contenders import from checkout ``path`` once, untimed (bytecode)."""
    env = environment_for(path)
    env['PYTHONPATH'] = os.pathsep.join([path, HERE])
    subprocess.run([sys.executable, '-c', _IMPORTS], env=env, check=True)


def plain_simulate(theta, voltage, sample_period_s):
    """Straightforward ZOH simulation in Python; ``theta`` = six parameters, i0, w0."""
    ra, la, cphi, inertia, viscous, coulomb, i0, w0 = (float(value) for value in theta)
    a = np.array([[-ra / la, -cphi / la], [cphi / inertia, -viscous / inertia]])
    ad = expm(a * sample_period_s)
    gamma = np.linalg.solve(a, ad - np.eye(2))
    a00, a01, a10, a11 = ad.ravel().tolist()
    g00, g01, g10, g11 = gamma.ravel().tolist()
    current = np.empty(len(voltage))
    speed = np.empty(len(voltage))
    i, w = i0, w0
    for k, u in enumerate(voltage.tolist()):
        current[k] = i
        speed[k] = w
        f0 = u / la
        f1 = (-coulomb if w > 0 else coulomb if w < 0 else 0.0) / inertia
        i, w = (a00 * i + a01 * w + g00 * f0 + g01 * f1,
                a10 * i + a11 * w + g10 * f0 + g11 * f1)
    return current, speed


def plain_child(path):
    """Child process of the plain fit: start search, least_squares; print its JSON line."""
    from scipy.optimize import least_squares

    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
    begin = time.perf_counter()
    data = np.load(path)
    record = Record(data['t'], data['current'], data['voltage'], data['speed'])
    start = RefinedEstimator()._starts(OutputErrorModel([record]))[0]
    spread_i, spread_w = np.std(record.current), np.std(record.speed)
    dt = record.sample_period_s

    def residual(theta):
        current, speed = plain_simulate(theta, record.voltage, dt)
        return np.concatenate([(current - record.current) / spread_i,
                               (speed - record.speed) / spread_w])

    x0 = np.array([start[name] for name in PHYSICAL_NAMES]
                  + [record.current[0], record.speed[0]])
    with np.errstate(all='ignore'):
        result = least_squares(residual, x0)
    namespace: dict = {}
    exec(_HWM, namespace)
    print(json.dumps({'call_s': time.perf_counter() - begin, 'nfev': int(result.nfev),
                      'peak_own': namespace['hwm'](),
                      'status': int(result.status),
                      'parameters': dict(zip(PHYSICAL_NAMES, result.x[:6].tolist()))}))


def max_error_pct(parameters):
    """Largest relative error of the six physical parameters [%] and its name."""
    errors = relative_errors_pct({name: parameters[name] for name in PHYSICAL_NAMES},
                                 PAPER_MOTORS[MOTOR].as_dict(), list(PHYSICAL_NAMES))
    name = max(errors, key=errors.get)
    return errors[name], name


def _median(values):
    return float(np.median(values)) if values else float('nan')


def measure_size(duration_s, rate_hz, directory, args):
    """Interleaved runs of every contender on one size; return a dict of lists of reports."""
    path = os.path.join(directory, f'record_{duration_s:g}s_{rate_hz:g}Hz.npz')
    n = make_data(duration_s, rate_hz, path)
    here = environment_for(ROOT)
    contenders = [('new, no discovery', [sys.executable, '-c', _CHILD, path, 'no'], here)]
    if n <= args.default_max_samples:
        contenders.insert(0, ('new, default', [sys.executable, '-c', _CHILD, path, 'default'],
                              here))
    if args.previous and n <= args.previous_max_samples:
        old = environment_for(args.previous)
        contenders.append(('previous, default',
                           [sys.executable, '-c', _CHILD, path, 'default'], old))
        if n <= args.previous_both_max_samples:
            contenders.append(('previous, no discovery',
                               [sys.executable, '-c', _CHILD, path, 'no'], old))
    if n <= args.plain_max_samples:
        contenders.append(('plain scipy least_squares',
                           [sys.executable, os.path.abspath(__file__), '--plain-child', path],
                           here))
    repeats = args.repeats if n <= 100_000 else 1
    runs = {name: [] for name, _, _ in contenders}
    for _ in range(repeats):
        for name, argv, env in contenders:
            runs[name].append(run_reaped(argv, env))
            print(f'# {duration_s:g} s @ {rate_hz:g} Hz {name}: cpu '
                  f'{runs[name][-1]["cpu_s"]:.2f} s, wall {runs[name][-1]["wall_s"]:.2f} s, '
                  f'peak {runs[name][-1]["peak_bytes"] / 2 ** 20:.0f} MiB', file=sys.stderr,
                  flush=True)
    os.remove(path)
    return n, runs


def size_rows(duration_s, rate_hz, n, runs):
    """Rows of the results table for one size (medians; ratios pair by pair)."""
    rows = []
    peer = runs.get('plain scipy least_squares')
    previous = runs.get('previous, default')
    for name, reports in runs.items():
        cpu = _median([r['cpu_s'] for r in reports])
        wall = _median([r['wall_s'] for r in reports])
        peak = _median([r['peak_bytes'] for r in reports])
        error, which = max_error_pct(reports[-1]['parameters'])
        notes = []
        if 'rss_before' in reports[-1]:
            extra = (peak - reports[-1]['rss_before']) / n
            notes.append(f'{extra:.0f} B/sample beyond the loaded record')
        if name == 'new, default' and peer:
            notes.append('cpu / plain {:.2f}'.format(_median(
                [a['cpu_s'] / b['cpu_s'] for a, b in zip(reports, peer)])))
        if name == 'new, default' and previous:
            notes.append('cpu / previous {:.2f}'.format(_median(
                [a['cpu_s'] / b['cpu_s'] for a, b in zip(reports, previous)])))
        if name == 'plain scipy least_squares':
            notes.append(f'{reports[-1]["nfev"]} evaluations, status {reports[-1]["status"]}')
        loads = ', '.join(f'{r["load"]:.1f}' for r in reports)
        rows.append([f'{duration_s:g} s @ {rate_hz / 1000:g} kHz ({n:,})', name,
                     f'{len(reports)}', f'{cpu:.2f}', f'{wall:.2f}',
                     f'{peak / 2 ** 20:.0f}', f'{error:.3f} ({which})', loads,
                     '; '.join(notes)])
    return rows


def cold_start(directory):
    """
    Warm-up from nothing, then the first whole process against later ones.

    An empty numba cache, and this checkout's ahead-of-time kernels removed first
    (:mod:`dcmotor_id.simulation.compiled`): the warm-up compiles both again.
    """
    import glob

    path = os.path.join(directory, 'cold.npz')
    make_data(60.0, 1000.0, path)
    for module in glob.glob(os.path.join(ROOT, 'dcmotor_id', 'simulation', '_aot_*')):
        os.remove(module)
    with tempfile.TemporaryDirectory() as cache:
        env = environment_for(ROOT, cache)
        with tempfile.TemporaryFile() as sink:
            process = subprocess.Popen([sys.executable, '-m', 'dcmotor_id.cli.warmup', '--quiet'],
                                       env=env, stdout=sink)
            _, _, usage = os.wait4(process.pid, 0)
        warm_up_cpu = usage.ru_utime + usage.ru_stime
        runs = [run_reaped([sys.executable, '-c', _CHILD, path, 'default', 'again'], env)
                for _ in range(4)]
    first, later = runs[0], runs[1:]
    return [
        ['warm-up (python -m dcmotor_id.cli.warmup, empty cache, no ahead-of-time module)',
         f'{warm_up_cpu:.2f}', '', ''],
        ['first whole process after the warm-up', f'{first["cpu_s"]:.2f}',
         f'{first["call_cpu_s"]:.2f}', f'{first["again_cpu_s"]:.2f}'],
        ['later whole processes (median of 3)', f'{_median([r["cpu_s"] for r in later]):.2f}',
         f'{_median([r["call_cpu_s"] for r in later]):.2f}',
         f'{_median([r["again_cpu_s"] for r in later]):.2f}'],
    ], (first['cpu_s'] / _median([r['cpu_s'] for r in later]),
        first['call_cpu_s'] / _median([r['again_cpu_s'] for r in runs]))


def main():
    """Parse the options, run the measurements and print the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--sizes', default=DEFAULT_SIZES,
                        help='comma-separated duration_s@rate_Hz (default: %(default)s)')
    parser.add_argument('--repeats', type=int, default=3,
                        help='interleaved rounds for records up to 100k samples')
    parser.add_argument('--previous', help='checkout of the previous version (PYTHONPATH)')
    parser.add_argument('--previous-max-samples', type=int, default=6_000_000)
    parser.add_argument('--previous-both-max-samples', type=int, default=600_000,
                        help='largest record the previous path also runs without discovery')
    parser.add_argument('--plain-max-samples', type=int, default=600_000)
    parser.add_argument('--default-max-samples', type=int, default=10 ** 9,
                        help='largest record the new path runs with discovery (default: all)')
    parser.add_argument('--skip-cold', action='store_true')
    parser.add_argument('--blas-threads', type=int,
                        help='OPENBLAS_NUM_THREADS of every child (default: not set; the new '
                        'path limits itself to one thread during identify)')
    parser.add_argument('--no-bytecode-cache', action='store_true',
                        help="keep the caller's PYTHONDONTWRITEBYTECODE in the children (default: "
                        'bytecode caching on, as in an installed package)')
    parser.add_argument('--plain-child', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.plain_child:
        plain_child(args.plain_child)
        return
    if args.blas_threads:
        BLAS_THREADS.append(args.blas_threads)
    if args.no_bytecode_cache:
        NO_BYTECODE_CACHE.append(True)
    cached = not args.no_bytecode_cache or not os.environ.get('PYTHONDONTWRITEBYTECODE')
    lines = [f'Command: `{command_line()}`  ', f'Machine: {environment()}; load average '
             f'{os.getloadavg()[0]:.2f} at the start; bytecode caching '
             f'{"on" if cached else "off (every process compiles the package)"}', '']
    if cached:
        for checkout in [ROOT] + ([args.previous] if args.previous else []):
            compile_sources(checkout)
    if args.previous and args.sizes:
        # Compile the previous checkout's kernels first (its own cache, not timed).
        subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.warmup', '--quiet'],
                       env=environment_for(args.previous), check=True)
    rows, growth = [], []
    with tempfile.TemporaryDirectory() as directory:
        for item in filter(None, args.sizes.split(',')):
            duration, rate = (float(value) for value in item.split('@'))
            n, runs = measure_size(duration, rate, directory, args)
            rows += size_rows(duration, rate, n, runs)
            growth.append((n, _median([r['call_cpu_s'] for r in runs['new, no discovery']]),
                           _median([r['call_cpu_s'] for r in runs.get('new, default', [])])))
            print('\n'.join(lines + [markdown_table(_HEADER, rows)]), file=sys.stderr,
                  flush=True)
        cold_rows, cold_ratio = (None, None) if args.skip_cold else cold_start(directory)
    lines.append(f'Motor 2, `paper` excitation, {NOISE * 100:g} % noise; whole processes '
                 '(import, load the record, identify); cpu = user + system seconds of the '
                 'process (os.wait4), median over the interleaved rounds; load = the 1-minute '
                 'load average when each run started (the machine has 2 cores).')
    lines.append('')
    lines.append(markdown_table(_HEADER, rows))
    if len(growth) > 1:
        sizes = np.log([g[0] for g in growth])
        lines.append('')
        for column, label in ((1, 'no discovery'), (2, 'default')):
            known = [(size, g[column]) for size, g in zip(sizes, growth) if np.isfinite(g[column])]
            if len(known) < 2:
                continue
            slope = np.polyfit([k[0] for k in known], np.log([k[1] for k in known]), 1)[0]
            lines.append(f'Growth of the CPU time of the identify call ({label}), least-squares '
                         f'slope of log time on log N over {len(known)} sizes up to '
                         f'{np.exp(known[-1][0]):,.0f} samples: N^{slope:.2f}.')
    if cold_rows:
        lines += ['', 'Cold start (60 s @ 1 kHz, default):', '',
                  markdown_table(['what', 'process cpu [s]', 'first identify call, cpu [s]',
                                  'second call in the same process, cpu [s]'], cold_rows), '',
                  f'First whole process after the warm-up / later ones: {cold_ratio[0]:.2f} '
                  f'(CPU); first identify call of a process / a second call in it: '
                  f'{cold_ratio[1]:.2f} (CPU: loading kernels, if any).']
    print('\n'.join(lines))


_HEADER = ['record', 'path', 'runs', 'cpu [s]', 'wall [s]', 'peak [MiB]',
           'max error [%]', 'load', 'notes']


if __name__ == '__main__':
    main()
