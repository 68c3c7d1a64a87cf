"""
Signal processing of measured records: low-pass smoothing, noise level, derivatives.

The one home of the filters the rest of the package applies to measured signals: the
regressors of the effects, the excitation checks, the start-point search and the position to
speed conversion all call these.  Every function takes numpy arrays, returns new arrays or
floats and never modifies its input.  Filters are zero-phase Butterworth low-passes computed
exactly as :func:`scipy.signal.butter` (``output='sos'``) and :func:`scipy.signal.sosfiltfilt`
compute them (same design, pairing, odd extension and initial conditions; test_signals.py
checks them against scipy to round-off).  Written here because importing :mod:`scipy.signal`
costs most of a second, more than the identification of a minute of data.
"""

from __future__ import annotations

from numba import njit
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Shortest signal that is filtered at all (shorter ones are returned as they are).
MIN_FILTER_SAMPLES = 30


def low_pass(values: ArrayLike, cutoff_fraction: float, order: int = 4) -> FloatArray:
    """
    Zero-phase Butterworth low-pass.

    Parameters
    ----------
    values : array_like
        The signal, uniformly sampled.
    cutoff_fraction : float
        Cut-off as a fraction of the sample rate (0 < fraction < 0.5).
    order : int
        Filter order (applied forward and backward, so the magnitude is squared).

    Returns
    -------
    numpy.ndarray
        The filtered signal; a copy of the input when it is too short to filter.

    """
    values = np.asarray(values, dtype=float)
    if values.shape[0] < MIN_FILTER_SAMPLES:
        return values.copy()
    if order % 2:
        # Odd orders pair a first-order section as scipy does in its own way: ask scipy.
        from scipy.signal import butter, sosfiltfilt
        return np.asarray(sosfiltfilt(butter(order, 2.0 * cutoff_fraction, output='sos'),
                                      values), dtype=float)
    return _sosfiltfilt(butter_sos(order, 2.0 * cutoff_fraction), values)


def butter_sos(order: int, cutoff: float) -> FloatArray:
    """
    Digital Butterworth low-pass as second-order sections, as ``scipy.signal.butter`` designs it.

    Parameters
    ----------
    order : int
        Filter order (even).
    cutoff : float
        Cut-off as a fraction of the Nyquist frequency (0 < cutoff < 1).

    Returns
    -------
    numpy.ndarray
        ``(order / 2, 6)`` rows ``[b0, b1, b2, 1, a1, a2]``, the poles nearest the unit
        circle last and the gain in the first section (scipy's ``nearest`` pairing).

    """
    if order % 2 or order < 2:
        raise ValueError('butter_sos designs even orders only')
    # Analog prototype, pre-warped cut-off (fs = 2), bilinear transform: scipy's iirfilter.
    poles = -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))
    warped = 4.0 * np.tan(np.pi * cutoff / 2.0)
    poles = warped * poles
    gain = warped ** order * np.real(1.0 / np.prod(4.0 - poles))
    digital = (4.0 + poles) / (4.0 - poles)
    # Conjugate pairs (zeros all at -1), the pair nearest to the unit circle last.
    upper = sorted(digital[digital.imag > 0], key=lambda pole: abs(1.0 - abs(pole)),
                   reverse=True)
    sos = np.array([[1.0, 2.0, 1.0, 1.0, -2.0 * pole.real,
                     pole.real * pole.real + pole.imag * pole.imag] for pole in upper])
    sos[0, :3] *= gain
    return sos


@njit(cache=True)
def _sosfilt(sos, values, initial):
    """Filter with second-order sections (transposed direct form II), as scipy's sosfilt."""
    n_sections = sos.shape[0]
    state = initial.copy()
    out = np.empty_like(values)
    for k in range(values.shape[0]):
        x = values[k]
        for section in range(n_sections):
            y = sos[section, 0] * x + state[section, 0]
            state[section, 0] = sos[section, 1] * x - sos[section, 4] * y + state[section, 1]
            state[section, 1] = sos[section, 2] * x - sos[section, 5] * y
            x = y
        out[k] = x
    return out


def _sosfiltfilt(sos: FloatArray, values: FloatArray) -> FloatArray:
    """Forward-backward filter with odd extension and steady-state initial conditions."""
    n_sections = sos.shape[0]
    taps = 2 * n_sections + 1 - min(int(np.sum(sos[:, 2] == 0)), int(np.sum(sos[:, 5] == 0)))
    edge = 3 * taps
    if values.shape[0] <= edge:
        raise ValueError(f'the signal must be longer than {edge} samples to be filtered')
    extended = np.concatenate((2 * values[0] - values[edge:0:-1], values,
                               2 * values[-1] - values[-2:-(edge + 2):-1]))
    initial = np.empty((n_sections, 2))
    scale = 1.0
    for section in range(n_sections):
        b, a = sos[section, :3], sos[section, 3:]
        # scipy's lfilter_zi: (I - companion(a)^T) zi = b[1:] - a[1:] b[0]
        system = np.array([[1.0 + a[1], -1.0], [a[2], 1.0]])
        initial[section] = scale * np.linalg.solve(system, b[1:] - a[1:] * b[0])
        scale *= b.sum() / a.sum()
    forward = _sosfilt(sos, extended, initial * extended[0])
    backward = _sosfilt(sos, forward[::-1].copy(), initial * forward[-1])
    return backward[::-1][edge:-edge].copy()


def smooth(values: ArrayLike, sample_period_s: float | None = None) -> FloatArray:
    """Zero-phase 4th-order low-pass at a tenth of the sample rate (regressors of signals)."""
    return low_pass(values, 0.1, order=4)


def noise_std(values: ArrayLike) -> float:
    """
    Robust standard deviation of white noise on a smooth signal.

    Second differences remove a smooth signal up to its curvature; for white noise of variance
    ``s^2`` they have variance ``6 s^2``.  The median absolute deviation makes the estimate
    insensitive to jumps (switching inputs, speed reversals).
    """
    values = np.asarray(values, dtype=float)
    if values.shape[0] < 5:
        return 0.0
    second = np.diff(values, 2)
    mad = np.median(np.abs(second - np.median(second)))
    return float(mad / 0.6745 / np.sqrt(6.0))


def dead_sign(values: ArrayLike, sample_period_s: float | None = None) -> FloatArray:
    """Sign of a smoothed measured signal, zero within twice its noise level of zero."""
    smoothed = smooth(values)
    deadband = 2.0 * noise_std(values)
    return np.where(np.abs(smoothed) > deadband, np.sign(smoothed), 0.0)


def central_differences(values: ArrayLike, step: float) -> FloatArray:
    """Differentiate by central differences (one-sided at both ends), ``step`` the period."""
    values = np.asarray(values, dtype=float)
    return np.gradient(values, step)


def integrate_trapezoid(values: ArrayLike, step: float, start: float = 0.0) -> FloatArray:
    """Integrate by the trapezoidal rule, ``start`` at the first sample, ``step`` the period."""
    values = np.asarray(values, dtype=float)
    return start + np.concatenate([[0.0], np.cumsum(0.5 * (values[1:] + values[:-1]) * step)])


def speed_from_position(position: ArrayLike, sample_period_s: float,
                        cutoff_hz: float | None = None, order: int = 4) -> FloatArray:
    """
    Derive speed from an encoder position with a differentiating filter.

    A Butterworth low-pass of the given order, applied forward and backward (no phase lag),
    followed by central differences: the processing of the EMPS reference (IDIM-LS).

    Parameters
    ----------
    position : array_like
        Position [rad] (or [m] for a linear axis).
    sample_period_s : float
        Sample period [s].
    cutoff_hz : float, optional
        Low-pass cut-off [Hz]; default a tenth of the sample rate, at most 100 Hz.
    order : int
        Filter order.

    Returns
    -------
    numpy.ndarray
        Speed [rad/s] (or [m/s]).

    """
    from scipy.signal import butter, sosfiltfilt

    position = np.asarray(position, dtype=float)
    fs = 1.0 / sample_period_s
    cutoff = min(0.1 * fs, 100.0) if cutoff_hz is None else float(cutoff_hz)
    if not 0 < cutoff < 0.5 * fs:
        raise ValueError(f'cut-off {cutoff} Hz must lie between 0 and the Nyquist {0.5 * fs} Hz')
    sos = butter(order, cutoff, fs=fs, output='sos')
    return central_differences(sosfiltfilt(sos, position), sample_period_s)
