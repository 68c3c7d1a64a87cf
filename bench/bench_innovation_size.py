"""
Size of the held-out innovation t tests on an errors-in-variables position residual (synthetic).

The residual of a mechanical model driven by a noisy logged current: the doubly integrated
input noise (a speed error that decays in 30 samples, integrated) plus an encoder's rounding
of a moving shaft.  A candidate that is no effect, a drift absorber (a ``t^2`` shape, as a
constant torque leaves in the position), is fitted on the training part (the first 70 %) by
least squares and extrapolated over the held-out part, as the loop's refits are.  For each
seed, each test says whether the candidate's held-out drop is significant at the loop's
one-sided :data:`~dcmotor_id.identification.discovery.judging.HELDOUT_ALPHA` (nominal: 0.135 %
of the seeds).  With ``--effect`` the residual holds a true ``t^2`` drift the base lacks (the
power).  Tests: ``ar`` (the rule innovation-t-alone's :func:`innovation_t`), ``arma``
(innovation-arma's :func:`innovation_arma_t`), and on the AR(1) innovations' drop a count of
effective samples by Geyer's initial positive sequence (``geyer``) and batch means over 10
blocks (``batch10``, Student t with 9 degrees of freedom).

Run ``PYTHONPATH=$PWD python bench/bench_innovation_size.py [--seeds 40]``.
"""

import argparse
import sys

import numpy as np
from scipy.stats import t as student

from dcmotor_id.core.records import Record
from dcmotor_id.identification.discovery import DiscoveryLoop
from dcmotor_id.identification.discovery import judging

N, STOP, DT = 6000, 4200, 1e-3
ENCODER_STEP = 2 * np.pi / 4096


class StandIn:
    """A stand-in for a Fit: one position record whose simulation misses by ``error``."""

    def __init__(self, error):
        """Keep the residual as the simulation of a zero measured position."""
        zeros = np.zeros(error.shape[0])
        self.records = [Record(np.arange(error.shape[0]) * DT, zeros, None, None, zeros,
                               source='synthetic')]
        self.simulated = [{'position': error}]
        self.stops = [STOP]

    def channel_residual(self, channel, part):
        """Model minus measurement on a part."""
        error = self.simulated[0][channel]
        return error[STOP:] if part == 'heldout' else error[:STOP]


def residual(seed):
    """Return the doubly integrated input noise plus the rounding of a moving shaft."""
    rng = np.random.default_rng(seed)
    decay = np.exp(-1.0 / 30.0)
    speed = np.zeros(N)
    kicks = rng.normal(0.0, 1.0, N)
    for k in range(1, N):
        speed[k] = decay * speed[k - 1] + kicks[k]
    angle = np.cumsum(np.sin(np.arange(N) * 2e-3) + 0.5) * 7e-3
    return np.cumsum(speed) * 2e-6 + angle - np.round(angle / ENCODER_STEP) * ENCODER_STEP


def geyer_time(x):
    """Integrated correlation time by Geyer's initial positive sequence (pairs of lags)."""
    x = x - np.mean(x)
    spectrum = np.fft.rfft(x, 2 * x.shape[0])
    acf = np.fft.irfft(spectrum * np.conj(spectrum))[:x.shape[0]]
    acf = acf / acf[0]
    total = -1.0
    for m in range(x.shape[0] // 2 - 1):
        pair = acf[2 * m] + acf[2 * m + 1]
        if pair <= 0:
            break
        total += 2.0 * pair
    return max(total, 1e-3)


def verdicts(loop, current, fitted):
    """Whether each test finds the candidate's held-out drop significant."""
    models = [judging.residual_arma(fit, 'position', False) for fit in (current, fitted)]
    before, after = judging._innovations(current, fitted, 0, 'position', models)
    drop, chance = before ** 2 - after ** 2, 2.0 * after * (after - before)
    out = {}
    for name, test in (('ar', judging.innovation_t), ('arma', judging.innovation_arma_t)):
        t, effective = test(loop, current, fitted)
        out[name] = t > judging.heldout_t_threshold(effective)
    effective = min(drop.shape[0] / geyer_time(chance), drop.shape[0])
    out['geyer'] = (np.mean(drop) / np.sqrt(np.var(chance) / effective)
                    > judging.heldout_t_threshold(effective))
    means = np.array([part.mean() for part in np.array_split(drop, 10)])
    out['batch10'] = (means.mean() / (means.std(ddof=1) / np.sqrt(10))
                      > student.ppf(1.0 - judging.HELDOUT_ALPHA, 9))
    return out


def main(argv=None):
    """Print the table: per residual kind, how many seeds each test finds significant."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--seeds', type=int, default=40)
    args = parser.parse_args(argv)
    loop = DiscoveryLoop([], 1.0, criterion='position', weights={'position': 1.0},
                         min_gain=0.05)
    shape = (np.arange(N) * DT) ** 2
    print('| residual | seeds | ' + ' | '.join(('ar', 'arma', 'geyer', 'batch10')) + ' |')
    print('|---|---|---|---|---|---|')
    for label, effect in (('no effect (size)', 0.0), ('a t^2 drift the base lacks', 3e-4)):
        counts = {}
        for seed in range(args.seeds):
            error = residual(seed) + effect * shape
            coefficient = (error[:STOP] @ shape[:STOP]) / (shape[:STOP] @ shape[:STOP])
            found = verdicts(loop, StandIn(error), StandIn(error - coefficient * shape))
            for name, value in found.items():
                counts[name] = counts.get(name, 0) + int(value)
        print(f'| {label} | {args.seeds} | ' + ' | '.join(
            f'{counts[name]} ({100 * counts[name] / args.seeds:.0f} %)'
            for name in ('ar', 'arma', 'geyer', 'batch10')) + ' |', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
