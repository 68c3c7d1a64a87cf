"""
Online estimation under sensor noise, tracking of changes, change alarms and cost.

The identifier node's online estimators on simulated drives (exact simulation at 1 kHz): ``window``
(:class:`dcmotor_id.streaming.online.WindowEstimator`, the default: exact output-error refits of a
window growing from the start up to 30 s, warm-started) and the old ``rls``
(:class:`dcmotor_id.streaming.online.RlsEstimator`, recursive least squares with a 10 s memory),
side by side on the same runs.

1. Accuracy: the paper's motors 1 and 2, excitations ``paper``, ``prbs`` and ``multisine``
   (30 s), white noise of 0, 0.1, 1 and 3 % of each signal's standard deviation on current
   and speed, ``--draws`` noise draws (one without noise): error after 10 s and 30 s, the
   empirical spread against the reported standard error, the RMS of error over reported
   standard error, how often ``converged`` is true while a parameter is off by more than its
   published (simultaneous) interval or by more than 3 standard errors, and at 1 % noise the
   spread and largest error against the offline output-error fit of the whole 30 s.
2. Tracking (``paper`` excitation, 1 % noise): Ra rising 25 % over 60 s, b stepping +50 %, a
   load torque of half the Coulomb friction appearing; tracking lag and alarm delay.
3. False alarms: a stationary motor at 1 % noise for ``--stationary-s`` per draw.
4. CPU per sample at 1 kHz and 10 kHz.

Usage: ``.venv/bin/python bench/bench_online.py [--draws 20] [--quick]``
"""

import argparse
import math
import os
import time

from common import command_line, environment, markdown_table, PHYSICAL_NAMES
import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation
from dcmotor_id.streaming.monitoring import ChangeDetector
from dcmotor_id.streaming.online import (INTERVAL_SIGMAS, LOAD_TORQUE, parse_schedule,
                                         RlsEstimator, simulate_scheduled, WindowEstimator)

DT = 1e-3
DURATION_S = 30.0
CHECKPOINTS_S = (10.0, 30.0)
MOTORS = ('paper1', 'paper2')
EXCITATIONS = ('paper', 'prbs', 'multisine')
NOISES = (0.0, 0.001, 0.01, 0.03)
BLOCK = 100  # samples a call, as the node's 50 Hz processing timer gives at 5 kHz
GRID_INTERVAL_S = 5.0  # refit interval of the accuracy grid (the node's default is 2 s)
WINDOW = {}  # options of every WindowEstimator (--window-s)


def window_length():
    """Return the window estimator's longest window in this run [s]."""
    return WINDOW.get('window_s', WindowEstimator(DT).window_s)


def noisy(current, speed, level, seed):
    """Add white noise of ``level`` times each signal's standard deviation."""
    rng = np.random.default_rng(seed)
    return add_sensor_noise(current, level, rng), add_sensor_noise(speed, level, rng)


def feed(estimators, voltage, current, speed, on_block=None):
    """Feed the arrays in blocks of BLOCK samples; call ``on_block(end_index)`` after each."""
    for start in range(0, voltage.size, BLOCK):
        part = slice(start, start + BLOCK)
        for estimator in estimators:
            estimator.update(voltage[part], current[part], speed[part])
        if on_block is not None:
            on_block(min(start + BLOCK, voltage.size))


def accuracy_runs(draws, motors, excitations, noises=NOISES):
    """Return ``{(motor, excitation, noise): {method: {checkpoint: [estimates]}}, offline}``."""
    results, offline = {}, {}
    for motor in motors:
        params = PAPER_MOTORS[motor]
        for kind in excitations:
            _, voltage = make_excitation(kind, DURATION_S, DT)
            current, speed = simulate_motor(params, voltage, DT)
            for level in noises:
                runs = {'window': {t: [] for t in CHECKPOINTS_S},
                        'rls': {t: [] for t in CHECKPOINTS_S}}
                for draw in range(draws if level > 0 else 1):
                    seed = draw + 1000 * NOISES.index(level)  # independent draws per level
                    meas_i, meas_w = noisy(current, speed, level, seed)
                    window = WindowEstimator(DT, refit_interval_s=GRID_INTERVAL_S,
                                             **WINDOW,
                                             cpu_budget=1.0)
                    rls = RlsEstimator(DT)

                    def snapshot(end, window=window, rls=rls, runs=runs):
                        for checkpoint in CHECKPOINTS_S:
                            if end == int(round(checkpoint / DT)):
                                runs['window'][checkpoint].append(window.estimate())
                                runs['rls'][checkpoint].append(rls.estimate())
                    feed((window, rls), voltage, meas_i, meas_w, snapshot)
                    if level == 0.01:
                        record = Record(np.arange(voltage.size) * DT, meas_i, voltage, meas_w)
                        fit = RefinedEstimator().fit([record])
                        offline.setdefault((motor, kind), []).append(fit.parameters)
                results[(motor, kind, level)] = runs
    return results, offline


def summarise(estimates, truth):
    """Return per-parameter max |error| %, spread %, mean stderr %, converged, violations."""
    values = np.array([[e.parameters[n] for n in PHYSICAL_NAMES] for e in estimates])
    errors = np.array([[e.stderr[n] for n in PHYSICAL_NAMES] for e in estimates])
    true = np.array([truth[n] for n in PHYSICAL_NAMES])
    rel = 100 * (values - true) / true
    converged = np.array([e.converged for e in estimates])
    with np.errstate(invalid='ignore', divide='ignore'):
        beyond = np.abs(values - true) / errors
        outside = np.any(~(beyond <= INTERVAL_SIGMAS), axis=1)
        outside3 = np.any(~(beyond <= 3.0), axis=1)
        z_rms = np.sqrt(np.nanmean(beyond ** 2, axis=0))
    return {'max': np.nanmax(np.abs(rel), axis=0),
            'z_rms': z_rms,
            'violations3': int((converged & outside3).sum()),
            'bias': np.nanmean(rel, axis=0),
            'spread': 100 * np.std(values, axis=0) / true if len(values) > 1 else
            np.full(len(true), np.nan),
            'stderr': 100 * np.nanmean(errors, axis=0) / true,
            'converged': int(converged.sum()), 'n': len(estimates),
            'violations': int((converged & outside).sum())}


def fmt(value, digits=3):
    """Format a number compactly (nan as '-')."""
    if value is None or not np.isfinite(value):
        return '-'
    return f'{value:.{digits}g}'


def accuracy_tables(results, offline):
    """Print the accuracy tables."""
    totals = {}
    for checkpoint in CHECKPOINTS_S:
        for method in ('window', 'rls'):
            rows = []
            for (motor, kind, level), runs in results.items():
                s = summarise(runs[method][checkpoint], PAPER_MOTORS[motor].as_dict())
                with np.errstate(invalid='ignore', divide='ignore'):
                    ratio = s['stderr'] / s['spread']
                rows.append([motor, kind, f'{100 * level:g}'] +
                            [fmt(v) for v in s['max']] +
                            [f'{fmt(np.nanmin(ratio), 2)}-{fmt(np.nanmax(ratio), 2)}'
                             if level > 0 else '-',
                             f"{fmt(np.nanmin(s['z_rms']), 2)}-{fmt(np.nanmax(s['z_rms']), 2)}"
                             if level > 0 else '-',
                             f"{s['converged']}/{s['n']}", str(s['violations']),
                             str(s['violations3'])])
                total = totals.setdefault(method, [0, 0, 0, 0])
                total[0] += s['n']
                total[1] += s['converged']
                total[2] += s['violations']
                total[3] += s['violations3']
            print(f'\n### {method}: largest |error| [%] after {checkpoint:g} s\n')
            print('`stderr/spread`: mean reported standard error over the empirical spread '
                  '(range over the six parameters); `z rms`: RMS over the runs of |error| / '
                  'reported standard error (range over the six; 1 when honest); `conv.`: runs '
                  'with converged = true; `conv. & off`: of those, runs with a parameter off by '
                  f'more than its published interval ({INTERVAL_SIGMAS:.2f} standard errors, '
                  'simultaneous for the six); `> 3 se`: by more than 3 standard errors.\n')
            print(markdown_table(['motor', 'excitation', 'noise %'] + list(PHYSICAL_NAMES) +
                                 ['stderr/spread', 'z rms', 'conv.', 'conv. & off', '> 3 se'],
                                 rows))
    print('\nAll checks (both checkpoints): ' + '; '.join(
        f'{method}: {n} estimates, {c} converged, {v} converged while a parameter was off by '
        f'more than its published interval ({v3} by more than 3 standard errors)'
        for method, (n, c, v, v3) in totals.items()) +
        ' (for Gaussian errors with honest standard errors, at most 1.6 % of the estimates '
        'have one of six parameters beyond 3 sigma, at most 0.27 % one beyond the '
        'simultaneous interval).')
    rows, worst = [], []
    for (motor, kind), fits in offline.items():
        truth = PAPER_MOTORS[motor].as_dict()
        true = np.array([truth[n] for n in PHYSICAL_NAMES])
        values_off = np.array([[f[n] for n in PHYSICAL_NAMES] for f in fits])
        spread_off = 100 * np.std(values_off, axis=0) / true
        max_off = 100 * np.max(np.abs(values_off - true), axis=0) / true
        s = summarise(results[(motor, kind, 0.01)]['window'][30.0], truth)
        rows.append([motor, kind] + [f'{fmt(a, 2)} / {fmt(b, 2)}'
                                     for a, b in zip(s['spread'], spread_off)] +
                    [fmt(np.nanmax(s['spread'] / spread_off), 2)])
        worst.append([motor, kind] + [f'{fmt(a, 2)} / {fmt(b, 2)}'
                                      for a, b in zip(s['max'], max_off)])
    print('\n### Spread at 1 % noise after 30 s: window / offline output error '
          '(all 30 s) [% of the value]\n')
    print(f'The window grows from the start up to {window_length():g} s, so after 30 s it '
          f'holds the last {min(window_length(), 30.0):g} s of the data of the offline fit '
          f'(expected ratio sqrt(30 / {min(window_length(), 30.0):g}) = '
          f'{math.sqrt(30.0 / min(window_length(), 30.0)):.2f}).\n')
    print(markdown_table(['motor', 'excitation'] + list(PHYSICAL_NAMES) + ['worst ratio'],
                         rows))
    print('\n### Largest |error| at 1 % noise after 30 s: window / offline output error '
          '[% of the value]\n')
    print('Goal of the issue: 2 % (Ra, CPhi, J, b), 5 % (La, Mc).\n')
    print(markdown_table(['motor', 'excitation'] + list(PHYSICAL_NAMES), worst))


def tracking(motor, kind, seed, schedule_text, duration_s, interval_s=2.0):
    """Run both estimators and the detector over a scheduled change; return trajectories."""
    params = PAPER_MOTORS[motor]
    schedule = parse_schedule(schedule_text)
    _, voltage = make_excitation(kind, duration_s, DT)
    current, speed = simulate_scheduled(params, schedule, voltage, DT)
    meas_i, meas_w = noisy(current, speed, 0.01, seed)
    window = WindowEstimator(DT, refit_interval_s=interval_s, cpu_budget=1.0, **WINDOW)
    rls = RlsEstimator(DT)
    detectors = {'window': ChangeDetector(min_baseline_window_s=window.window_s),
                 'rls': ChangeDetector(min_baseline_window_s=rls.memory_s)}
    trajectory = {'window': [], 'rls': []}
    alarms = {'window': [], 'rls': []}
    every = int(round(interval_s / DT))

    def on_block(end):
        if end % every:
            return
        for name, estimator in (('window', window), ('rls', rls)):
            estimate = estimator.estimate()
            trajectory[name].append(estimate)
            alarms[name].append((estimate.time_s, list(detectors[name].update(estimate))))
    feed((window, rls), voltage, meas_i, meas_w, on_block)
    return schedule, trajectory, alarms


def lag_figures(motor, schedule, trajectory, alarms, name, kind, start_s, end_s):
    """Return (tracking lag [s], alarm delay [s], first alarm text) of one change."""
    params = PAPER_MOTORS[motor]
    key = LOAD_TORQUE if name == 'load_torque' else name

    def value(estimate):
        if key == LOAD_TORQUE:
            return (estimate.effects or {}).get(LOAD_TORQUE, math.nan)
        return estimate.parameters[key]

    def truth(time_s):
        motor_now, load = schedule.at(params, time_s)
        return load if key == LOAD_TORQUE else getattr(motor_now, key)
    times = np.array([e.time_s for e in trajectory])
    values = np.array([value(e) for e in trajectory])
    before, after = truth(start_s - 1e-9), truth(end_s + 1e-9)
    if kind == 'ramp':
        slope = (after - before) / (end_s - start_s)
        mid = (times >= 0.5 * (start_s + end_s)) & (times <= end_s)
        lags = [(truth(t) - v) / slope for t, v in zip(times[mid], values[mid])]
        lag = float(np.nanmean(lags)) if lags else math.nan
    else:
        with np.errstate(invalid='ignore'):
            crossed = np.nonzero((times >= start_s) & (np.abs(values - before) >=
                                                       0.9 * abs(after - before)))[0]
        lag = float(times[crossed[0]] - start_s) if crossed.size else math.nan
    delay, text = math.nan, ''
    for time_s, active in alarms:
        hit = [alarm for alarm in active if alarm.name == key]
        if time_s >= start_s and hit:
            delay, text = time_s - start_s, hit[0].level + ' ' + hit[0].text()
            break
    return lag, delay, text


# The changes start 10 s after the first full 30 s window (the baseline learned online).
CHANGES = (
    ('Ra', 'ramp', 'Ra:+25%:ramp:40:100', 130.0, 40.0, 100.0),
    ('b', 'step', 'b:+50%:step:40', 100.0, 40.0, 40.0),
    ('load_torque', 'step', None, 100.0, 40.0, 40.0),
)


def converged_checks(motor, schedule, trajectory, start_s):
    """Return (converged, converged with a true value outside the interval) from start_s on."""
    params = PAPER_MOTORS[motor]
    converged = off = 0
    for estimate in trajectory:
        if estimate.time_s < start_s or not estimate.converged:
            continue
        converged += 1
        # the motor at the last sample the estimate saw
        truth = schedule.at(params, estimate.time_s - DT)[0].as_dict()
        interval = estimate.interval
        off += any(not abs(estimate.parameters[n] - truth[n]) <= interval[n]
                   for n in PHYSICAL_NAMES)
    return converged, off


def tracking_table(draws, motors):
    """Print tracking lag and alarm delay per change, both estimators."""
    rows, examples = [], []
    for motor in motors:
        for name, kind, text, duration_s, start_s, end_s in CHANGES:
            if text is None:
                text = f'load_torque:+{0.5 * PAPER_MOTORS[motor].Mc:g}:step:{start_s:g}'
            figures = {'window': [], 'rls': []}
            checks = {'window': [0, 0, 0], 'rls': [0, 0, 0]}
            for seed in range(draws):
                schedule, trajectory, alarms = tracking(motor, 'paper', seed, text, duration_s)
                for method in figures:
                    after = converged_checks(motor, schedule, trajectory[method], start_s)
                    checks[method][0] += sum(e.time_s >= start_s for e in trajectory[method])
                    checks[method][1] += after[0]
                    checks[method][2] += after[1]
                    if method == 'rls' and name == 'load_torque':
                        figures[method].append((math.nan, math.nan, ''))
                        continue
                    figures[method].append(lag_figures(motor, schedule, trajectory[method],
                                                       alarms[method], name, kind, start_s,
                                                       end_s))
            row = [motor, f'`{text}`']
            for method in ('window', 'rls'):
                lags = [f[0] for f in figures[method]]
                delays = [f[1] for f in figures[method]]
                row += [fmt(np.nanmean(lags)) if np.any(np.isfinite(lags)) else '-',
                        fmt(np.nanmean(delays)) if np.any(np.isfinite(delays)) else 'none']
            for method in ('window', 'rls'):
                total, converged, off = checks[method]
                row += [f'{converged}/{total}', str(off)]
            rows.append(row)
            examples += [f'- {motor}, `{text}`: {f[2]}' for f in figures['window'][:1] if f[2]]
    print('\n## Tracking (paper excitation, 1 % noise, refit every 2 s, '
          f'window up to {window_length():g} s, {draws} draws, means)\n')
    print('Lag: a ramp, mean of (truth - estimate) / slope over its second half; a step, '
          'data time until the estimate has made 90 % of it. Alarm: data time from the start '
          'of the change to the first alarm on that parameter (baseline learned online, '
          'warn 5 %, 5 sigma; "none": no alarm on it). The RLS has no load-torque '
          'estimate. `conv.`: estimates (one every 2 s) from the start of the change on '
          'with converged = true, of all; `off`: of those, with a parameter outside its '
          'published interval around the value at that time.\n')
    print(markdown_table(['motor', 'change', 'window lag s', 'window alarm s', 'rls lag s',
                          'rls alarm s', 'window conv.', 'window off', 'rls conv.',
                          'rls off'], rows))
    print('\nFirst alarm texts (window, first draw):\n')
    print('\n'.join(examples))


def false_alarm_table(draws, stationary_s, motors):
    """Print false alarms per hour on a stationary motor at 1 % noise."""
    rows = []
    for motor in motors:
        counts = {'window': 0, 'rls': 0}
        for seed in range(draws):
            _, _, alarms = tracking(motor, 'paper', 100 + seed, '', stationary_s)
            for method in counts:
                active = set()
                for _, current in alarms[method]:
                    names = {alarm.name for alarm in current}
                    counts[method] += len(names - active)
                    active = names
        hours = draws * stationary_s / 3600.0
        rows.append([motor, f'{draws} x {stationary_s / 60:g} min'] +
                    [f'{counts[m]} ({counts[m] / hours:.3g}/h)' for m in ('window', 'rls')])
    print('\n## False alarms on a stationary motor (paper excitation, 1 % noise)\n')
    print(markdown_table(['motor', 'data', 'window: alarms', 'rls: alarms'], rows))


def cpu_table():
    """Print the CPU per sample at 1 and 10 kHz (refits in-process, node settings)."""
    rows = []
    params = PAPER_MOTORS['paper2']
    for rate, duration_s in ((1000.0, 60.0), (10000.0, 60.0)):
        dt = 1.0 / rate
        _, voltage = make_excitation('paper', duration_s, dt)
        current, speed = simulate_motor(params, voltage, dt)
        meas_i, meas_w = noisy(current, speed, 0.01, 0)
        block = int(rate / 50)  # the node's 50 Hz processing timer
        for name, estimator in (('window', WindowEstimator(dt, cpu_budget=0.08, **WINDOW)),
                                ('rls', RlsEstimator(dt))):
            started = time.process_time()
            for first in range(0, voltage.size, block):
                part = slice(first, first + block)
                estimator.update(voltage[part], meas_i[part], meas_w[part])
            total = time.process_time() - started
            fits = getattr(estimator, 'cpu_s', 0.0)
            refits = getattr(estimator, 'n_refits', 0)
            rows.append([f'{rate:g}', name, fmt(1e6 * total / voltage.size),
                         fmt(1e6 * (total - fits) / voltage.size),
                         f'{100 * total / duration_s:.2g}',
                         str(refits) if name == 'window' else '-',
                         fmt(duration_s / refits) if refits else '-'])
    print('\n## Cost (motor 2, 60 s of data, blocks of 20 ms, refits in-process)\n')
    print('`CPU/sample`: all CPU time over the samples; `buffering`: without the refits '
          "(what the node's executor pays when refits run in their process); `% core`: CPU "
          'over data time, i.e. the share of one core in real time (window: '
          '`online_cpu_budget` 0.08, refit interval 2 s, stretched to the budget).\n')
    print(markdown_table(['rate Hz', 'method', 'CPU/sample us', 'buffering us/sample',
                          '% core', 'refits', 's between refits'], rows))


def main():
    """Run the benchmark and print the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--draws', type=int, default=20)
    parser.add_argument('--tracking-draws', type=int, default=3)
    parser.add_argument('--stationary-s', type=float, default=600.0)
    parser.add_argument('--stationary-draws', type=int, default=2)
    parser.add_argument('--motors', nargs='+', default=list(MOTORS))
    parser.add_argument('--excitations', nargs='+', default=list(EXCITATIONS))
    parser.add_argument('--noises', nargs='+', type=float, default=list(NOISES),
                        help='noise levels of the accuracy grid (fractions)')
    parser.add_argument('--skip', nargs='*', default=[],
                        choices=('accuracy', 'tracking', 'alarms', 'cpu'))
    parser.add_argument('--window-s', type=float, default=None,
                        help="the window estimator's window_s (default: its default, 30 s)")
    parser.add_argument('--quick', action='store_true', help='2 draws, short stationary run')
    args = parser.parse_args()
    if args.quick:
        args.draws, args.tracking_draws = 2, 1
        args.stationary_s, args.stationary_draws = 120.0, 1
    if args.window_s is not None:
        WINDOW['window_s'] = args.window_s
    started = time.monotonic()
    print('# Online estimation: accuracy, tracking, alarms, cost\n')
    print(f'Command: `{command_line()}`  \nMachine: {environment()}  \n'
          f'Load average at the start: {os.getloadavg()[0]:.2f}\n')
    if 'accuracy' not in args.skip:
        print(f'## Accuracy\n\n{DURATION_S:g} s at {1 / DT:g} Hz, {args.draws} noise draws '
              f'per noise level (1 without noise), refits every {GRID_INTERVAL_S:g} s of data '
              f'over a window growing from the start up to {window_length():g} s (the node '
              'refits every 2 s; the estimates at 10 s and 30 s are the same); RLS with the '
              "node's 10 s memory.")
        results, offline = accuracy_runs(args.draws, args.motors, args.excitations,
                                         tuple(args.noises))
        accuracy_tables(results, offline)
    if 'tracking' not in args.skip:
        tracking_table(args.tracking_draws, args.motors)
    if 'alarms' not in args.skip:
        false_alarm_table(args.stationary_draws, args.stationary_s, args.motors)
    if 'cpu' not in args.skip:
        cpu_table()
    print(f'\nWall time {time.monotonic() - started:.0f} s; load average at the end: '
          f'{os.getloadavg()[0]:.2f}.')


if __name__ == '__main__':
    main()
