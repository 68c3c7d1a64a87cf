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

Run from the repository root::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_design_gain.py --seeds 4 \
        --out bench/design_results.md

``--out`` replaces this benchmark's section of the file (its last), or appends it.
"""

import argparse
from dataclasses import replace
import os
import sys
import time

from bench_voltage_speed import combinations, EXPERIMENTS, GAIN, noisy_record, table
import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.design.control import design_controller
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


def closed_loop(motor, design, reference, acceleration, start=0.0):
    """Run the designed discrete speed PI plus the feedforward on the true motor; the speed."""
    ff, pi = design['feedforward'], design['speed_loop']['discrete']
    i0 = (motor.b * start + motor.Mc * np.sign(start)) / motor.CPhi
    stepper = MotorStepper(motor, DT, (i0, start))
    w, integral, previous = start, 0.0, 0.0
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
    parser.add_argument('--out', help='replace or append the section in this file')
    args = parser.parse_args()
    load = os.getloadavg()
    began = time.process_time()
    found = list(rows(args.seeds))
    body = table(['motor', 'identified from', 'speed bandwidth Hz', 'acceleration gain used',
                  'feedforward voltage error % (worst)', 'tracking RMS rad/s (worst)',
                  'tracking peak rad/s (worst)', 'step overshoot % (worst)'], found)
    report = '\n'.join([
        '## Voltage-to-speed design: kA or the acceleration gain (issue 31)', '',
        f'`bench/bench_design_gain.py {" ".join(sys.argv[1:])}`; load average {load[0]:.2f} '
        f'{load[1]:.2f} {load[2]:.2f} (2 cores); {time.process_time() - began:.0f} s CPU.', '',
        'Medians over the seeds (worst in brackets); `truth`: the true kA and acceleration '
        'gain. Feedforward: RMS voltage error on a held-out noiseless multisine record; '
        'tracking: the designed 1 ms PI plus the feedforward on a smooth 0/40/-40/0 rad/s '
        'profile; step: 20 -> 40 rad/s with the static feedforward.', '', body, '',
        summary(found), ''])
    if args.out:
        write_section(args.out, report)
    print(report)


def write_section(path, section):
    """Replace this benchmark's section of ``path`` (its last one), or append it."""
    text = ''
    if os.path.exists(path):
        with open(path, encoding='utf-8') as handle:
            text = handle.read()
    heading = section.split('\n', 1)[0]
    kept = text.split(heading, 1)[0].rstrip('\n')
    with open(path, 'w', encoding='utf-8') as handle:
        handle.write((kept + '\n\n' if kept else '') + section)


if __name__ == '__main__':
    main()
