"""
Records with a position and no speed: the position criterion against the speed criterion.

1. **Quantised encoder** (``--counts`` counts per revolution, no speed column): motor 2 of
   Table 1, the ``paper`` excitation (8 s), 1 % white noise on the current, the position
   rounded to the encoder's step, at 1, 2 and 4 kHz and ``--seeds`` noise draws.  Each record
   is identified without discovery with ``--criterion speed`` (the speed derived from the
   position by the differentiating filter, the path before the position criterion) and with
   the default (``auto``: ``position``); the table gives the median and the largest absolute
   error per parameter.
2. **Cramer-Rao bound at 1 % position noise**: the paper's two training records of both
   motors (4 s each at dT = 1e-4 s), white noise of 1 % of each signal's standard deviation on
   the current and on the position, ``--runs`` draws; the refined method with the position
   criterion (speed derived from the noisy position, then not compared) against the bound of
   the same observation model
   (:func:`dcmotor_id.identification.estimators.fisher.cramer_rao_bound` with
   ``criterion='position'``, initial states as nuisance parameters).

Usage: ``.venv/bin/python bench/bench_position.py [--seeds N] [--runs N]``
(its markdown on stdout: ``bench/position_results.md``)
"""

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from dcmotor_id.core.model import PAPER_MOTORS  # noqa: E402
from dcmotor_id.core.records import Record  # noqa: E402
from dcmotor_id.identification.error_model.criterion import integrate_speed  # noqa: E402
from dcmotor_id.identification.estimators.fisher import cramer_rao_bound  # noqa: E402
from dcmotor_id.identification.estimators.refined import RefinedEstimator  # noqa: E402
from dcmotor_id.identification.identify import identify, prepare_records  # noqa: E402
from dcmotor_id.simulation import simulate_motor  # noqa: E402
from dcmotor_id.simulation.excitation import make_excitation  # noqa: E402
from dcmotor_id.simulation.scenarios import PAPER_SAWTOOTH, PAPER_SINE  # noqa: E402

NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
RATES_HZ = (1000, 2000, 4000)
#: The issue's target: the position criterion's spread at most this multiple of the bound.
TARGET_CRB_RATIO = 1.5


def encoder_record(rate_hz, seed, counts):
    """Motor 2, ``paper`` excitation, 1 % current noise, a quantised encoder, no speed."""
    dt = 1.0 / rate_hz
    motor = PAPER_MOTORS['paper2']
    t, voltage = make_excitation('paper', 8.0, dt)
    current, speed = simulate_motor(motor, voltage, dt, (0.0, 0.0))
    rng = np.random.default_rng(seed)
    lsb = 2.0 * np.pi / counts
    position = np.round(integrate_speed(speed, dt, rng.uniform(0, 2 * np.pi)) / lsb) * lsb
    current = current + 0.01 * np.std(current) * rng.standard_normal(t.shape[0])
    return Record(t, current, voltage, None, position, source=f'encoder {rate_hz} Hz')


def encoder_section(seeds, counts):
    """Return the markdown of part 1."""
    motor = PAPER_MOTORS['paper2']
    lines = ['## 1. Quantised encoder, no speed column: speed vs position criterion', '',
             f'Motor 2, `paper` excitation 8 s, {counts} counts/rev, 1 % current noise, '
             f'{seeds} seeds; `identify(..., discover=False)`. |error| in %, median (largest).',
             '', '| rate | criterion | ' + ' | '.join(NAMES) + ' | time per fit |',
             '|---|---|' + '---|' * len(NAMES) + '---|']
    for rate in RATES_HZ:
        for criterion in ('speed', 'auto'):
            errors, seconds, used = [], [], set()
            for seed in range(seeds):
                records = prepare_records([encoder_record(rate, seed, counts)])
                start = time.process_time()
                result = identify(records, discover=False, criterion=criterion)
                seconds.append(time.process_time() - start)
                used.add(result.criterion)
                errors.append([abs(result.parameters[name] / getattr(motor, name) - 1) * 100
                               for name in NAMES])
            table = np.array(errors)
            cells = [f'{np.median(table[:, k]):.3f} ({np.max(table[:, k]):.3f})'
                     for k in range(len(NAMES))]
            lines.append(f'| {rate} Hz | {criterion} ({", ".join(sorted(used))}) | '
                         + ' | '.join(cells) + f' | {np.median(seconds):.2f} s |')
    return lines


def paper_position_records(motor, level, rng):
    """Simulate the paper's two records with ``level`` noise on current and position."""
    records, noise = [], {'current': [], 'position': []}
    for spec in (PAPER_SINE, PAPER_SAWTOOTH):
        t, voltage = make_excitation(spec['kind'], 4.0, 1e-4, amplitude_v=spec['amplitude_v'],
                                     frequency_hz=spec['frequency_hz'])
        current, speed = simulate_motor(motor, voltage, 1e-4)
        position = integrate_speed(speed, 1e-4, 0.0)
        sigma_i, sigma_p = level * np.std(current), level * np.std(position)
        noise['current'].append(sigma_i)
        noise['position'].append(sigma_p)
        records.append(Record(t, current + sigma_i * rng.standard_normal(t.shape[0]), voltage,
                              None, position + sigma_p * rng.standard_normal(t.shape[0]),
                              source=spec['kind']))
    return records, noise


def crlb_section(runs, level=0.01):
    """Return the markdown of part 2."""
    lines = ['## 2. Spread against the Cramer-Rao bound, 1 % noise on current and position', '',
             f'{runs} runs per motor; RMS error over the runs / the bound (target <= '
             f'{TARGET_CRB_RATIO}).', '',
             '| motor | ' + ' | '.join(NAMES) + ' | fits failed | time per fit |',
             '|---|' + '---|' * len(NAMES) + '---|---|']
    for label in ('paper1', 'paper2'):
        motor = PAPER_MOTORS[label]
        truth = motor.as_dict(derived=False)
        errors, failed, seconds = [], 0, []
        bound = None
        for run in range(runs):
            rng = np.random.default_rng(1000 + run)
            raw, noise = paper_position_records(motor, level, rng)
            if bound is None:
                bound = cramer_rao_bound(raw, motor, noise, criterion='position')
            records = prepare_records(raw)
            start = time.process_time()
            try:
                estimate = RefinedEstimator(criterion='position').fit(records)
            except Exception:  # noqa: BLE001 - a failed fit is counted, not fatal
                failed += 1
                continue
            seconds.append(time.process_time() - start)
            errors.append([estimate.parameters[name] - truth[name] for name in NAMES])
        table = np.array(errors)
        rms = np.sqrt(np.mean(table ** 2, axis=0))
        assert bound is not None
        cells = [f'{rms[k] / bound[name]:.2f}' for k, name in enumerate(NAMES)]
        lines.append(f'| {label} | ' + ' | '.join(cells) + f' | {failed} | '
                     f'{np.median(seconds):.2f} s |')
    return lines


def main():
    """Run both parts and print the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--runs', type=int, default=30)
    parser.add_argument('--counts', type=int, default=4096)
    args = parser.parse_args()
    load = os.getloadavg()
    start = time.perf_counter()
    lines = ['# Position-only records: the position criterion (issue 20)', '',
             f'Command: `.venv/bin/python bench/bench_position.py --seeds {args.seeds} --runs '
             f'{args.runs}` (load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f} at the '
             'start; times are CPU seconds of the fit). See the docstring for the set-up.', '']
    lines += encoder_section(args.seeds, args.counts) + ['']
    lines += crlb_section(args.runs) + ['']
    lines.append(f'Total {time.perf_counter() - start:.0f} s.')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
