"""
Size of the input-noise coefficient test (rule ``input-noise-null``, issue 29) on clean records.

The discovery loop judges a candidate's coefficients only after its held-out test passed, so
the clean rows of ``bench/bench_discovery.py`` measure this test on the few candidates that
got that far.  This script measures it on every clean record: the records of
``bench_discovery.py`` (random motors and excitations, 6 s at 1 kHz, the encoder's angle; mode
``mechanical-input-noise``: white noise of 0.5 % or 1 % of the current's spread on the logged
current that drives the model; ``mechanical``: the exact current), the loop's base fit on the
training part, then the refit with a load torque and the refit with a viscous asymmetry (true
value 0 for both), each refit's ``T^2`` against its draws
(:func:`dcmotor_id.identification.discovery.input_null.input_noise_statistic`).  Under a
calibrated null, ``T^2`` of one coefficient follows ``F(1, 200)``: a mean near 1, and it exceeds
its 5 %, 1 % and 0.135 % quantiles (3.89, 6.76, 10.6) at those rates.

Run ``python bench/bench_input_null_size.py [--records N] [--seed S] [--modes ...] [--out FILE]``
(the table is printed; its committed copy is in ``bench/discovery_results.md``, round 8).
"""

import argparse
import os
import sys
import time

import numpy as np
from scipy.stats import f as fisher

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.identification.discovery.input_null import DRAWS, input_noise_statistic
from dcmotor_id.identification.discovery.loop import base_fit
from dcmotor_id.identification.discovery.refitting import try_candidate
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.discovery.structure import Candidate, Structure
from dcmotor_id.identification.effects import VOCABULARY
from dcmotor_id.identification.error_model.criterion import resolve_criterion
from dcmotor_id.simulation import simulate_motor_effects

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_discovery import (DT, measured, mechanical_shaft,  # noqa: E402,I100
                             random_excitation, random_motor)

#: The candidates refitted on every clean record (one coefficient each).
EFFECTS = ('load_torque', 'viscous_asymmetry')
#: Sizes reported (one-sided, of F(1, DRAWS)); the last is the rule's.
SIZES = (0.05, 0.01, 0.00135)


def clean_record(mode, noise, rng):
    """Return a clean record of ``mode`` as bench_discovery logs it, and the torque constant."""
    motor = random_motor(rng)
    kind, amplitude, t, voltage = random_excitation(rng)
    current, speed, angle = simulate_motor_effects(motor, voltage, DT, [])
    speed, angle = mechanical_shaft(motor, current, [])
    records, torque_constant = measured(mode, t, current, voltage, speed, angle, noise, rng,
                                        motor)
    return records, torque_constant, f'{kind} {amplitude:.0f} V'


def statistics(records, torque_constant):
    """Return ``{effect: T^2}`` of the refits with each effect of :data:`EFFECTS` (or None)."""
    loop = LoopState(records, torque_constant=torque_constant,
                     criterion=resolve_criterion(records, 'auto'))
    loop, base = base_fit(loop, None, Structure())
    out = {}
    for cls in [cls for cls in VOCABULARY if cls.name in EFFECTS]:
        inner = next(iter(cls.inner_grid(base.records, base.values, torque_constant)))
        fitted = try_candidate(loop, base, cls, inner, {})
        found = None if fitted is None else input_noise_statistic(
            loop, Candidate(cls, inner, {}, 0.0, fit=fitted))
        out[cls.name] = None if found is None else found[0]
    return out


def summary(mode, values):
    """Return the table row of a mode: records, mean T^2 and the rates beyond each quantile."""
    values = np.array(values, dtype=float)
    cells = []
    for size in SIZES:
        limit = float(fisher.ppf(1.0 - size, 1, DRAWS))
        cells.append(f'{int(np.sum(values >= limit))} ({100 * np.mean(values >= limit):.1f} %)')
    return (f'| {mode} | {values.shape[0]} | {np.mean(values):.2f} | {np.median(values):.2f} | '
            + ' | '.join(cells) + ' |')


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--records', type=int, default=20, help='clean records per mode')
    parser.add_argument('--seed', type=int, default=29)
    parser.add_argument('--modes', nargs='+', default=['mechanical-input-noise', 'mechanical'],
                        choices=['mechanical-input-noise', 'mechanical'])
    parser.add_argument('--out', help='write the table here too (its committed copy: '
                        'bench/discovery_results.md, round 8)')
    args = parser.parse_args(argv)
    started = time.perf_counter()
    rows, failed = [], 0
    for mode in args.modes:
        rng = np.random.default_rng(args.seed)
        values = []
        for index in range(args.records):
            records, torque_constant, label = clean_record(mode, (0.005, 0.01)[index % 2], rng)
            try:
                found = statistics(records, torque_constant)
            except DcMotorIdError:
                failed += 1
                continue
            print(mode, index, label, found, flush=True)
            values.extend(value for value in found.values() if value is not None)
        rows.append(summary(mode, values))
    lines = [
        '# Size of the input-noise coefficient test (rule input-noise-null)', '',
        f'Generated by `python bench/bench_input_null_size.py --records {args.records} --seed '
        f'{args.seed} --modes {" ".join(args.modes)}` in {time.perf_counter() - started:.0f} s; '
        f'{failed} record(s) whose base model had no fit left out.  Every clean record refitted '
        f'with each of {", ".join(EFFECTS)} (true value 0); T^2 of the effect\'s coefficient '
        f'against its {DRAWS} draws of the noise.  Under a calibrated null T^2 follows '
        f'F(1, {DRAWS}): mean about 1, median 0.45, and each column at its size.', '',
        '| mode | refits | mean T^2 | median T^2 | '
        + ' | '.join(f'beyond the {100 * size:g} % quantile' for size in SIZES) + ' |',
        '|---|---|---|---|' + '---|' * len(SIZES)] + rows
    print('\n'.join(lines))
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as stream:
            stream.write('\n'.join(lines) + '\n')
        print(f'wrote {args.out}')


if __name__ == '__main__':
    main()
