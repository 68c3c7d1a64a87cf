"""
Voltage-to-speed design (issue 31): kA or the acceleration gain in the feedforward and the plant.

A voltage-to-speed result holds ``kS, kV, kA`` (``kA = Ra J/CPhi``) and, when the armature lag
shapes the speed, ``combined.acceleration_gain`` = ``kA + Ta Ra b/CPhi`` (``Ta = La/Ra``), the
coefficient of ``dw/dt`` in ``u = kS sgn w + kV w + (kA + Ta Ra b/CPhi) dw/dt + Ta kA
d2w/dt2``: what a feedforward that neglects the jerk needs, and the first-order plant that
matches the motor's ``1/(Ta kA s^2 + (kA + Ta Ra b/CPhi) s + kV)`` up to ``s``.  The design
can take either as its acceleration gain; this benchmark measures which one controls better.

For each simulated motor (the cases of ``bench_voltage_speed.py``), experiment (a 10 s PRBS
and the SysId-like ramps + steps, 1 % white speed noise, 1 kHz) and noise seed, the
voltage-to-speed fit gives ``kS, kV, kA`` and the acceleration gain; the design
(``design_controller``, 1 ms sample period) is made twice, once with each as ``kA``.  Then, on
the TRUE motor (the exact hybrid simulation, Coulomb friction and armature included):

- **feedforward**: the voltage ``kS sgn w + kV w + k dw/dt`` predicted from the speed of a
  held-out noiseless record (a 10 s multisine 0.2-2 Hz, 30 V; ``dw/dt`` by central
  differences), its RMS error in % of the RMS voltage;
- **tracking**: the designed discrete speed PI plus the feedforward following a smooth
  speed profile (0 -> 40 -> -40 -> 0 rad/s, cosine ramps of 0.3-0.6 s): RMS and largest
  speed error [rad/s];
- **step**: the PI with the static feedforward (kS, kV) on a reference step 20 -> 40 rad/s:
  overshoot in % of the step.

Rows ``truth`` use the true ``kA`` and acceleration gain (no estimation error).

``--section lag --before DIR`` measures instead the speed loop designed with the armature
lag in its plant (the second-order ``1/(Ta kA s^2 + (kA + Ta Ra b/CPhi) s + kV)``) against
the code in ``DIR`` (a tree of the code before, e.g. ``git archive main``, whose design
leaves the lag out), in the same run: each identify result as ``identify --json`` writes it
(``combined`` with ``Ta`` and the acceleration gain) is designed by both codes (the one in
``DIR`` in a subprocess), and each design is run on the true motor as above.  Besides the
step with the static feedforward it measures the PI alone on the same step (what the design
states as ``nominal.speed.step_overshoot_pct``) and the phase margin of the designed PI on the
true motor's sampled voltage-to-speed plant (python-control).

Run from the repository root::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_design_gain.py --seeds 4 \
        --out bench/design_results.md
    git archive main | tar -x -C /tmp/main_tree    # plus its compiled kernel
    PYTHONPATH=$PWD .venv/bin/python bench/bench_design_gain.py --section lag \
        --before /tmp/main_tree --seeds 4 --out bench/design_results.md

``--out`` replaces this benchmark's section of the file, or appends it.
"""

import argparse
from dataclasses import replace
import json
import os
import subprocess
import sys
import time

from bench_voltage_speed import combinations, EXPERIMENTS, GAIN, noisy_record, table
import control
import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.design.control import design_controller
from dcmotor_id.design.loops import margins, motor_model
from dcmotor_id.design.plant import Motor
from dcmotor_id.identification.estimators import voltage_speed as vs
from dcmotor_id.simulation import MotorStepper, simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

DT = 1e-3
MOTORS = {'paper motor 2 (CPhi/kV 0.51)': PAPER_MOTORS['paper2'],
          'paper motor 2, CPhi 1.2 (CPhi/kV 0.75)': replace(PAPER_MOTORS['paper2'], CPhi=1.2)}
#: Speed bandwidths [Hz] asked of the design: above the lowest a 60 deg PI reaches on both
#: motors (5.6 Hz); the armature pole is at 16 Hz.
BANDWIDTHS = (8.0, 15.0)
CHOICES = ('kA', 'acceleration gain')


def held_out(motor):
    """Return the held-out record's voltage, speed and acceleration (noiseless multisine)."""
    voltage = make_excitation('multisine', 10.0, DT, amplitude_v=30.0, frequency_hz=0.2,
                              max_frequency_hz=2.0, seed=7)[1]
    _, speed = simulate_motor(motor, voltage, DT)
    return voltage, speed, np.gradient(speed, DT)


def feedforward_error_pct(gains, record):
    """Return the RMS error of the feedforward's voltage on a record, in % of its RMS voltage."""
    voltage, speed, acceleration = record
    predicted = gains['kS'] * np.sign(speed) + gains['kV'] * speed + gains['kA'] * acceleration
    return 100.0 * np.sqrt(np.mean((predicted - voltage)[10:-10] ** 2)) / np.sqrt(
        np.mean(voltage ** 2))


def profile():
    """Return a smooth speed reference and its derivative (cosine ramps between plateaus)."""
    pieces, level = [], 0.0
    for target, ramp_s, hold_s in ((40.0, 0.3, 0.5), (-40.0, 0.6, 0.5), (0.0, 0.3, 0.3)):
        t = np.arange(int(round(ramp_s / DT))) * DT
        pieces.append(level + (target - level) * 0.5 * (1.0 - np.cos(np.pi * t / ramp_s)))
        pieces.append(np.full(int(round(hold_s / DT)), target))
        level = target
    reference = np.concatenate([np.zeros(100)] + pieces)
    return reference, np.gradient(reference, DT)


def closed_loop(motor, design, reference, acceleration, start=0.0, integral=0.0):
    """Run the designed discrete speed PI plus the feedforward on the true motor; the speed."""
    ff, pi = design['feedforward'], design['speed_loop']['discrete']
    i0 = (motor.b * start + motor.Mc * np.sign(start)) / motor.CPhi
    stepper = MotorStepper(motor, DT, (i0, start))
    w, previous = start, 0.0
    speeds = np.empty(reference.size)
    for k, (target, slope) in enumerate(zip(reference, acceleration)):
        error = target - w
        integral += pi['q0'] * error + pi['q1'] * previous
        previous = error
        static = ff['kS'] * np.sign(target) + ff['kV'] * target
        speeds[k] = w
        _, w = stepper.step(static + ff['kA'] * slope + integral)
    return speeds


def metrics(motor, design, record):
    """Return the feedforward error, tracking RMS and peak errors and the step overshoot."""
    reference, slope = profile()
    speeds = closed_loop(motor, design, reference, slope)
    step = np.full(int(round(1.0 / DT)), 40.0)
    response = closed_loop(motor, design, step, np.zeros(step.size), start=20.0)
    return [feedforward_error_pct(design['feedforward'], record),
            float(np.sqrt(np.mean((speeds - reference) ** 2))),
            float(np.max(np.abs(speeds - reference))),
            100.0 * max(0.0, float(response.max()) - 40.0) / 20.0]


def designs(gains, bandwidth):
    """Return the design with kA and with the acceleration gain as its acceleration gain."""
    made = {}
    for choice in CHOICES:
        acceleration = gains['kA'] if choice == 'kA' else gains[GAIN]
        result = {'mode': 'voltage_speed', 'stderr': {},
                  'parameters': {'kS': gains['kS'], 'kV': gains['kV'], 'kA': acceleration}}
        made[choice] = design_controller(result, speed_bandwidth_hz=bandwidth,
                                         sample_period_s=DT)
    return made


def rows(seeds):
    """Yield a row per motor, experiment, bandwidth and choice (medians over the seeds)."""
    for label, motor in MOTORS.items():
        record = held_out(motor)
        fits = {'truth': [combinations(motor)]}
        for experiment, make in EXPERIMENTS.items():
            voltage = make()
            fits[experiment] = []
            for seed in range(seeds):
                fit = vs.fit_voltage_speed([noisy_record(motor, voltage, seed)])
                fits[experiment].append(dict(fit.values, **{
                    GAIN: fit.acceleration_gain or fit.values['kA']}))
        for bandwidth in BANDWIDTHS:
            for experiment, found in fits.items():
                measured = {choice: [] for choice in CHOICES}
                for gains in found:
                    for choice, made in designs(gains, bandwidth).items():
                        measured[choice].append(metrics(motor, made, record))
                for choice in CHOICES:
                    values = np.median(np.array(measured[choice]), axis=0)
                    worst = np.max(np.array(measured[choice]), axis=0)
                    yield [label, experiment, f'{bandwidth:g}', choice,
                           f'{values[0]:.2f} ({worst[0]:.2f})', f'{values[1]:.3f} '
                           f'({worst[1]:.3f})', f'{values[2]:.2f} ({worst[2]:.2f})',
                           f'{values[3]:.1f} ({worst[3]:.1f})']


def summary(found):
    """Return a line counting the cases where the acceleration gain did better than kA."""
    pairs = list(zip(found[::2], found[1::2]))
    names = ('feedforward voltage error', 'tracking RMS', 'tracking peak', 'step overshoot')
    counts = []
    for column, name in enumerate(names, start=4):
        medians = [(float(ka[column].split()[0]), float(gain[column].split()[0]))
                   for ka, gain in pairs]
        lower = sum(gain < ka for ka, gain in medians)
        higher = sum(gain > ka for ka, gain in medians)
        counts.append(f'{name} lower in {lower}, higher in {higher} of {len(pairs)}')
    return 'The acceleration gain against kA (medians): ' + '; '.join(counts) + '.'


def main():
    """Run the comparison and print (or write) the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seeds', type=int, default=4, help='noise seeds per experiment')
    parser.add_argument('--section', choices=('gain', 'lag'), default='gain',
                        help='gain: kA or the acceleration gain; lag: the armature lag in the '
                        'plant, before (--before) and after')
    parser.add_argument('--before', help='a tree of the code before (section lag)')
    parser.add_argument('--out', help='replace or append the section in this file')
    args = parser.parse_args()
    if args.section == 'lag' and not args.before:
        parser.error('--section lag needs --before DIR (a tree of the code before)')
    load = os.getloadavg()
    began = time.process_time()
    run = f'`bench/bench_design_gain.py {" ".join(sys.argv[1:])}`; load average ' \
        f'{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (2 cores)'
    report = (lag_report(args, run, began) if args.section == 'lag'
              else gain_report(args, run, began))
    if args.out:
        write_section(args.out, report)
    print(report)


def gain_report(args, run, began):
    """Return the section comparing kA and the acceleration gain."""
    found = list(rows(args.seeds))
    body = table(['motor', 'identified from', 'speed bandwidth Hz', 'acceleration gain used',
                  'feedforward voltage error % (worst)', 'tracking RMS rad/s (worst)',
                  'tracking peak rad/s (worst)', 'step overshoot % (worst)'], found)
    return '\n'.join([
        '## Voltage-to-speed design: kA or the acceleration gain (issue 31)', '',
        f'{run}; {time.process_time() - began:.0f} s CPU.', '',
        'Medians over the seeds (worst in brackets); `truth`: the true kA and acceleration '
        'gain. Feedforward: RMS voltage error on a held-out noiseless multisine record; '
        'tracking: the designed 1 ms PI plus the feedforward on a smooth 0/40/-40/0 rad/s '
        'profile; step: 20 -> 40 rad/s with the static feedforward.', '', body, '',
        summary(found), ''])


def write_section(path, section):
    """Replace the section of ``path`` with ``section``'s heading (up to the next), or append."""
    text = ''
    if os.path.exists(path):
        with open(path, encoding='utf-8') as handle:
            text = handle.read()
    heading = section.split('\n', 1)[0]
    kept, _, rest = text.partition(heading)
    after = rest.split('\n## ', 1)[1] if '\n## ' in rest else ''
    parts = [kept.rstrip('\n'), section.rstrip('\n')] + (['## ' + after.rstrip('\n')]
                                                         if after else [])
    with open(path, 'w', encoding='utf-8') as handle:
        handle.write('\n\n'.join(part for part in parts if part) + '\n')


# ----------------------------------------------------------------------------- section lag

#: Runs the code before on a list of ``[result, bandwidth]`` (stdin) and prints the designs.
BEFORE_SCRIPT = (
    'import json, sys\n'
    'from dcmotor_id.design.control import design_controller\n'
    'cases = json.load(sys.stdin)\n'
    'json.dump([design_controller(result, speed_bandwidth_hz=bandwidth, '
    f'sample_period_s={DT!r}) for result, bandwidth in cases], sys.stdout)\n')
CODES = ('before (main)', 'after (this branch)')


def identify_result(motor, fit=None):
    """Return a voltage-to-speed result as ``identify --json`` writes it (fit None: true)."""
    if fit is None:
        true = combinations(motor)
        values, stderr = {name: true[name] for name in ('kS', 'kV', 'kA')}, {}
        lag, gain = motor.La / motor.Ra, true[GAIN]
        lag_error = gain_error = None
    else:
        values, stderr = dict(fit.values), dict(fit.stderr)
        lag, lag_error = fit.armature_time_constant_s, fit.armature_stderr_s
        gain, gain_error = fit.acceleration_gain, fit.acceleration_gain_stderr
    combined = {} if lag is None else {
        'armature_time_constant_s': {'value': lag, 'stderr': lag_error},
        'acceleration_gain': {'value': gain, 'stderr': gain_error}}
    return {'mode': 'voltage_speed', 'parameters': values, 'stderr': stderr,
            'combined': combined}


def before_designs(tree, cases):
    """Return the designs the code in ``tree`` makes of ``cases`` (a subprocess)."""
    done = subprocess.run([sys.executable, '-c', BEFORE_SCRIPT], input=json.dumps(cases),
                          capture_output=True, text=True, check=True, cwd=tree,
                          env=dict(os.environ, PYTHONPATH=os.path.abspath(tree)))
    return json.loads(done.stdout)


def true_phase_margin(motor, design):
    """Return the phase margin [deg] of the designed PI on the true sampled motor."""
    plant = control.c2d(motor_model(Motor(motor.as_dict(derived=False), {}, 'full'))[1, 0],
                        DT, method='zoh')
    loop = design['speed_loop']
    pi = control.c2d(control.tf([loop['kp'], loop['ki']], [1.0, 0.0]), DT, method='tustin')
    return margins(pi * plant)['phase_margin_deg']


def pi_alone_overshoot(motor, design):
    """Return the overshoot [%] of the PI alone (no feedforward) on the 20 -> 40 rad/s step."""
    alone = dict(design, feedforward={'kS': 0.0, 'kV': 0.0, 'kA': 0.0})
    step = np.full(int(round(2.0 / DT)), 40.0)
    i0 = (motor.b * 20.0 + motor.Mc) / motor.CPhi
    # from the steady state: the integral holds the voltage of 20 rad/s
    response = closed_loop(motor, alone, step, np.zeros(step.size), start=20.0,
                           integral=motor.Ra * i0 + motor.CPhi * 20.0)
    return 100.0 * max(0.0, float(response.max()) - 40.0) / 20.0


def lag_metrics(motor, design):
    """Return the stated and true margins, the two step overshoots and the tracking errors."""
    reference, slope = profile()
    speeds = closed_loop(motor, design, reference, slope)
    step = np.full(int(round(1.0 / DT)), 40.0)
    response = closed_loop(motor, design, step, np.zeros(step.size), start=20.0)
    stated = design['nominal']['speed']
    return [stated['phase_margin_deg'], true_phase_margin(motor, design),
            stated.get('step_overshoot_pct', np.nan), pi_alone_overshoot(motor, design),
            100.0 * max(0.0, float(response.max()) - 40.0) / 20.0,
            float(np.sqrt(np.mean((speeds - reference) ** 2))),
            float(np.max(np.abs(speeds - reference)))]


def lag_cases(seeds):
    """Return ``(motor label, experiment, result)`` of every motor, experiment and seed."""
    cases = []
    for label, motor in MOTORS.items():
        cases.append((label, 'truth', identify_result(motor)))
        for experiment, make in EXPERIMENTS.items():
            voltage = make()
            for seed in range(seeds):
                fit = vs.fit_voltage_speed([noisy_record(motor, voltage, seed)])
                cases.append((label, experiment, identify_result(motor, fit)))
    return cases


def lag_rows(seeds, tree):
    """Yield a row per motor, experiment, bandwidth and code (medians over the seeds)."""
    cases = lag_cases(seeds)
    asked = [(case, bandwidth) for bandwidth in BANDWIDTHS for case in cases]
    before = before_designs(tree, [[case[2], bandwidth] for case, bandwidth in asked])
    after = [design_controller(case[2], speed_bandwidth_hz=bandwidth, sample_period_s=DT)
             for case, bandwidth in asked]
    groups = {}
    for (case, bandwidth), old, new in zip(asked, before, after):
        motor = MOTORS[case[0]]
        for code, design in zip(CODES, (old, new)):
            key = (case[0], case[1], f'{bandwidth:g}', code)
            groups.setdefault(key, []).append(lag_metrics(motor, design))
    for key, measured in groups.items():
        values = np.median(np.array(measured), axis=0)
        worst = np.max(np.array(measured), axis=0)
        least = np.min(np.array(measured), axis=0)
        stated = '-' if np.isnan(values[2]) else f'{values[2]:.1f}'
        yield list(key) + [
            f'{values[0]:.1f}', f'{values[1]:.1f} ({least[1]:.1f})', stated,
            f'{values[3]:.1f} ({worst[3]:.1f})', f'{values[4]:.1f} ({worst[4]:.1f})',
            f'{values[5]:.3f} ({worst[5]:.3f})', f'{values[6]:.2f} ({worst[6]:.2f})']


def lag_report(args, run, began):
    """Return the section comparing the design without and with the armature lag."""
    found = list(lag_rows(args.seeds, args.before))
    body = table(['motor', 'identified from', 'speed bandwidth Hz', 'design',
                  'stated PM deg', 'PM on the true motor deg (least)',
                  'stated step overshoot %', 'step overshoot PI alone % (worst)',
                  'step overshoot with static feedforward % (worst)',
                  'tracking RMS rad/s (worst)', 'tracking peak rad/s (worst)'], found)
    return '\n'.join([
        '## Voltage-to-speed speed loop: the armature lag in the plant (issue 31)', '',
        f'{run}; {time.process_time() - began:.0f} s CPU (this process; the code before runs '
        'in a subprocess).', '',
        'The same identify results (`truth`: the true kS, kV, kA, Ta and acceleration gain; '
        f'else medians over {args.seeds} seeds, worst in brackets) designed by the code before '
        '(first-order plant `(kA + Ta Ra b/CPhi) s + kV`) and after (second-order plant with '
        'the identified Ta), 60 deg asked, 1 ms; every figure but the stated ones measured on '
        'the TRUE motor: the phase margin of the designed PI on its sampled voltage-to-speed '
        'plant (python-control), the step 20 -> 40 rad/s of the PI alone (exact simulation, '
        'from the steady state) and with the static feedforward, and the tracking of the '
        'smooth 0/40/-40/0 rad/s profile with the PI and the feedforward.', '', body, ''])


if __name__ == '__main__':
    main()
