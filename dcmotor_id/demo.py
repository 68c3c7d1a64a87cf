"""``make demo``: the paper's motor 2 identified by the paper's method and the default one."""

import time

import numpy as np

from dcmotor_id.estimators.paper import PaperEstimator
from dcmotor_id.excitation import add_sensor_noise, make_excitation, PAPER_SAWTOOTH, PAPER_SINE
from dcmotor_id.identify import identify
from dcmotor_id.model import DERIVED_NAMES, PAPER_MOTORS, PARAMETER_NAMES, UNITS
from dcmotor_id.records import Record
from dcmotor_id.simulation import simulate_motor

SAMPLE_PERIOD_S = 1e-4
DURATION_S = 4.0


def paper_records(params, noise, seed=0, sample_period_s=SAMPLE_PERIOD_S,
                  duration_s=DURATION_S):
    """Simulate the paper's two training sets (sine for N1, sawtooth for N2) with noise."""
    rng = np.random.default_rng(seed)
    records = []
    for spec in (PAPER_SINE, PAPER_SAWTOOTH):
        t, voltage = make_excitation(spec['kind'], duration_s, sample_period_s,
                                     amplitude_v=spec['amplitude_v'],
                                     frequency_hz=spec['frequency_hz'])
        current, speed = simulate_motor(params, voltage, sample_period_s)
        records.append(Record(t, add_sensor_noise(current, noise, rng), voltage,
                              add_sensor_noise(speed, noise, rng), source=spec['kind']))
    return records


def _table(truth, results):
    header = f"{'':<6}{'truth':>12}" + ''.join(
        f'{name:>14}{"err %":>9}' for name in results)
    lines = [header]
    for key in PARAMETER_NAMES + DERIVED_NAMES:
        row = f'{key:<6}{truth[key]:>12.5g}'
        for result in results.values():
            if result is None:
                row += f'{"failed":>14}{"":>9}'
                continue
            value = result['parameters'][key]
            row += f'{value:>14.5g}{abs(value - truth[key]) / truth[key] * 100:>9.3g}'
        lines.append(row + f'  {UNITS[key]}')
    return '\n'.join(lines)


def run_demo():
    """Print truth, paper method and default method side by side, without and with noise."""
    params = PAPER_MOTORS['paper2']
    truth = params.as_dict()
    print("Motor 2 of the paper's Table 1; training sets as in the paper (N1: 0.5 Hz 110 V sine, "
          f'N2: 1 Hz 43 V sawtooth), {DURATION_S:g} s each at dT = {SAMPLE_PERIOD_S:g} s.')
    for noise in (0.0, 0.01):
        records = paper_records(params, noise)
        results = {}
        for label, kwargs in (('paper', {'method': 'paper',
                                         'estimator': PaperEstimator([0], [1])}),
                              ('refined', {'method': 'refined'})):
            start = time.perf_counter()
            try:
                results[label] = identify(records, **kwargs)
            except Exception as error:  # noqa: BLE001  (the demo shows the failure)
                print(f'{label}: {error}')
                results[label] = None
            elapsed = time.perf_counter() - start
            print(f'  {label} method: {elapsed:.2f} s')
        print(f'\nsensor noise {noise * 100:g} % of each signal std on current and speed:')
        print(_table(truth, results))
        refined = results['refined']
        if refined:
            print('refined standard errors: ' + ', '.join(
                f"{key} {refined['stderr'][key] / refined['parameters'][key] * 100:.2g} %"
                for key in PARAMETER_NAMES))
        print()
    return 0
