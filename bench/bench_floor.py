"""
The regression floor (issue 29): default ``identify`` against the model-free regression.

For each laboratory scenario of :mod:`dcmotor_id.simulation.lab_scenarios` named below, the
default identification and the regression (:func:`dcmotor_id.identification.pipeline.floor
.regression_floor`) on the same records, in the same run: the error of every base parameter
against the truth, whether the answer is the regression's, and the run time.

Run from the repository root::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_floor.py [--out bench/floor_results.md]
"""

import argparse
import time
import warnings

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline.floor import regression_floor
from dcmotor_id.identification.pipeline.segments import split_tests
from dcmotor_id.simulation.lab_scenarios import SCENARIOS, sysid_routine

NAMES = ('small_motor_encoder_500hz', 'amplifier_ramp_step', 'hobby_servo_pwm_angle',
         'sysid_routine', 'voltage_step_from_rest', 'hobby_motor_encoder', 'small_motor_low_rate',
         'coloured_disturbance')
PARAMETERS = ('Ra', 'CPhi', 'J', 'b', 'Mc')


def _errors(values, truth):
    """Per-parameter error in percent of the truth, as table cells."""
    return [f'{100.0 * (values[name] / getattr(truth, name) - 1.0):+.1f}'
            if name in values else '-' for name in PARAMETERS]


def rows():
    """Yield one table row per scenario and estimator."""
    for name in NAMES:
        scenario = sysid_routine()[0] if name == 'sysid_routine' else SCENARIOS[name]()
        records = prepare_records(scenario.records)
        start = time.perf_counter()
        # The regression on the tests the identification fits (a SysId routine is split).
        floor = regression_floor(list(split_tests(records).records), scenario.torque_constant)
        floor_s = time.perf_counter() - start
        start = time.perf_counter()
        try:
            result = identify(records, torque_constant=scenario.torque_constant)
            cells = _errors(result.parameters, scenario.truth)
            used = 'regression' if any('regression' in text and ('failed' in text or 'worse'
                                                                 in text)
                                       for text in result.warnings) else 'output error'
            used += ''.join(f', {len(result.sources)} tests' for text in result.warnings
                            if 'separate records' in text)
            used += ''.join(', ramp cut' for text in result.warnings
                            if 'did not reach the motor' in text)
        except DcMotorIdError as error:
            cells, used = ['-'] * len(PARAMETERS), f'refused: {str(error)[:60]}'
        identify_s = time.perf_counter() - start
        yield [name, 'identify (default)', *cells, used, f'{identify_s:.2f}']
        floor_cells = _errors(floor.parameters, scenario.truth) if floor else ['-'] * 5
        yield [name, 'regression', *floor_cells,
               'static electrical' if floor and floor.static_electrical else '',
               f'{floor_s:.2f}']


def main(argv=None):
    """Write the table (markdown) to ``--out`` and print it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--out', default='bench/floor_results.md')
    args = parser.parse_args(argv)
    header = ['scenario', 'estimator', *[f'{name} err %' for name in PARAMETERS], 'answer',
              'time s']
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        lines += ['| ' + ' | '.join(row) + ' |' for row in rows()]
    text = ('# Regression floor: default identify vs the model-free regression\n\n'
            'Command: `PYTHONPATH=$PWD .venv/bin/python bench/bench_floor.py`\n\n'
            + '\n'.join(lines) + '\n')
    with open(args.out, 'w', encoding='utf-8') as handle:
        handle.write(text)
    print(text)


if __name__ == '__main__':
    main()
