"""
The numba cache warm-up run by the set-up step, so that a user's first identification is fast.

The kernels are compiled with ``cache=True``: the first process that calls one compiles it
(6-10 s in all) and writes the machine code next to the source (``__pycache__``); later
processes load it.  ``python -m dcmotor_id.cli.warmup`` (the Makefile's install rule) runs a tiny
simulation and identification through the public entry points, on synthetic data, so that
every kernel is compiled for the argument types the CLI and the nodes use (the identify steps
compile the fit's sensitivity kernel, :func:`dcmotor_id.simulation.sensitivity.normal_kernel`,
and the fit on the position its position kernel).
It goes through the command line and the public classes only, not the kernels' names, so it
keeps covering them wherever they live.  Measured in ``bench/bench_cold_start.py`` and
``bench/bench_speed.py`` (cold start).

Its first step compiles the kernels of the identify path ahead of time
(:func:`dcmotor_id.simulation.compiled.build`: an extension module that loads without numba,
which saves every later process numba's import and set-up, ``bench/cold_start_results.md``);
without a C compiler it says so and the identify steps compile the JIT kernels into the cache
instead.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import os
import sys
import tempfile
import time
from typing import Sequence

#: Effects simulated into the warm-up record (the brush drop has its own kernel step).
SIMULATED_EFFECTS = ('load_torque:torque_Nm=0.2', 'brush_drop:drop_V=1.0')


def _drop_column(source: str, target: str, column: str) -> None:
    """Copy a CSV file without one column (a record for the mechanical-only mode)."""
    with open(source, newline='', encoding='utf-8') as stream:
        rows = list(csv.reader(stream))
    drop = rows[0].index(column)
    with open(target, 'w', newline='', encoding='utf-8') as stream:
        csv.writer(stream).writerows([cell for i, cell in enumerate(row) if i != drop]
                                     for row in rows)


def _with_position(source: str, target: str) -> None:
    """Copy a record as current and position (the speed's running integral; no voltage)."""
    import numpy as np

    table = np.genfromtxt(source, delimiter=',', names=True)
    t, speed = table['t'], table['speed']
    position = np.concatenate([[0.0], np.cumsum(0.5 * np.diff(t) * (speed[:-1] + speed[1:]))])
    np.savetxt(target, np.column_stack([t, table['current'], position]), delimiter=',',
               header='t,current,position', comments='')


def _online(path: str) -> None:
    """Feed a record to the online estimator (the identifier node's recursive kernel)."""
    import numpy as np

    from dcmotor_id.streaming.online import RlsEstimator
    table = np.genfromtxt(path, delimiter=',', names=True)
    estimator = RlsEstimator(float(table['t'][1] - table['t'][0]))
    estimator.update(table['voltage'], table['current'], table['speed'])
    estimator.estimate()


def _stepper() -> None:
    """Step the motor of the ``sim_motor`` node, with and without effects."""
    from dcmotor_id.core.model import PAPER_MOTORS
    from dcmotor_id.identification.effects import parse_effect
    from dcmotor_id.simulation import MotorStepper
    params = PAPER_MOTORS['paper2']
    effects = [parse_effect(text) for text in SIMULATED_EFFECTS]
    for stepper in (MotorStepper(params, 1e-3), MotorStepper(params, 1e-3, effects=effects)):
        for _ in range(3):
            stepper.step(10.0)


def _ahead_of_time() -> int:
    """Compile the identify path's kernels ahead of time (the JIT serves when this fails)."""
    from dcmotor_id.simulation.compiled import build
    try:
        build()
    except Exception as error:  # no C compiler, no numba.pycc, a read-only install
        print(f'warm-up: no ahead-of-time kernels ({type(error).__name__}: {error}); the numba '
              'JIT and its on-disk cache serve instead', file=sys.stderr)
    return 0


def warm_up(directory: str) -> list[tuple[str, float]]:
    """
    Compile (or load) every numba kernel once; return (step, seconds) pairs.

    Parameters
    ----------
    directory : str
        Scratch directory for the synthetic CSV files and the JSON result.

    """
    from dcmotor_id.cli.main import main as cli
    plain = os.path.join(directory, 'plain.csv')
    effects = os.path.join(directory, 'effects.csv')
    mechanical = os.path.join(directory, 'mechanical.csv')
    position = os.path.join(directory, 'position.csv')
    simulate = ['simulate', '--duration', '1', '--sample-period', '1e-3', '--noise', '0.005']
    effect_args = [arg for text in SIMULATED_EFFECTS for arg in ('--effect', text)]

    def mechanical_mode() -> int:
        _drop_column(plain, mechanical, 'voltage')
        return cli(['identify', mechanical, '--no-discover', '--torque-constant', '0.7'])

    def on_the_position() -> int:
        _with_position(plain, position)
        return cli(['identify', position, '--no-discover', '--torque-constant', '0.7',
                    '--criterion', 'position'])

    steps = [
        ('ahead-of-time kernels', _ahead_of_time),
        ('simulate', lambda: cli(simulate + ['--out', plain])),
        ('simulate with effects', lambda: cli(simulate + effect_args + ['--out', effects])),
        ('identify with discovery',
         lambda: cli(['identify', effects, '--extended-vocabulary',
                      '--json', os.path.join(directory, 'result.json')])),
        ('identify, mechanical mode', mechanical_mode),
        ('identify on the position', on_the_position),
        ('identify, paper method', lambda: cli(['identify', plain, '--method', 'paper',
                                                '--no-discover'])),
        ('online estimator', lambda: _online(plain)),
        ('sim_motor stepper', _stepper),
    ]
    timings = []
    for name, step in steps:
        start = time.perf_counter()
        code = step()
        if code:
            raise RuntimeError(f'warm-up step {name!r} failed with exit code {code}')
        timings.append((name, time.perf_counter() - start))
    return timings


def main(argv: Sequence[str] | None = None) -> int:
    """Run the warm-up; print one line per step unless ``--quiet``."""
    parser = argparse.ArgumentParser(prog='python -m dcmotor_id.cli.warmup',
                                     description='compile and cache the numba kernels')
    parser.add_argument('--quiet', action='store_true', help='print nothing on success')
    args = parser.parse_args(argv)
    if not args.quiet:
        print('warm-up: compiling the numba kernels into their cache and the ahead-of-time '
              'module (once; about half a minute) ...', flush=True)
    # The CLI's own tables are not the point here.
    with tempfile.TemporaryDirectory(prefix='dcmotor-id-warmup-') as directory, \
            open(os.devnull, 'w', encoding='utf-8') as devnull, \
            contextlib.redirect_stdout(devnull):
        timings = warm_up(directory)
    if not args.quiet:
        for name, seconds in timings:
            print(f'warm-up: {name:<28}{seconds:6.2f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
