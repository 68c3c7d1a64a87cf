"""
Benchmark: controller design from identified parameters, checked on the exact simulator.

Both motors of Table 1. Each is identified by the default method from the paper's two training
records (4 s each at 1 kHz, 1 % white noise on current and speed); the cascade is designed from the
identified values (``dcmotor_id.design.control``), then run on the TRUE motor with the exact hybrid
simulator (Coulomb friction included) and its closed-loop -3 dB bandwidths measured with a
multisine at a 40 rad/s bias (``measured_bandwidth_hz``). The margins are python-control's on the
sampled loops; their spread is over the ends and corners of the parameters' 95 % intervals, with
the identified standard errors and with 10 and 100 times them (100 x: a motor known to a few per
cent, e.g. from a datasheet).

Usage: ``.venv/bin/python bench/bench_design.py``
"""

import time

from common import command_line, environment, fit_refined, make_records, markdown_table
import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS, PARAMETER_NAMES
from dcmotor_id.design.control import design, measured_bandwidth_hz
from dcmotor_id.design.plant import DesignOptions, motor_from_result

#: (sample period [s], current bandwidth [Hz], speed bandwidth [Hz], phase margin [deg]).
CASES = ((1e-4, 200.0, 20.0, 60.0), (5e-4, 100.0, 10.0, 50.0), (1e-3, 50.0, 8.0, 45.0))


def identified(name):
    """Identify a paper motor from its training records at 1 kHz and 1 % noise."""
    estimate = fit_refined(make_records(PAPER_MOTORS[name], 0.01, seed=3,
                                        sample_period_s=1e-3))
    return {'parameters': {key: estimate.parameters[key] for key in PARAMETER_NAMES},
            'stderr': {key: estimate.stderr[key] for key in PARAMETER_NAMES},
            'mode': 'full'}


def _f(value, digits=4):
    return 'inf' if not np.isfinite(value) else f'{value:.{digits}g}'


def main():
    """Print the markdown report."""
    started = time.time()
    accuracy, robust, identified_rows = [], [], []
    for name in sorted(PAPER_MOTORS):
        truth = PAPER_MOTORS[name]
        result = identified(name)
        rel = {key: result['stderr'][key] / result['parameters'][key] * 100
               for key in PARAMETER_NAMES}
        identified_rows.append([name] + [f'{rel[key]:.2g}' for key in PARAMETER_NAMES])
        for dt, current, speed, margin in CASES:
            options = DesignOptions(current, speed, margin, dt)
            motor = motor_from_result(result)
            design_, _ = design(motor, options)
            true_design, _ = design(motor_from_result({'parameters': truth.as_dict()}),
                                    options)
            achieved = {loop: measured_bandwidth_hz(truth, design_, loop)['bandwidth_hz']
                        for loop in ('current', 'speed')}
            nominal = design_['nominal']
            accuracy.append([
                name, f'{dt:g}', f'{current:g} / {speed:g} / {margin:g}',
                f"{_f(achieved['current'])} ({(achieved['current'] / current - 1) * 100:+.1f} %)",
                f"{_f(achieved['speed'])} ({(achieved['speed'] / speed - 1) * 100:+.1f} %)",
                f"{_f(nominal['current']['phase_margin_deg'], 3)} / "
                f"{_f(nominal['current']['gain_margin_db'], 3)}",
                f"{_f(nominal['speed']['phase_margin_deg'], 3)} / "
                f"{_f(nominal['speed']['gain_margin_db'], 3)}",
                f"{(design_['speed_loop']['kp'] / true_design['speed_loop']['kp'] - 1) * 100:+.2f}"
                ' %'])
            for factor in (1.0, 10.0, 100.0):
                inflated = dict(result, stderr={key: value * factor for key, value in
                                                result['stderr'].items()})
                spread = design(motor_from_result(inflated), options)[0]['robustness']['range']
                robust.append([
                    name, f'{dt:g}', f'{factor:g} x',
                    *[f'{_f(spread[key][0], 3)} .. {_f(spread[key][1], 3)}' for key in (
                        'current.phase_margin_deg', 'current.bandwidth_hz',
                        'speed.phase_margin_deg', 'speed.gain_margin_db',
                        'speed.bandwidth_hz')]])
    print('# Controller design: requested vs achieved on the exact simulator\n')
    print(f'Command: `{command_line()}`  ')
    print(f'Machine: {environment()}, python-control {_control_version()}\n')
    print(__doc__.split('Usage')[0].strip().split('\n\n', 1)[1] + '\n')
    print('## Identified relative standard errors [%] (the 1 x intervals)\n')
    print(markdown_table(['motor', *PARAMETER_NAMES], identified_rows) + '\n')
    print('## Requested vs achieved (true motor, exact simulation)\n')
    print('Bandwidths [Hz] measured on the true motor; margins (phase [deg] / gain [dB]) of '
          'the sampled loops designed from the identified model; the last column is how far '
          'the speed gain kp is from the one designed from the true parameters.\n')
    print(markdown_table(['motor', 'dt [s]', 'asked: current / speed [Hz] / PM [deg]',
                          'current bandwidth', 'speed bandwidth', 'current PM / GM',
                          'speed PM / GM', 'speed kp vs true'], accuracy))
    print('\n## Spread across the 95 % intervals (ends and 32 corners)\n')
    print(markdown_table(['motor', 'dt [s]', 'stderr', 'current PM [deg]',
                          'current bandwidth [Hz]', 'speed PM [deg]', 'speed GM [dB]',
                          'speed bandwidth [Hz]'], robust))
    print(f'\nTotal time {time.time() - started:.0f} s.')


def _control_version():
    import control
    return control.__version__


if __name__ == '__main__':
    main()
