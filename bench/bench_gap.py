"""
Size and power of the gap check (issue 29): a parameter the record does not decide.

:mod:`dcmotor_id.identification.checks.gap` names a parameter when the output-error fit and
the model-free regression predict the held-out part equally well (Diebold-Mariano, 1 %) and
the regression on the record lies farther from the regression on the fit's own simulation
(with the sensor's noise) than the stated standard errors allow (Bonferroni, 1 %).  This
script counts how often it does on voltage-speed SysId routines (5 ms samples, ramps and
steps both ways, ``--noise`` of the speed's spread, ``--seeds`` draws each):

* **Size**: a first-order motor (one time scale, kA/kV = 0.5 s): every warning is a false
  alarm (the fit is right: kA within a few per cent).
* **Power**: a speed that is ``share`` of a 30 ms response and the rest of a 0.5 s one (the
  two time scales of the base-bot drivetrain log): the warning naming kA is the answer.

The full mode's size is counted by ``bench/bench_random_motors.py`` and
``bench/bench_random_classes.py`` (column *within, undecided*), the real recordings' by
``bench/bench_real.py``.  Run from the repository root (a few minutes)::

    .venv/bin/python bench/bench_gap.py --seeds 10 --out bench/gap_results.md
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.gap import UNDECIDED
from dcmotor_id.identification.estimators.voltage_speed import simulate_speed
from dcmotor_id.identification.identify import identify, prepare_records

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import markdown_table, write_report  # noqa: E402,I100  (bench/common.py)

#: Sample period [s] of the SysId routine (WPILib's 5 ms).
DT = 5e-3
#: The motor's friction and speed constants [V], [V s/rad].
MOTOR = {'kS': 0.7, 'kV': 0.1}
#: kA of the fast and the slow response [V s^2/rad] (30 ms and 0.5 s with kV).
FAST_KA, SLOW_KA = 0.003, 0.05
#: Shares of the fast response: 0 is one time scale (the size).
SHARES = (0.0, 0.3, 0.5)


def sysid_voltage() -> np.ndarray:
    """Return a SysId routine: quasi-static ramps both ways, then dynamic steps both ways [V]."""
    t = np.arange(0.0, 8.0, DT)
    rest = np.zeros(200)
    return np.concatenate([0.6 * t, rest, -0.6 * t, rest, np.full(600, 8.0), rest,
                           np.full(600, -8.0), rest])


def two_time_scales(share: float, seed: int = 0, noise: float = 0.04) -> Record:
    """Return a record whose speed is ``share`` of a 30 ms response and the rest of a 0.5 s one."""
    volts = sysid_voltage()
    fast = simulate_speed({**MOTOR, 'kA': FAST_KA}, volts, DT, 0.0)
    slow = simulate_speed({**MOTOR, 'kA': SLOW_KA}, volts, DT, 0.0)
    speed = share * fast + (1.0 - share) * slow
    speed = speed + noise * np.std(speed) * np.random.default_rng(seed).standard_normal(
        speed.size)
    return Record(np.arange(volts.size) * DT, voltage=volts, speed=speed, source='two scales')


def named(result) -> list[str]:
    """Return the parameters a result says the record does not decide."""
    return [text.split(' (')[0].rsplit(' on ', 1)[-1] for text in result.warnings
            if text.startswith(UNDECIDED)]


def rows_of(seeds: int, noise: float) -> list[list[str]]:
    """Identify every share and seed; return one row per share."""
    rows = []
    for share in SHARES:
        said, errors = 0, []
        for seed in range(seeds):
            result = identify(prepare_records([two_time_scales(share, seed, noise)]))
            said += 'kA' in ', '.join(named(result))
            errors.append(100.0 * (result.parameters['kA'] / SLOW_KA - 1.0))
            print(f'share {share} seed {seed}: {named(result)}', file=sys.stderr, flush=True)
        rows.append([f'{share:g}', 'size (one time scale)' if share == 0 else 'power',
                     str(seeds), str(said), f'{np.median(errors):+.1f}'])
    return rows


def main(argv: list[str] | None = None) -> int:
    """Run the shares and seeds; write the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--noise', type=float, default=0.04)
    parser.add_argument('--out', default='bench/gap_results.md')
    args = parser.parse_args(argv)
    load, started = os.getloadavg(), time.time()
    rows = rows_of(args.seeds, args.noise)
    lines = ['# The gap check: size and power on voltage-speed SysId routines (issue 29)', '',
             f'Command: `bench/bench_gap.py --seeds {args.seeds} --noise {args.noise:g}`  ',
             f'Load average at the start: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}; run time '
             f'{time.time() - started:.0f} s', '',
             '*share*: of the 30 ms response in the speed (0: a first-order motor, kA/kV = '
             '0.5 s); *kA named*: records whose answer says the record does not decide kA '
             '(`checks/gap.py`); *kA error*: the median of the answer against the slow '
             "response's kA.", '']
    lines += markdown_table(['share', 'measures', 'records', 'kA named', 'kA error [%]'],
                            rows).splitlines()
    write_report(lines, args.out)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
