"""
One voltage step from rest on small fast motors: the class of issue 29's first recording.

Random small motors (Ra 1-10 Ohm, La/Ra 0.05-1 ms, CPhi 0.005-0.05 V s, mechanical time
constant 10-100 ms, Coulomb friction 1-5 % of the stall torque), each given one voltage step
from rest (6-24 V) and logged from t = 0 at 500 Hz to 2 kHz by the physical drive simulator
(:func:`~dcmotor_id.simulation.lab_scenarios.simulate_drive`: the fit's model is not the
data's), with the speed as a noisy tachometer, a 1024-4096-count encoder's speed, or only the
encoder's angle, and in a third of the cases an amplifier that ramps the applied voltage over
10-50 ms while the log reads the level from t = 0.  Each record is identified by the default
``identify`` (discovery on; the physical simulator has no effect of the vocabulary, so an
effect found is a false one) and, as the peer in the same run, by the model-free regression
(:func:`~dcmotor_id.identification.pipeline.floor.regression_floor`, where the record has a
speed).  Goals (issue 29): no failure where the regression answers; Ra and CPhi within 5 %,
J within 10 %.

Run from the repository root (the ``dcmotor_id`` on ``PYTHONPATH`` is measured)::

    .venv/bin/python bench/bench_step_from_rest.py --cases 24 --out bench/step_from_rest_results.md
"""

import argparse
import os
import sys
import time

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.records import Record
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline.floor import regression_floor
from dcmotor_id.simulation.lab_scenarios import encoder_speed, simulate_drive

# bench/common.py, beside this script
from common import environment, markdown_table, write_report  # noqa: I100

#: Goals of the class: largest relative error [%] of Ra and CPhi, of J.
GOAL_PCT = {'Ra': 5.0, 'CPhi': 5.0, 'J': 10.0}


def draw_case(rng: np.random.Generator, index: int) -> tuple[str, MotorParameters, Record]:
    """Draw one motor, step and logging; return its label, truth and record."""
    ra = float(rng.uniform(1.0, 10.0))
    cphi = float(np.exp(rng.uniform(np.log(0.005), np.log(0.05))))
    tau_m = float(rng.uniform(0.01, 0.1))
    level = float(rng.uniform(6.0, 24.0))
    stall = cphi * level / ra
    truth = MotorParameters(Ra=ra, La=ra * float(rng.uniform(5e-5, 1e-3)), CPhi=cphi,
                            J=tau_m * cphi ** 2 / ra, b=0.02 * cphi ** 2 / ra,
                            Mc=float(rng.uniform(0.01, 0.05)) * stall)
    dt = float(rng.choice([5e-4, 1e-3, 2e-3]))
    n = int(round(max(12 * tau_m, 0.5) / dt))
    t = np.arange(n) * dt
    ramp_s = float(rng.uniform(0.01, 0.05)) if index % 3 == 2 else 0.0
    applied = level * (np.clip((t + dt) / ramp_s, 0.0, 1.0) if ramp_s else np.ones(n))
    out = simulate_drive(truth, applied, dt)
    current = out['current'] + rng.normal(0.0, 0.005 * level / ra, n)  # 0.5 % of stall
    sensor = ('tachometer', 'encoder speed', 'encoder angle')[int(rng.integers(0, 3))]
    counts = int(rng.choice([1024, 2048, 4096]))
    kwargs = {'current': current, 'voltage': np.full(n, level)}
    if sensor == 'tachometer':
        kwargs['speed'] = out['speed'] + rng.normal(0.0, 0.005 * np.max(out['speed']), n)
    elif sensor == 'encoder speed':
        kwargs['speed'] = encoder_speed(out['angle'], dt, counts)
    else:
        kwargs['position'] = np.floor(out['angle'] * counts / (2 * np.pi)) * 2 * np.pi / counts
    label = (f'{index}: {level:.0f} V, {1 / dt:.0f} Hz, Ta {1e3 * truth.La / ra:.2f} ms, '
             f'tau_m {1e3 * tau_m:.0f} ms, {sensor}'
             + (f' ({counts})' if sensor != 'tachometer' else '')
             + (f', ramp {1e3 * ramp_s:.0f} ms' if ramp_s else ''))
    return label, truth, Record(t, source=f'case{index}', **kwargs)


def errors(values: dict, truth: MotorParameters) -> dict[str, float]:
    """Return the relative errors [%] of Ra, CPhi, J."""
    return {name: 100.0 * (values[name] / getattr(truth, name) - 1.0) for name in GOAL_PCT}


def run_case(label: str, truth: MotorParameters, record: Record) -> list[str]:
    """Identify one record and its regression; return the table row."""
    records = prepare_records([record])
    start = time.process_time()
    try:
        result = identify(records)
        tool, method = errors(result.parameters, truth), result.method
        effects = ', '.join(effect['name'] for effect in result.effects) or 'none'
    except DcMotorIdError as error:
        tool, method, effects = None, f'refused: {str(error)[:90]}', '-'
    cpu = time.process_time() - start
    floor = regression_floor(records) if record.speed is not None else None
    peer = errors(floor.parameters, truth) if floor is not None and floor.usable else None

    def show(found):
        return ' / '.join(f'{found[name]:+.1f}' for name in GOAL_PCT) if found else '-'
    met = tool is not None and all(abs(tool[name]) <= goal for name, goal in GOAL_PCT.items())
    return [label, method, show(tool), 'yes' if met else 'no', effects, show(peer),
            f'{cpu:.1f}']


def main(argv=None) -> int:
    """Run the cases; print (and write) the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--cases', type=int, default=24)
    parser.add_argument('--seed', type=int, default=29)
    parser.add_argument('--label', default='')
    parser.add_argument('--out')
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    load = os.getloadavg()
    rows = []
    for index in range(args.cases):
        rows.append(run_case(*draw_case(rng, index)))
        print(' | '.join(rows[-1]), file=sys.stderr, flush=True)
    met = sum(row[3] == 'yes' for row in rows)
    failed = sum(row[2] == '-' for row in rows)
    false = sum(row[4] not in ('none', '-') for row in rows)
    lines = [f'# One voltage step from rest on small fast motors {args.label}'.rstrip(), '',
             f'Command: `{" ".join(["bench/bench_step_from_rest.py"] + (argv or sys.argv[1:]))}`'
             '  ', environment() + '  ',
             f'Load average at the start {load[0]:.2f}, at the end {os.getloadavg()[0]:.2f}', '',
             f'Goal (Ra, CPhi within 5 %, J within 10 %) met on {met} of {len(rows)}; '
             f'no answer on {failed}; an effect found (none is in the data) on {false}.', '',
             markdown_table(['case', 'method (or refusal)', 'Ra / CPhi / J error [%]',
                             'goal met', 'effects found', 'regression Ra / CPhi / J [%]',
                             'CPU s'], rows)]
    write_report(lines, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
