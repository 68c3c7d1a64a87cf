"""
Whether the raw current resolves the armature's time constant La/Ra: its likelihood profile.

The regression's electrical equation ``u = Ra i + La di/dt + CPhi w`` is an equation error on
zero-phase low-passed signals.  Where the model misses the samples at the steps (a status frame
that logs the voltage of a step before the current has answered it, a record that starts on a
step, which the filter's padding smears over tens of samples), the filtered ``di/dt`` is the
column most alike to that misfit: La absorbs it, with a small standard error and a large
likelihood gain, and an La/Ra of tens of samples is claimed for a current that settles within
one (a SysId log at 20 ms of a motor whose La/Ra is 3 ms: La 0.18 H, a hundred times the truth,
16 % stated).

The raw samples decide it without a filter.  With the voltage held over each sample and the
speed linear between samples, the electrical equation is exactly, with ``a = exp(-dt/tau)``,
``tau = La/Ra``::

    i[k+1] = a i[k] + (1 - a) u[k] / Ra - CPhi / Ra ((1 - a - g) w[k] + g w[k+1])
    g = 1 - (tau/dt) (1 - a)

(``g = 1`` at ``tau = 0``: the current settled at the end of the sample; a speed derived from
the position takes the position's mean speed over the sample instead).  For a fixed ``tau``
the current simulated from these (no measured current on the right-hand side, so its noise
does not bias ``a``) is linear in ``1/Ra``, ``CPhi/Ra`` and each stretch's initial current: the
sum of squares of the current's output error ``S(tau)`` is a linear least squares.  Its profile
over ``tau`` is a likelihood ratio ``n_eff ln(S(tau) / S_min)`` on the samples its residual is
worth (its correlation time,
:func:`~dcmotor_id.identification.checks.start.correlation_time`), compared with the
chi-square quantile (one degree of freedom) at :data:`LAG_LEVEL`.  A ``tau`` the ratio rejects
is contradicted by the current's samples, and the least ``tau`` rejected above every accepted
one bounds it.  The speed's noise, which a longer ``tau`` smooths, biases the profile towards
longer time constants: a claim is acted on only when rejected as too slow
(:attr:`LagProfile.claimed_too_slow`), and the bound errs on the long side.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.identification.checks.start import correlation_time
from dcmotor_id.signals.filters import period_mean_speed

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: Size of the likelihood-ratio test on the profile (as the regression's test of La's column).
LAG_LEVEL = 0.001
#: The chi-square quantile (one degree of freedom) at :data:`LAG_LEVEL`.
LAG_THRESHOLD = 10.828
#: The profile's time constants: 0 and the sample period times ``2 ** (j / 2)`` from this j.
GRID_FIRST = -8
#: The profile's longest time constant, as a share of the longest stretch's duration.
GRID_LAST_SHARE = 2.0
#: The profile's longest time constant, as a multiple of the larger of the claimed time
#: constant and the sample period (beyond it no point bears on the claim).
GRID_LAST_CLAIMED = 2.0
#: Largest exponent ``-j ln a`` within a block of :func:`_lagged` (``exp`` of it stays finite).
BLOCK_EXPONENT = 600.0
#: Fewest samples of a stretch between left-out samples that enters the profile.
MIN_STRETCH = 8
#: Most samples the profile takes, the first ones (each point of the profile is a pass over
#: them): the contradiction it looks for shows at every step, and a SysId routine of 1,000
#: samples rejects its claim by a ratio in the hundreds; a 60 s record at 1 kHz then costs a
#: third of its full profile.
MAX_SAMPLES = 20_000


@dataclass(frozen=True)
class LagProfile:
    """
    The current's profile over La/Ra (see the module): what the raw samples say of it.

    ``time_constants_s`` and ``ratios``: the points of the profile and their likelihood ratios
    against its least sum of squares; ``claimed_s``: the time constant tested for the caller
    (one of the points); ``effective_samples``: what the ratios count the samples as.
    """

    time_constants_s: tuple[float, ...]
    ratios: tuple[float, ...]
    claimed_s: float
    effective_samples: float

    def rejects(self, tau_s: float) -> bool:
        """Whether the samples reject this time constant (a point of the profile)."""
        index = self.time_constants_s.index(tau_s)
        return self.ratios[index] > LAG_THRESHOLD

    @property
    def claimed_too_slow(self) -> bool:
        """
        Whether the samples reject the claimed time constant as slower than they show.

        Rejected, and above every time constant they accept.  One-sided: the speed's noise,
        an input of the simulated current, is smoothed by a longer time constant, which
        biases the profile towards longer ones; a claim rejected as too slow all the same is
        contradicted, one rejected as too fast may be the bias's.
        """
        return self.rejects(self.claimed_s) and self.claimed_s >= self.upper_s

    @property
    def upper_s(self) -> float:
        """Return the least time constant rejected above every accepted one (inf: none)."""
        order = np.argsort(self.time_constants_s)
        taus = np.asarray(self.time_constants_s)[order]
        accepted = np.flatnonzero(np.asarray(self.ratios)[order] <= LAG_THRESHOLD)
        if accepted.shape[0] == 0 or accepted[-1] + 1 >= taus.shape[0]:
            return math.inf
        return float(taus[accepted[-1] + 1])


@dataclass(frozen=True)
class _Stretch:
    """One run of usable samples: the current, the voltage and the speed's two hold parts."""

    current: np.ndarray
    volts: np.ndarray
    speed_start: np.ndarray
    speed_end: np.ndarray


def _stretches(records: Sequence[Record], masks: Sequence[np.ndarray]) -> list[_Stretch]:
    """
    Cut the records into runs of finite, not left-out samples (each its initial current).

    At most :data:`MAX_SAMPLES` in all, the first ones.
    """
    out: list[_Stretch] = []
    for rec, mask in zip(records, masks):
        current = np.asarray(rec.current, dtype=float)
        volts = np.asarray(rec.voltage, dtype=float)
        if rec.speed_from_position:
            assert rec.position is not None  # a speed from the position has one
            mean = period_mean_speed(rec.position, rec.sample_period_s)
            start = end = np.append(mean, mean[-1])
        else:
            speed = np.asarray(rec.speed, dtype=float)
            start, end = speed, np.append(speed[1:], speed[-1])
        usable = ~np.asarray(mask, dtype=bool) & np.isfinite(current) & np.isfinite(volts) \
            & np.isfinite(start) & np.isfinite(end)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], usable.astype(int), [0]])))
        for first, stop in zip(edges[::2], edges[1::2]):
            taken = sum(stretch.current.shape[0] for stretch in out)
            stop = min(int(stop), int(first) + MAX_SAMPLES - taken)
            if stop - first >= MIN_STRETCH:
                part = slice(int(first), int(stop))
                out.append(_Stretch(current[part], volts[part], start[part], end[part]))
    return out


def _decay(a: float, n: int) -> np.ndarray:
    """Return ``a ** k`` for ``k < n``, zero where it is below 1e-18 (not computed there)."""
    out = np.zeros(n)
    if a <= 0.0:
        out[:1] = 1.0
        return out
    count = min(n, int(math.ceil(-41.5 / math.log(a))) + 1)
    out[:count] = np.exp(np.arange(count) * math.log(a))
    return out


def _lagged(signal: np.ndarray, a: float) -> np.ndarray:
    """
    Return ``y[k+1] = a y[k] + p[k]``, ``y[0] = 0``, of the signal ``p``, without a loop over it.

    In blocks over which ``a ** -j`` stays finite: within a block a cumulative sum of
    ``p[j] a ** -j`` times ``a ** j``, then each block's start carried from the one before.
    """
    n = signal.shape[0]
    out = np.zeros(n)
    if n < 2 or a <= 0.0:
        out[1:] = signal[:-1]
        return out
    rate = -math.log(a)
    length = max(1, min(n, int(BLOCK_EXPONENT / rate)))
    count = -(-n // length)
    padded = np.zeros(count * length)
    padded[:n] = signal
    steps = np.arange(length) * rate
    blocks = np.cumsum(padded.reshape(count, length) * np.exp(steps), axis=1) * np.exp(-steps)
    carried = np.exp(-(steps + rate))
    for index in range(1, count):
        blocks[index] += blocks[index - 1, -1] * carried
    out[1:] = blocks.reshape(-1)[:n - 1]
    return out


def _columns(stretches: Sequence[_Stretch], tau_over_dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Return the simulated current's columns (1/Ra, -CPhi/Ra, initial currents) and target."""
    a = math.exp(-1.0 / tau_over_dt) if tau_over_dt > 0 else 0.0
    g = 1.0 - tau_over_dt * (1.0 - a) if tau_over_dt > 0 else 1.0
    samples = sum(stretch.current.shape[0] for stretch in stretches)
    columns = np.zeros((samples, 2 + len(stretches)))
    row = 0
    for index, stretch in enumerate(stretches):
        n = stretch.current.shape[0]
        columns[row:row + n, 0] = (1.0 - a) * _lagged(stretch.volts, a)
        columns[row:row + n, 1] = _lagged((1.0 - a - g) * stretch.speed_start
                                          + g * stretch.speed_end, a)
        columns[row:row + n, 2 + index] = _decay(a, n)
        row += n
    return columns, np.concatenate([stretch.current for stretch in stretches])


def _residual(columns: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Return the least-squares residual (normal equations on unit-norm columns; zero dropped)."""
    norms = np.sqrt(np.einsum('ij,ij->j', columns, columns))
    used = norms > 0
    scaled = columns[:, used] / norms[used]
    solution = np.linalg.solve(scaled.T @ scaled, scaled.T @ target)
    return target - scaled @ solution


def lag_profile(records: Sequence[Record], masks: Sequence[np.ndarray],
                claimed_s: float) -> LagProfile | None:
    """
    Profile the current's output error over La/Ra (see the module), ``claimed_s`` among it.

    ``masks``: per record, the samples left out (a command that did not reach the motor).
    None when fewer than ten samples per coefficient are left, or the arithmetic fails.
    """
    stretches = _stretches(records, masks)
    dt = records[0].sample_period_s
    samples = sum(stretch.current.shape[0] for stretch in stretches)
    if not stretches or samples < 10 * (2 + len(stretches)) or not dt > 0:
        return None
    claimed = float(claimed_s) / dt if np.isfinite(claimed_s) and claimed_s > 0 else 0.0
    last = min(GRID_LAST_SHARE * max(stretch.current.shape[0] for stretch in stretches),
               GRID_LAST_CLAIMED * max(claimed, 1.0))
    grid = [0.0] + [2.0 ** (j / 2.0) for j in range(GRID_FIRST, 64) if 2.0 ** (j / 2.0) <= last]
    grid = sorted(set(grid + [claimed]))
    sums, best_residual = [], None
    with np.errstate(all='ignore'):
        for tau in grid:
            columns, target = _columns(stretches, tau)
            try:
                residual = _residual(columns, target)
            except np.linalg.LinAlgError:
                return None
            sums.append(float(np.einsum('i,i->', residual, residual)))
            if sums[-1] <= min(sums):
                best_residual = residual
    best = int(np.argmin(sums))
    if not np.all(np.isfinite(sums)) or not sums[best] > 0 or best_residual is None:
        return None
    effective = samples / correlation_time(best_residual)
    ratios = effective * np.log(np.asarray(sums) / sums[best])
    return LagProfile(tuple(tau * dt for tau in grid), tuple(map(float, ratios)),
                      claimed * dt, float(effective))
