"""
Accuracy of the identifier's online (recursive least-squares) estimate against sensor noise.

The online estimator (:mod:`dcmotor_id.online`) regresses on measured current and speed, so
sensor noise biases it like the paper's neurons; this shows by how much.  Motor 2 of the
paper, the ``paper`` excitation (sine then sawtooth) repeated over 30 s at 1 kHz, white noise
of ``level * std(signal)`` on current and speed, five noise draws per level; the last row uses
sim_motor's default absolute noise (0.01 A, 0.02 rad/s), which is what ``make demo`` sees.

Usage: ``.venv/bin/python bench/bench_online.py``
"""

from common import command_line, environment, markdown_table, pct, PHYSICAL_NAMES
import numpy as np

from dcmotor_id.excitation import add_sensor_noise, make_excitation
from dcmotor_id.model import PAPER_MOTORS, relative_errors_pct
from dcmotor_id.online import OnlineEstimator
from dcmotor_id.simulation import simulate_motor

SAMPLE_PERIOD_S = 1e-3
DURATION_S = 30.0
RUNS = 5


def main():
    """Print the worst relative error of the online estimate per noise level."""
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('paper', DURATION_S, SAMPLE_PERIOD_S)
    current, speed = simulate_motor(params, voltage, SAMPLE_PERIOD_S)
    cases = [(f'{level * 100:g} % of std', level, None) for level in (0.0, 0.001, 0.01)]
    cases.append(('sim_motor default (0.01 A, 0.02 rad/s)', None, (0.01, 0.02)))
    rows = []
    for label, level, absolute in cases:
        worst = dict.fromkeys(PHYSICAL_NAMES, 0.0)
        for seed in range(RUNS):
            rng = np.random.default_rng(seed)
            if absolute is None:
                measured_i = add_sensor_noise(current, level, rng)
                measured_w = add_sensor_noise(speed, level, rng)
            else:
                measured_i = current + rng.normal(0.0, absolute[0], current.shape)
                measured_w = speed + rng.normal(0.0, absolute[1], speed.shape)
            estimator = OnlineEstimator(SAMPLE_PERIOD_S)
            estimator.update(voltage, measured_i, measured_w)
            errors = relative_errors_pct(estimator.estimate().parameters, params.as_dict(),
                                         PHYSICAL_NAMES)
            worst = {name: max(worst[name], errors[name]) for name in PHYSICAL_NAMES}
        rows.append([label] + [pct(worst[name]) for name in PHYSICAL_NAMES])
    print('## Online estimate against sensor noise\n')
    print(f'Command: `{command_line()}`  \nMachine: {environment()}\n')
    print(f'Motor 2, `paper` excitation over {DURATION_S:g} s at {1 / SAMPLE_PERIOD_S:g} Hz; '
          f'largest relative error [%] over {RUNS} noise draws.\n')
    print(markdown_table(['noise'] + list(PHYSICAL_NAMES), rows))


if __name__ == '__main__':
    main()
