"""
Benchmark 4: time to identify a 60 s record at 1 kHz with the default method.

Data: motor 2 of Table 1, the ``paper`` excitation (30 s of the 0.5 Hz 110 V sine, then 30 s of
the 1 Hz 43 V sawtooth) at 1 kHz, exact simulation, 1 % white noise on current and speed.

Timed, in this order:

* **cold, empty numba cache**: a fresh interpreter with ``NUMBA_CACHE_DIR`` pointing to an empty
  directory (the kernels are compiled), import and one :func:`~dcmotor_id.identify.identify`;
* **cold, warm cache**: a fresh interpreter with the package's on-disk numba cache (the usual
  first call of a user): import and one call;
* **warm**: :func:`~dcmotor_id.identify.identify` with ``discover=False`` in this process, the
  median of several calls (the path ``dcmotor-id identify --no-discover`` takes after reading
  the CSV: checks, fit with standard errors, simulation errors); the effect discovery of the
  default CLI call (another feature, on top of the method) is timed separately;
* **plain**: :func:`scipy.optimize.least_squares` with its defaults (``trf``, ``2-point``
  Jacobian, ``x_scale=1``) on the output error of a straightforward ZOH simulation written in
  Python: ``Ad = expm(A dT)`` and ``Gamma = A^-1 (Ad - I)`` once per evaluation, then one
  matrix-vector update per sample with the Coulomb term ``-Mc sgn(w[k])`` held over the sample
  (no location of speed reversals inside a sample).  Residuals are the current and speed errors
  divided by each signal's standard deviation; the unknowns are the six parameters and the
  initial state, started from the refined method's own start point.  It runs once, in the
  same process, after the warm timing.

Usage: ``.venv/bin/python bench/bench_speed.py [--repeats N] [--skip-plain]``
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time

from common import command_line, environment, markdown_table, pct, PHYSICAL_NAMES
import numpy as np
from scipy.linalg import expm
from scipy.optimize import least_squares

from dcmotor_id.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.excitation import add_sensor_noise, make_excitation
from dcmotor_id.identify import identify, prepare_records
from dcmotor_id.model import PAPER_MOTORS, relative_errors_pct
from dcmotor_id.records import Record
from dcmotor_id.simulation import simulate_motor

DURATION_S = 60.0
SAMPLE_PERIOD_S = 1e-3
NOISE = 0.01
MOTOR = 'paper2'
TARGET_S = 1.0

_CHILD = """
import sys
import time
start = time.perf_counter()
import numpy as np
from dcmotor_id.identify import identify, prepare_records
from dcmotor_id.records import Record
imported = time.perf_counter()
data = np.load(sys.argv[1])
record = Record(data['t'], data['current'], data['voltage'], data['speed'])
loaded = time.perf_counter()
identify(prepare_records([record]), discover=False)
print(imported - start, time.perf_counter() - loaded)
"""


def make_data(seed=0):
    """Simulate the 60 s record at 1 kHz of motor 2 with 1 % noise, prepared as the CLI would."""
    params = PAPER_MOTORS[MOTOR]
    t, voltage = make_excitation('paper', DURATION_S, SAMPLE_PERIOD_S)
    current, speed = simulate_motor(params, voltage, SAMPLE_PERIOD_S)
    rng = np.random.default_rng(seed)
    record = Record(t, add_sensor_noise(current, NOISE, rng), voltage,
                    add_sensor_noise(speed, NOISE, rng), source='speed-benchmark')
    return prepare_records([record])


def cold_call(records, cache_dir=None):
    """Import and one identify() in a fresh interpreter; return (import_s, first_call_s)."""
    env = dict(os.environ)
    if cache_dir is not None:
        env['NUMBA_CACHE_DIR'] = cache_dir
    record = records[0]
    with tempfile.TemporaryDirectory() as directory:
        path = os.path.join(directory, 'record.npz')
        np.savez(path, t=record.time_s, current=record.current, voltage=record.voltage,
                 speed=record.speed)
        output = subprocess.run([sys.executable, '-c', _CHILD, path], env=env, check=True,
                                capture_output=True, text=True).stdout
    import_s, call_s = (float(value) for value in output.split())
    return import_s, call_s


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


def plain_fit(record, start):
    """Scipy least_squares with defaults on the plain output error; return (result, time)."""
    spread_i, spread_w = np.std(record.current), np.std(record.speed)
    dt = record.sample_period_s

    def residual(theta):
        current, speed = plain_simulate(theta, record.voltage, dt)
        return np.concatenate([(current - record.current) / spread_i,
                               (speed - record.speed) / spread_w])

    x0 = np.array([start[name] for name in PHYSICAL_NAMES]
                  + [record.current[0], record.speed[0]])
    begin = time.perf_counter()
    with np.errstate(all='ignore'):
        result = least_squares(residual, x0)
    return result, time.perf_counter() - begin


def _median_time(function, repeats):
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        function()
        times.append(time.perf_counter() - begin)
    return float(np.median(times))


def run(repeats, skip_plain):
    """Time the default method (cold and warm) and the plain fit; return the report."""
    lines = [f'Command: `{command_line()}`  ', f'Machine: {environment()}; load average '
             f'{os.getloadavg()[0]:.2f} at the start', '']
    params = PAPER_MOTORS[MOTOR]
    records = make_data()
    with tempfile.TemporaryDirectory() as empty_cache:
        compile_import, compile_call = cold_call(records, empty_cache)
    cold_import, cold_call_s = cold_call(records)
    identify(records, discover=False)
    warm = []
    for _ in range(repeats):
        begin = time.perf_counter()
        result = identify(records, discover=False).as_dict()
        warm.append(time.perf_counter() - begin)
    warm_s = float(np.median(warm))
    with_discovery = []
    for _ in range(3):
        begin = time.perf_counter()
        identify(records)
        with_discovery.append(time.perf_counter() - begin)
    refined_err = relative_errors_pct(result['parameters'], params.as_dict(),
                                      list(PHYSICAL_NAMES))
    rows = [
        ['default (refined), cold: empty numba cache', f'{compile_call:.2f}',
         f'import {compile_import:.2f} s; the call includes compiling the kernels'],
        ['default (refined), cold: warm numba cache (first call)', f'{cold_call_s:.2f}',
         f'import {cold_import:.2f} s; the call includes loading the cached kernels'],
        [f'default (refined), warm: median of {repeats}', f'{warm_s:.2f}',
         f'min {min(warm):.2f} s, max {max(warm):.2f} s; largest error '
         f'{pct(max(refined_err.values()))} %'],
        ['identify with effect discovery (the CLI without --no-discover), warm',
         f'{np.median(with_discovery):.2f}', 'median of 3; not part of the target'],
    ]
    verdict = f'warm {warm_s:.2f} s against the target of {TARGET_S:g} s: ' + (
        'met' if warm_s <= TARGET_S else 'NOT met')
    model = OutputErrorModel(records)
    truth = params.as_dict(derived=False)
    kernel_s = _median_time(lambda: model.simulate(truth, 0, np.zeros(2)), 21)
    plain_sim_s = _median_time(lambda: plain_simulate(
        list(truth.values()) + [0.0, 0.0], records[0].voltage, SAMPLE_PERIOD_S), 5)
    rows.append(['one simulation of the record: exact hybrid kernel / plain Python loop',
                 f'{kernel_s:.4f} / {plain_sim_s:.3f}', 'median; what one residual costs'])
    if not skip_plain:
        start = RefinedEstimator()._start(model)
        plain, plain_s = plain_fit(records[0], start)
        plain_values = dict(zip(PHYSICAL_NAMES, plain.x[:6]))
        plain_err = relative_errors_pct(plain_values, params.as_dict(), list(PHYSICAL_NAMES))
        rows.append(['plain scipy least_squares (trf, 2-point, Python ZOH)', f'{plain_s:.1f}',
                     f'{plain.nfev} evaluations + {plain.njev} Jacobians, status '
                     f'{plain.status}; largest error {pct(max(plain_err.values()))} % '
                     f'({max(plain_err, key=plain_err.get)})'])
        verdict += f'; plain / default = {plain_s / warm_s:.0f}x'
    lines.append(f'{DURATION_S:g} s at {1 / SAMPLE_PERIOD_S:g} Hz ({len(records[0])} samples), '
                 f'motor 2, `paper` excitation, {NOISE * 100:g} % noise.')
    lines.append('')
    lines.append(markdown_table(['what', 'time [s]', 'notes'], rows))
    lines.append('')
    lines.append(verdict + '.')
    return '\n'.join(lines)


def main():
    """Parse the options and print the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=11, help='warm calls timed')
    parser.add_argument('--skip-plain', action='store_true', help='skip the plain fit')
    args = parser.parse_args()
    print(run(args.repeats, args.skip_plain))


if __name__ == '__main__':
    main()
