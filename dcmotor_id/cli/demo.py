"""The offline demo (``make demo``): the paper's motor 2 identified by both methods."""

from __future__ import annotations

import time
from typing import Any

from dcmotor_id.core.model import DERIVED_NAMES, PAPER_MOTORS, PARAMETER_NAMES, UNITS
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.identification.identify import identify
from dcmotor_id.simulation.scenarios import DURATION_S, paper_records, SAMPLE_PERIOD_S


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


def run_demo() -> int:
    """Print truth, paper method and default method side by side, without and with noise."""
    params = PAPER_MOTORS['paper2']
    truth = params.as_dict()
    print("Motor 2 of the paper's Table 1; training sets as in the paper (N1: 0.5 Hz 110 V sine, "
          f'N2: 1 Hz 43 V sawtooth), {DURATION_S:g} s each at dT = {SAMPLE_PERIOD_S:g} s.')
    for noise in (0.0, 0.01):
        records = paper_records(params, noise)
        results: dict[str, dict[str, Any] | None] = {}
        for label, kwargs in (('paper', {'method': 'paper',
                                         'estimator': PaperEstimator([0], [1])}),
                              ('refined', {'method': 'refined'})):
            start = time.perf_counter()
            try:
                results[label] = identify(records, **kwargs).as_dict()
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
