"""
Excitation signals (armature voltage) and the sensor models: noise and quantisation.

Every generator returns the voltage at the sample instants ``t_k = k dt``; the simulator holds
each value over its sample (ZOH).  Units: V, s, Hz.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

#: Names accepted by :func:`make_excitation` (and the CLI's ``--excitation``).
EXCITATION_KINDS = ('sine', 'sawtooth', 'prbs', 'chirp', 'multisine', 'paper')

#: The paper's training excitations: N1 with a 0.5 Hz 110 V sine, N2 with a 1 Hz 43 V sawtooth.
PAPER_SINE: dict[str, Any] = {'kind': 'sine', 'amplitude_v': 110.0, 'frequency_hz': 0.5}
PAPER_SAWTOOTH: dict[str, Any] = {'kind': 'sawtooth', 'amplitude_v': 43.0, 'frequency_hz': 1.0}


def sample_times(duration_s: float, sample_period_s: float) -> np.ndarray:
    """Return ``t_k = k dt`` for ``0 <= t_k < duration_s``."""
    if sample_period_s <= 0 or duration_s <= 0:
        raise ValueError('duration and sample period must be positive')
    n_samples = int(round(duration_s / sample_period_s))
    return np.arange(n_samples) * sample_period_s


def make_excitation(kind: str, duration_s: float, sample_period_s: float,
                    amplitude_v: float | None = None, frequency_hz: float | None = None,
                    offset_v: float = 0.0, seed: int = 0,
                    max_frequency_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """
    Generate an armature-voltage excitation.

    Parameters
    ----------
    kind : str
        ``sine``, ``sawtooth`` (rising ramp from ``-A`` to ``+A`` each period), ``prbs``
        (maximum-length binary sequence, +/-A, clocked at ``frequency_hz``), ``chirp`` (linear
        sweep from ``frequency_hz`` to ``max_frequency_hz``), ``multisine`` (Schroeder-phased
        sum of 12 log-spaced sines between those two frequencies, peak ``A``) or ``paper``
        (the sine of the paper's N1 training set followed by the sawtooth of N2's).
    duration_s, sample_period_s : float
        Record length and sample period [s].
    amplitude_v : float, optional
        Amplitude [V]; default 110 V for ``sine`` and ``paper``, 43 V otherwise.
    frequency_hz : float, optional
        Fundamental / clock / start frequency [Hz].  Defaults: sine 0.5, sawtooth 1, prbs 20,
        chirp and multisine 0.2.
    offset_v : float
        Constant added to the signal [V].
    seed : int
        Seed of the random generator (PRBS start state).
    max_frequency_hz : float, optional
        Upper frequency of ``chirp`` and ``multisine`` [Hz]; default 20.

    Returns
    -------
    t, voltage : numpy.ndarray
        Sample times [s] and voltage [V].

    """
    t = sample_times(duration_s, sample_period_s)
    if kind not in EXCITATION_KINDS:
        raise ValueError(f'unknown excitation {kind!r}; choose one of '
                         f'{", ".join(EXCITATION_KINDS)}')
    default_amplitude = 110.0 if kind in ('sine', 'paper') else 43.0
    amplitude = default_amplitude if amplitude_v is None else float(amplitude_v)
    upper = 20.0 if max_frequency_hz is None else float(max_frequency_hz)
    return t, _shape(kind, t, sample_period_s, amplitude, frequency_hz, upper, seed) + offset_v


def _shape(kind: str, t: np.ndarray, sample_period_s: float, amplitude: float,
           frequency_hz: float | None, upper: float, seed: int) -> np.ndarray:
    """Return the voltage of a known ``kind`` at ``t`` (see :func:`make_excitation`)."""
    # Imported here: scipy.signal takes most of a second to import, and identifying (the
    # CLI's usual path) never generates an excitation.
    from scipy import signal
    if kind == 'sine':
        f = 0.5 if frequency_hz is None else frequency_hz
        return amplitude * np.sin(2 * np.pi * f * t)
    if kind == 'sawtooth':
        f = 1.0 if frequency_hz is None else frequency_hz
        return amplitude * signal.sawtooth(2 * np.pi * f * t)
    if kind == 'prbs':
        return _prbs(t, sample_period_s, amplitude,
                     20.0 if frequency_hz is None else frequency_hz, seed)
    if kind == 'chirp':
        f = 0.2 if frequency_hz is None else frequency_hz
        return amplitude * signal.chirp(t, f0=f, t1=max(t[-1], sample_period_s), f1=upper)
    if kind == 'multisine':
        f = 0.2 if frequency_hz is None else frequency_hz
        freqs = np.geomspace(f, upper, 12)
        phases = -np.pi * np.arange(1, 13) * np.arange(12) / 12.0
        u = np.sum(np.sin(2 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]), axis=0)
        return amplitude * u / np.max(np.abs(u))
    half = len(t) // 2  # paper
    return np.concatenate([
        amplitude * np.sin(2 * np.pi * 0.5 * t[:half]),
        43.0 * signal.sawtooth(2 * np.pi * 1.0 * t[:len(t) - half]),
    ])


def _prbs(t: np.ndarray, sample_period_s: float, amplitude: float, f: float,
          seed: int) -> np.ndarray:
    """Return a maximum-length binary sequence of +/-``amplitude`` clocked at ``f`` [Hz]."""
    from scipy import signal
    hold = max(1, int(round(1.0 / (f * sample_period_s))))
    n_bits = int(np.ceil(len(t) / hold)) + 1
    nbits = max(4, int(np.ceil(np.log2(n_bits + 1))))
    rng = np.random.default_rng(seed)
    state = rng.integers(0, 2, size=nbits)
    state[0] = 1
    sequence = signal.max_len_seq(nbits, state=state, length=n_bits)[0]
    return amplitude * (2.0 * np.repeat(sequence, hold)[:len(t)] - 1.0)


def add_sensor_noise(values: ArrayLike, relative: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Add white Gaussian noise of standard deviation ``relative * std(values)``."""
    values = np.asarray(values, dtype=float)
    if relative <= 0:
        return values.copy()
    return values + rng.normal(0.0, relative * np.std(values), size=values.shape)


def quantise(values: ArrayLike, step: float | None) -> np.ndarray:
    """Round to a multiple of ``step`` (an ADC or encoder resolution); ``step <= 0``: no-op."""
    values = np.asarray(values, dtype=float)
    if step is None or step <= 0:
        return values.copy()
    return np.round(values / step) * step
