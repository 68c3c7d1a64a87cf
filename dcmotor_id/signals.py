"""
Signal processing of measured records: low-pass smoothing, noise level, derivatives.

The one home of the filters the rest of the package applies to measured signals: the
regressors of the effects, the excitation checks, the start-point search and the position to
speed conversion all call these.  Every function takes numpy arrays, returns new arrays or
floats and never modifies its input.  Filters are scipy's zero-phase Butterworth
(:func:`scipy.signal.sosfiltfilt`), imported lazily so that importing the package does not pay
for :mod:`scipy.signal`.
"""

from __future__ import annotations

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
    from scipy.signal import butter, sosfiltfilt

    values = np.asarray(values, dtype=float)
    if values.shape[0] < MIN_FILTER_SAMPLES:
        return values.copy()
    sos = butter(order, 2.0 * cutoff_fraction, output='sos')
    return np.asarray(sosfiltfilt(sos, values), dtype=float)


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
