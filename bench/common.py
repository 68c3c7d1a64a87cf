"""
Helpers shared by the benchmark scripts: the paper's data sets, the two methods, tables.

Every benchmark prints a markdown report to stdout (the tables committed in bench/, indexed by
bench/README.md); run them from the repository root, e.g.
``.venv/bin/python bench/bench_replication.py``.
"""

import datetime
import os
import platform
import sys
from unittest import mock

import numba
import numpy as np
import scipy

from dcmotor_id.core.model import relative_errors_pct
from dcmotor_id.identification.discovery.state import LoopState
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.simulation.scenarios import paper_records

#: Parameters in the order of the paper's Tables 2-3.
TABLE_NAMES = ('La', 'Ra', 'CPhi', 'Ka', 'Ta', 'J', 'b', 'Mc')
#: Physical parameters (no derived ones), in the package's order.
PHYSICAL_NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
#: Relative errors [%] the paper reports in Tables 2 (motor 1) and 3 (motor 2).
PAPER_REPORTED_PCT = {
    'paper1': {'La': 0.19, 'Ra': 0.44, 'CPhi': 0.14, 'Ka': 0.44, 'Ta': 0.31, 'J': 0.0005,
               'b': 0.74, 'Mc': 0.17},
    'paper2': {'La': 0.42, 'Ra': 0.39, 'CPhi': 0.15, 'Ka': 0.52, 'Ta': 0.40, 'J': 0.54,
               'b': 0.97, 'Mc': 0.27},
}
#: The paper's motors by the label used in the tables.
MOTOR_LABELS = {'paper1': 'motor 1 (36.7 kW)', 'paper2': 'motor 2 (2.3 kW)'}
#: Default length of each of the two training records [s] (the paper does not state it).
DURATION_S = 4.0


def make_records(params, noise, seed=0, sample_period_s=1e-4, duration_s=DURATION_S):
    """
    Simulate the paper's training records: 0.5 Hz 110 V sine (N1), 1 Hz 43 V sawtooth (N2).

    Noise is white, of standard deviation ``noise`` times each signal's standard deviation,
    on current and speed of each record.
    """
    return paper_records(params, noise, seed=seed, sample_period_s=sample_period_s,
                         duration_s=duration_s)


def fit_paper(records):
    """Fit the paper's method as the paper did: N1 on the sine record, N2 on the sawtooth."""
    return PaperEstimator([0], [1]).fit(records)


def fit_refined(records):
    """Fit the default method on both records together (shared parameters)."""
    return RefinedEstimator().fit(records)


def errors_pct(estimate, truth, names=TABLE_NAMES):
    """Relative errors of an estimate [%] (the paper's eq. 26), by name."""
    values = {name: estimate.parameters[name] for name in names}
    return relative_errors_pct(values, truth.as_dict(), list(names))


def signed_errors_pct(estimate, truth, names=PHYSICAL_NAMES):
    """Signed relative errors ``(estimate - truth) / truth`` [%] as an array in ``names`` order."""
    reference = truth.as_dict()
    return np.array([(estimate.parameters[name] - reference[name]) / reference[name] * 100.0
                     for name in names])


def pct(value, digits=3):
    """Format a percentage compactly (scientific below 1e-3)."""
    if value is None or not np.isfinite(value):
        return 'n/a'
    if value == 0:
        return '0'
    if abs(value) < 1e-3 or abs(value) >= 1e4:
        return f'{value:.1e}'
    return f'{value:.{digits}g}'


def markdown_table(header, rows):
    """Render a markdown table (first column left-aligned, the others right-aligned)."""
    lines = ['| ' + ' | '.join(header) + ' |',
             '|' + '|'.join([':---'] + ['---:'] * (len(header) - 1)) + '|']
    for row in rows:
        lines.append('| ' + ' | '.join(str(cell) for cell in row) + ' |')
    return '\n'.join(lines)


def write_report(lines, path):
    """Print the report's lines and write them to ``path`` (None: print only)."""
    text = '\n'.join(lines) + '\n'
    print(text)
    if path:
        with open(path, 'w', encoding='utf-8') as stream:
            stream.write(text)


def environment():
    """One line naming the machine and the library versions the figures come from."""
    return (f'{datetime.date.today().isoformat()}, {platform.machine()} with '
            f'{os.cpu_count()} CPUs, Python {platform.python_version()}, numpy '
            f'{np.__version__}, scipy {scipy.__version__}, numba {numba.__version__}')


def command_line():
    """Return the command that produced the output, for the report."""
    return ' '.join(['.venv/bin/python'] + [os.path.relpath(sys.argv[0])] + sys.argv[1:])


def judged_by(rule):
    """
    Judge the discovery loops that ``identify`` runs in this scope by ``rule``.

    The product has no switch for this (every identification uses the default rule); the
    benchmark compares the rules on the same records, so it gives each loop the rule here.
    """
    original = LoopState.__init__

    def init(self, *args, **kwargs):
        kwargs.setdefault('acceptance', rule)
        original(self, *args, **kwargs)
    return mock.patch.object(LoopState, '__init__', init)
