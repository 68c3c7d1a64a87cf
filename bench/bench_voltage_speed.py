"""
Voltage and speed without a current (issue 31): kS, kV, kA against the truth and the bound.

Four questions, one table each, in one run:

1. On a simulated motor (paper motor 2, 1 % white speed noise, 1 kHz) excited by a 10 s PRBS
   and by a SysId-like routine (quasistatic ramps and dynamic steps, both directions), how far
   are kS, kV, kA from the true combinations ``Ra Mc/CPhi``, ``CPhi + Ra b/CPhi``,
   ``Ra J/CPhi``; are the stated standard errors honest; and how do they compare with the
   Cramer-Rao bound of the same experiment (the least standard error any unbiased estimator
   reaches on those data)?
2. Why kA is loose on the SysId routine: the bound of kA for variants of the experiment (the
   share ``CPhi/kV`` known, less noise, a slower sample rate, steps that reverse the motor
   while it runs) and the bias of a first-order model that leaves the armature lag out.
3. On the public SysId log of a real mechanism (``sysid_data.json`` of
   github.com/calcmogul/SysIdOpt: four tests, 5 ms samples), the identified kS, kV beside a
   quasistatic steady-state fit of the same log (``u`` regressed on ``sgn w`` and ``w`` over
   the two slow tests).
4. The effect discovery on the voltage-to-speed model (``discovery/voltage_speed.py``), on
   paper motor 2 at 1 % noise: clean records (false effects over the seeds), a true load
   torque (0.5 N m and 0.1 N m) and a Coulomb asymmetry (0.3 N m): the effect found, a
   wrong one, its value against the truth in volts (``Ra T/CPhi``) and kS, kV, kA before
   (no discovery) and after.  Section 1 has a 30 s PRBS too, for the issue's goal of 2 %
   against the Cramer-Rao bound.

Why kA: with the armature lag ``Ta = La/Ra`` the voltage-to-speed transfer function is
``1 / (Ta kA s^2 + (kA + Ta Ra b/CPhi) s + kV)``: its three coefficients do not give ``kA``
and ``Ta Ra b/CPhi = Ta (kV - CPhi)`` apart (any share ``CPhi/kV`` between 0 and 1 fits
them); only the Coulomb friction, which acts behind the armature, tells them apart, at the
instants the friction reverses or breaks away.  A PRBS reverses the motor dozens of times, a
SysId routine four.

Run from the repository root::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_voltage_speed.py \
        --sysidopt /work/.mirror/calcmogul+SysIdOpt/repo --out bench/voltage_speed_results.md

``--sysidopt`` takes a clone (bare or not) of github.com/calcmogul/SysIdOpt;
``--discovery-only`` runs section 4 alone (its load average and command line first).
"""

import argparse
from dataclasses import replace
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery.state import DEFAULT_ACCEPTANCE
from dcmotor_id.identification.estimators import voltage_speed as vs
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

DT = 1e-3
NAMES = ('kS', 'kV', 'kA')
#: The acceleration gain ``kA + Ta Ra b/CPhi`` (``combined.acceleration_gain``).
GAIN = 'kA + Ta Ra b/CPhi'
#: The log's nominal sample period [s] (its stamps jitter around it).
SYSID_PERIOD_S = 5e-3
SYSID_TESTS = ('slow-forward', 'slow-backward', 'fast-forward', 'fast-backward')


def combinations(motor):
    """Return the true kS, kV, kA of a motor (La neglected) and its acceleration gain."""
    return {'kS': motor.Ra * motor.Mc / motor.CPhi,
            'kV': motor.CPhi + motor.Ra * motor.b / motor.CPhi,
            'kA': motor.Ra * motor.J / motor.CPhi,
            GAIN: (motor.Ra * motor.J + motor.La * motor.b) / motor.CPhi}


def sysid_voltage(dt=DT, reversing=0):
    """SysId-like routine: ramps both ways, then steps both ways [V] (as the unit tests)."""
    t = np.arange(0.0, 3.0, dt)
    rest = np.zeros(int(round(0.3 / dt)))
    step = int(round(1.5 / dt))
    parts = [6.0 * t, rest, -6.0 * t, rest, np.full(step, 28.0), rest, np.full(step, -28.0)]
    if reversing:  # then steps of 0.4 s that reverse the running motor
        parts += [rest] + [np.full(int(round(0.4 / dt)), 28.0 * (-1) ** k)
                           for k in range(reversing)]
    return np.concatenate(parts)


def prbs_voltage(dt=DT, duration=10.0):
    """``duration`` s (10 s) of a +-43 V PRBS clocked at 20 Hz."""
    return make_excitation('prbs', duration, dt, amplitude_v=43.0, frequency_hz=20.0,
                           seed=1)[1]


def long_prbs_voltage(dt=DT):
    """30 s of the PRBS."""
    return prbs_voltage(dt, 30.0)


EXPERIMENTS = {'PRBS 10 s': prbs_voltage, 'ramps + steps': sysid_voltage}
#: Experiments of table 1 on paper motor 2 only.
LONG_EXPERIMENTS = {'PRBS 30 s': long_prbs_voltage}


def noisy_record(motor, voltage, seed, noise=0.01, dt=DT):
    """Return a record of the speed under ``voltage`` (white noise, ``noise`` of its spread)."""
    _, speed = simulate_motor(motor, voltage, dt)
    rng = np.random.default_rng(seed)
    speed = speed + noise * np.std(speed) * rng.standard_normal(speed.size)
    return Record(np.arange(voltage.size) * dt, voltage=voltage, speed=speed, source='sim')


def true_theta(motor):
    """Return the estimator's second-order parameters at the truth (``vs.motor_of``'s layout)."""
    truth = combinations(motor)
    share_lag = motor.La / motor.Ra * truth['kV'] / truth['kA']
    return np.array([math.log(truth['kA']), math.log(truth['kV']), truth['kS'],
                     math.log(share_lag), motor.CPhi / truth['kV']])


def jacobian(function, x, steps):
    """Central-difference Jacobian of ``function`` at ``x`` with per-coordinate ``steps``."""
    columns = []
    for index, step in enumerate(steps):
        shift = np.zeros_like(x)
        shift[index] = step
        columns.append((function(x + shift) - function(x - shift)) / (2.0 * step))
    return np.column_stack(columns)


def cramer_rao(motor, voltage, noise=0.01, dt=DT, share_known=False):
    """
    Return the Cramer-Rao bound [% of the truth] of kS, kV, kA on one record (white noise).

    The model is the estimator's exact second-order one with the record's initial speed and
    current free, as the fit has them; at rest a stuck motor's initial speed carries no
    information and is dropped.
    """
    record = noisy_record(motor, voltage, 0, noise=0.0, dt=dt)
    sigma = noise * float(np.std(record.speed))
    x = np.concatenate([true_theta(motor), [0.0, 0.0]])
    matrix = jacobian(vs._residual(vs._second_order, [record], 5), x,
                      [1e-6, 1e-6, 1e-6 * max(x[2], 1.0), 1e-6, 1e-6, 1e-3, 1e-3])
    if share_known:
        matrix = np.delete(matrix, 4, axis=1)
    keep = np.linalg.norm(matrix, axis=0) > 0
    covariance = np.linalg.inv(matrix[:, keep].T @ matrix[:, keep]) * sigma ** 2
    sd = np.sqrt(np.diag(covariance))
    truth = combinations(motor)
    out = {'kS': 100.0 * sd[2] / truth['kS'], 'kV': 100.0 * sd[1], 'kA': 100.0 * sd[0]}
    if not share_known:
        gain, gain_sd = vs.acceleration_gain(x, covariance)
        out[GAIN] = 100.0 * gain_sd / gain
    return out


def simulated_rows(seeds):
    """Table 1: per motor and experiment, errors, stated standard errors and the bound."""
    motors = {'paper motor 2 (CPhi/kV 0.51)': PAPER_MOTORS['paper2'],
              'paper motor 2, CPhi 1.2 (CPhi/kV 0.75)': replace(PAPER_MOTORS['paper2'],
                                                                CPhi=1.2)}
    for label, motor in motors.items():
        truth = combinations(motor)
        experiments = dict(EXPERIMENTS, **(LONG_EXPERIMENTS if motor.CPhi == 0.7 else {}))
        for experiment, make in experiments.items():
            voltage = make()
            bound = cramer_rao(motor, voltage)
            errors, stated, times, lags = [], [], [], 0
            for seed in range(seeds):
                began = time.process_time()
                fit = vs.fit_voltage_speed([noisy_record(motor, voltage, seed)])
                times.append(time.process_time() - began)
                values = dict(fit.values, **{GAIN: fit.acceleration_gain or math.nan})
                spreads = dict(fit.stderr, **{GAIN: fit.acceleration_gain_stderr or math.nan})
                errors.append([100.0 * (values[n] / truth[n] - 1.0) for n in (*NAMES, GAIN)])
                stated.append([100.0 * spreads[n] / truth[n] for n in (*NAMES, GAIN)])
                lags += fit.armature_time_constant_s is not None
            errors, stated = np.array(errors), np.array(stated)
            spread = np.sqrt(np.mean(errors ** 2, axis=0))
            for k, name in enumerate((*NAMES, GAIN)):
                worst = float(np.max(np.abs(errors[:, k])))
                yield [label, experiment, name, f'{worst:.2f}', f'{spread[k]:.2f}',
                       f'{np.median(stated[:, k]):.2f}', f'{bound[name]:.2f}',
                       f'{int(np.sum(np.abs(errors[:, k]) <= 2.0 * stated[:, k]))}/{seeds}',
                       'yes' if worst <= 2.0 else 'no',
                       f'{lags}/{seeds}', f'{np.median(times):.1f}']


def first_order_bias(motor, voltage):
    """Return kA of a first-order fit on noiseless data, in % off the truth (the lag's bias)."""
    record = noisy_record(motor, voltage, 0, noise=0.0)
    start = vs.regression_start([record])
    theta = np.array([math.log(start['kA']), math.log(start['kV']), start['kS']])
    fit = vs._fit(vs._first_order_state, [record], theta, [-np.inf, -np.inf, 0.0],
                  [np.inf, np.inf, np.inf])
    return 100.0 * (math.exp(fit.x[0]) / combinations(motor)['kA'] - 1.0)


def bound_rows():
    """Table 2: the bound of kA on variants of the SysId routine (paper motor 2)."""
    motor = PAPER_MOTORS['paper2']
    variants = [
        ('ramps + steps, 1 kHz, 1 % noise (as table 1)', lambda: cramer_rao(
            motor, sysid_voltage())),
        ('the same, the share CPhi/kV known', lambda: cramer_rao(
            motor, sysid_voltage(), share_known=True)),
        ('the same, 0.25 % noise', lambda: cramer_rao(motor, sysid_voltage(), noise=0.0025)),
        ('the same, 5 ms samples (200 Hz)', lambda: cramer_rao(
            motor, sysid_voltage(5e-3), dt=5e-3)),
        ('ramps + steps + 8 reversing steps of 0.4 s', lambda: cramer_rao(
            motor, sysid_voltage(reversing=8))),
        ('ramps + steps + 20 reversing steps of 0.4 s', lambda: cramer_rao(
            motor, sysid_voltage(reversing=20))),
        ('PRBS 10 s (as table 1)', lambda: cramer_rao(motor, prbs_voltage())),
    ]
    for label, bound in variants:
        values = bound()
        yield [label, f'{values["kS"]:.2f}', f'{values["kV"]:.3f}', f'{values["kA"]:.2f}',
               f'{values[GAIN]:.3f}' if GAIN in values else '-']
    yield ['first-order model (no armature lag), ramps + steps, no noise: kA off by',
           '', '', f'{first_order_bias(motor, sysid_voltage()):+.1f} (bias)', '']


def effect_cases(motor):
    """Return table 4's cases: label -> (true effects, (name, volts) or None)."""
    from dcmotor_id.identification.effects import make_effect
    volts = motor.Ra / motor.CPhi
    return {
        'none': ([], None),
        f'load torque 0.5 N m ({0.5 * volts:.3g} V)': (
            [make_effect('load_torque', torque_Nm=0.5)], ('load_torque', 0.5 * volts)),
        f'load torque 0.1 N m ({0.1 * volts:.3g} V)': (
            [make_effect('load_torque', torque_Nm=0.1)], ('load_torque', 0.1 * volts)),
        f'Coulomb asymmetry 0.3 N m ({0.3 * volts:.3g} V)': (
            [make_effect('coulomb_asymmetry', delta_Nm=0.3)],
            ('coulomb_asymmetry', 0.3 * volts)),
    }


#: A Coulomb asymmetry below the Coulomb friction is the same model as a load torque
#: (``dcmotor_id.identification.effects``): the tie goes to the load torque.
SAME_MODEL = {'coulomb_asymmetry': {'coulomb_asymmetry', 'load_torque'}}


def effect_record(motor, voltage, effects, seed):
    """Return a prepared record of the speed under ``voltage`` with true ``effects``."""
    from dcmotor_id.simulation import simulate_motor_effects
    _, speed, _ = simulate_motor_effects(motor, voltage, DT, effects)
    speed = speed + 0.01 * np.std(speed) * np.random.default_rng(seed).standard_normal(
        speed.size)
    return prepare_records([Record(np.arange(voltage.size) * DT, voltage=voltage,
                                   speed=speed, source='sim')])


def effect_value(result):
    """Return the first effect's value in volts and its standard error (``combined``)."""
    for key, entry in (result.combined or {}).items():
        if '.' in key:
            return entry['value'], entry['stderr']
    return math.nan, math.nan


def discovery_case(motor, make, effects, true, seeds):
    """Run one case of table 4 over the seeds; return its counts and errors."""
    truth = combinations(motor)
    found = wrong = within = 0
    values, before, after, names, times, screens = [], [], [], [], [], []
    for seed in range(seeds):
        records = effect_record(motor, make(), effects, seed)
        base = vs.fit_voltage_speed(records)
        began = time.process_time()
        result = identify(records)
        times.append(time.process_time() - began)
        screens += [candidate for step in result.discovery.get('steps', [])
                    for candidate in step['candidates']]
        got = [effect['name'] for effect in result.effects]
        names += got
        right = bool(true) and bool(got) and got[0] in SAME_MODEL.get(true[0], {true[0]})
        found += right
        wrong += len(got) - right
        if right:
            value, stderr = effect_value(result)
            values.append(value)
            within += abs(value - true[1]) <= 2.0 * stderr
        before.append([100.0 * (base.values[n] / truth[n] - 1.0) for n in NAMES])
        after.append([100.0 * (result.parameters[n] / truth[n] - 1.0) for n in NAMES])
    return (found, wrong, within, values, np.array(before), np.array(after), names, times,
            screens)


def screen_cells(screens):
    """
    Return the candidates refitted of those screened, and the screen against the refits.

    The largest gap in points between a refitted candidate's screen (the share of the
    training residual its linearised fit explains) and its refit's training gain.
    """
    refitted = [item for item in screens if item['refitted']]
    gaps = [abs(item['screen_explained_pct'] - item['insample_gain_pct'])
            for item in refitted if item['insample_gain_pct'] is not None]
    return [f'{len(refitted)}/{len(screens)}', f'{max(gaps):.2f}' if gaps else '-']


def discovery_rows(seeds):
    """
    Table 4: the effect discovery on the voltage-to-speed model (paper motor 2, 1 % noise).

    The clean records over ``seeds`` seeds, the cases with an effect over half as many (at
    least 2): found (the true effect, or the one it is the same model as), wrong (any other
    effect), the value's median against the truth and how often it lies within two stated
    standard errors, and kS, kV, kA's rms error before (no discovery) and after.
    """
    motor = PAPER_MOTORS['paper2']
    for label, (effects, true) in effect_cases(motor).items():
        count = seeds if true is None else max(2, seeds // 2)
        for experiment, make in EXPERIMENTS.items():
            found, wrong, within, values, before, after, names, times, screens = \
                discovery_case(motor, make, effects, true, count)
            rms = [np.sqrt(np.mean(errors ** 2, axis=0)) for errors in (before, after)]
            listed = ', '.join(sorted(set(names))) or 'none'
            yield [label, experiment, '-' if true is None else f'{found}/{count}',
                   f'{wrong}/{count}', listed,
                   '-' if not values else f'{np.median(values):.4g} ({true[1]:.4g})',
                   '-' if not values else f'{within}/{found}',
                   *[f'{rms[0][k]:.2f} / {rms[1][k]:.2f}' for k in range(len(NAMES))],
                   f'{np.median(times):.1f}', *screen_cells(screens)]


def load_sysidopt(path):
    """Return the tests of SysIdOpt's ``sysid_data.json`` (a clone, bare or not) by name."""
    if os.path.exists(os.path.join(path, 'sysid_data.json')):
        with open(os.path.join(path, 'sysid_data.json'), encoding='utf-8') as handle:
            data = json.load(handle)
    else:
        data = json.loads(subprocess.run(['git', '--git-dir', path, 'show',
                                          'HEAD:sysid_data.json'], check=True,
                                         capture_output=True, text=True).stdout)
    # columns: time [s], voltage [V], position, velocity; units Radians: rad/s already.
    assert data['units'] == 'Radians', data['units']
    return {name: np.asarray(data[name], dtype=float) for name in SYSID_TESTS}


def on_grid(test, name, period=SYSID_PERIOD_S):
    """Return a test on a uniform grid: the voltage held (as applied), the speed interpolated."""
    time_s = test[:, 0] - test[0, 0]
    grid = np.arange(0.0, time_s[-1], period)
    held = np.clip(np.searchsorted(time_s, grid, side='right') - 1, 0, time_s.size - 1)
    return Record(grid, voltage=test[held, 1], speed=np.interp(grid, time_s, test[:, 3]),
                  source=name)


def quasistatic_fit(tests):
    """``u`` on ``sgn w`` and ``w`` over the moving samples of the slow tests: kS, kV, stderr."""
    rows, target = [], []
    for name in ('slow-forward', 'slow-backward'):
        speed, voltage = tests[name][:, 3], tests[name][:, 1]
        moving = np.abs(speed) > 0.02 * np.abs(speed).max()
        rows.append(np.column_stack([np.sign(speed), speed])[moving])
        target.append(voltage[moving])
    matrix, target = np.concatenate(rows), np.concatenate(target)
    solution, residual = np.linalg.lstsq(matrix, target, rcond=None)[:2]
    variance = float(residual[0]) / (target.size - 2)
    sd = np.sqrt(np.diag(np.linalg.inv(matrix.T @ matrix)) * variance)
    values = {'kS': float(solution[0]), 'kV': float(solution[1])}
    return values, {'kS': float(sd[0]), 'kV': float(sd[1])}


def sysidopt_rows(path):
    """Table 3: the identified kS, kV, kA beside the quasistatic fit of the same log."""
    tests = load_sysidopt(path)
    records = [on_grid(test, name) for name, test in tests.items()]
    began = time.process_time()
    result = identify(prepare_records(records))
    seconds = time.process_time() - began
    reference, reference_sd = quasistatic_fit(tests)
    for name in NAMES:
        value, sd = result.parameters[name], result.stderr[name]
        ref = reference.get(name)
        yield [name, f'{value:.5g}', f'{100.0 * sd / value:.1f}', '-' if ref is None
               else f'{ref:.5g} +- {100.0 * reference_sd[name] / ref:.1f} %',
               '-' if ref is None else f'{100.0 * (value / ref - 1.0):+.2f}',
               '-' if ref is None else ('yes' if abs(value / ref - 1.0) <= 0.10 else 'no'),
               f'{seconds:.1f}']
    effects = ', '.join(f"{effect['name']} " + ' '.join(
        f'{key}={value:.4g}' for key, value in effect['parameters'].items()
        if isinstance(value, float)) for effect in result.effects) or 'none'
    yield ['effects found (discovery)', effects, '-', '-', '-', '-', '']
    for key, label in (('armature_time_constant_s', 'second lag Ta [s]'),
                       ('acceleration_gain', f'{GAIN} (acceleration_gain)')):
        entry = (result.combined or {}).get(key)
        yield [label, '-' if entry is None else f'{entry["value"]:.3g}',
               '-' if entry is None else f'{100.0 * entry["stderr"] / entry["value"]:.1f}',
               '-', '-', '-', '']


def table(header, rows):
    """Markdown table."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    return '\n'.join(lines + ['| ' + ' | '.join(row) + ' |' for row in rows])


def discovery_section(seeds):
    """Return section 4's lines: the effect discovery on the voltage-to-speed model."""
    return ['', '## 4. Effect discovery on the voltage-to-speed model (paper motor 2, '
            '1 % noise)', '',
            'identify with discovery on (the default): the effects that act on the shaft '
            '(load_torque, coulomb_asymmetry, viscous_asymmetry, sensor_delay) fitted on the '
            'voltage-to-speed model with its armature lag, in volts (a torque T as Ra T/CPhi), '
            f"each judged by the loop's held-out rule ({DEFAULT_ACCEPTANCE}, the default). "
            f'Clean records over {seeds} seeds, the others over '
            f'{max(2, seeds // 2)}. found: the true '
            'effect (a Coulomb asymmetry below the Coulomb friction is the same model as a '
            'load torque, and the tie goes to the load torque); wrong: any other effect '
            'added; value: the median of the effect found in V (the truth); within 2 se: '
            'its stated standard error; kS, kV, kA: rms error in % of the true combination '
            'before (no discovery) / after; s: median CPU seconds of identify; refitted: '
            'the candidates refitted of those the rounds tried (screened), over the seeds; '
            'screen gap: the largest difference in points between a refitted '
            "candidate's screen (the share of the training residual its linearised fit "
            "explains) and its refit's training gain.", '',
            table(['true effect', 'experiment', 'found', 'wrong', 'effects added',
                   'value V (true)', 'within 2 se', 'kS % before / after',
                   'kV % before / after', 'kA % before / after', 's', 'refitted',
                   'screen gap'],
                  discovery_rows(seeds))]


def main():
    """Run the tables and print (or write) the report."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', type=int, default=8, help='noise seeds per experiment')
    parser.add_argument('--sysidopt', help='clone of github.com/calcmogul/SysIdOpt')
    parser.add_argument('--out', help='write the report here (default: stdout)')
    parser.add_argument('--discovery-only', action='store_true',
                        help='run section 4 (the effect discovery) alone')
    args = parser.parse_args()
    load = os.getloadavg()
    if args.discovery_only:
        return write_report([f'`bench/bench_voltage_speed.py {" ".join(sys.argv[1:])}`; load '
                             f'average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (2 cores).',
                             *discovery_section(args.seeds)], args.out)
    parts = ['# Voltage and speed without a current: kS, kV, kA (issue 31)', '',
             f'`bench/bench_voltage_speed.py {" ".join(sys.argv[1:])}`; load average '
             f'{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (2 cores).', '',
             '## 1. Simulated motor, 1 % white speed noise, 1 kHz', '',
             'Errors in % of the true combination over the seeds; stated: the median stated '
             'standard error [%]; bound: the Cramer-Rao bound [%] of the same record; within '
             '2 se: seeds whose error is within two stated standard errors; lag: fits that '
             'kept the armature lag; s: median CPU seconds per fit.', '',
             table(['motor', 'experiment', 'parameter', 'worst abs. error %', 'rms error %',
                    'stated %', 'bound %', 'within 2 se', 'within 2 %', 'lag', 's'],
                   simulated_rows(args.seeds)), '',
             '## 2. Why kA is loose on ramps and steps: its bound on variants (paper motor 2)',
             '', table(['experiment', 'kS bound %', 'kV bound %', 'kA bound %',
                       f'{GAIN} bound %'], bound_rows())]
    if args.sysidopt:
        commit = subprocess.run(['git', '--git-dir', args.sysidopt, 'rev-parse', 'HEAD'],
                                capture_output=True, text=True).stdout.strip()
        parts += ['', '## 3. Public SysId log (calcmogul/SysIdOpt `sysid_data.json`, '
                  f'commit {commit[:7] or "?"}) against a quasistatic fit of the same log', '',
                  'identify on the four tests as four records (each put on a 5 ms grid: the '
                  'voltage held, the speed interpolated); the quasistatic fit: `u` on `sgn w` '
                  'and `w` over the moving samples of the two slow tests, with its standard '
                  'error.', '',
                  table(['parameter', 'identify', 'stated %', 'quasistatic fit',
                         'identify vs quasistatic %', 'within 10 %', 'CPU s'],
                        sysidopt_rows(args.sysidopt))]
    parts += discovery_section(args.seeds)
    write_report(parts, args.out)


def write_report(parts, out):
    """Print the report's lines and write them to ``out`` when given."""
    report = '\n'.join(parts) + '\n'
    if out:
        with open(out, 'w', encoding='utf-8') as handle:
            handle.write(report)
    print(report)


if __name__ == '__main__':
    main()
