"""
Signal processing of measured records: low-pass smoothing, noise level, derivatives.

The one home of the filters the rest of the package applies to measured signals: the
regressors of the effects, the excitation checks, the start-point search and the position to
speed conversion all call these.  Every function takes numpy arrays, returns new arrays or
floats and never modifies its input.  Filters are zero-phase Butterworth low-passes
computed as :func:`scipy.signal.butter` (``output='sos'``) and :func:`scipy.signal.sosfiltfilt`
compute them (same design steps, same odd padding and initial conditions, same section
recursion: the results agree to rounding, see test/test_signals.py), but without importing
:mod:`scipy.signal`, which costs most of a second of every process (issue 11); odd orders, which
the package does not use, fall back to scipy.
"""

from __future__ import annotations

import functools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcmotor_id.core.noise import noise_std

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
    sos, zi = _design(int(order), float(2.0 * cutoff_fraction))
    return _forward_backward(sos, zi, values)


@functools.lru_cache(maxsize=64)
def _design(order: int, cutoff: float) -> tuple[FloatArray, FloatArray]:
    """
    Return :func:`butter_sos` and its step states (:func:`_sections_zi`) for one cut-off.

    A pure function of two numbers, kept for the cut-offs in use: ``identify`` low-passes
    about thirty signals at five cut-offs (the design is a tenth of a filter's CPU).  The
    arrays are the package's own (:func:`low_pass` passes them to the kernel, which reads
    them), never returned to a caller.
    """
    sos = np.ascontiguousarray(butter_sos(order, cutoff), dtype=float)
    return sos, _sections_zi(sos)


def butter_sos(order: int, cutoff: float) -> FloatArray:
    """
    Digital Butterworth low-pass as second-order sections, as ``scipy.signal.butter`` makes it.

    Parameters
    ----------
    order : int
        Filter order.
    cutoff : float
        Cut-off as a fraction of the Nyquist frequency (0 < cutoff < 1).

    Returns
    -------
    numpy.ndarray
        ``(order // 2, 6)`` sections ``[b0, b1, b2, 1, a1, a2]``, the gain in the first one.

    """
    if order % 2 or order < 2:
        from scipy.signal import butter  # odd orders: not used by the package
        return np.asarray(butter(order, cutoff, output='sos'), dtype=float)
    if not 0.0 < cutoff < 1.0:
        raise ValueError(f'digital filter cut-off must lie in (0, 1), got {cutoff}')
    # Analog prototype, pre-warped cut-off, bilinear transform at fs = 2 (scipy's steps).
    m = np.arange(-order + 1, order, 2, dtype=float)
    poles = -np.exp(1j * np.pi * m / (2 * order))
    warped = 4.0 * np.tan(np.pi * cutoff / 2.0)
    poles = warped * poles
    gain = warped ** order
    digital = (4.0 + poles) / (4.0 - poles)
    gain = gain * np.real(1.0 / np.prod(4.0 - poles))
    # One pole of each conjugate pair (scipy's _cplxreal keeps those of positive imaginary
    # part); the sections are filled from the last, nearest the unit circle last.
    upper = digital[digital.imag > 0]
    upper = upper[np.lexsort((np.abs(upper.imag), upper.real))]
    sos = np.zeros((order // 2, 6))
    for section in range(order // 2 - 1, -1, -1):
        worst = int(np.argmin(np.abs(1.0 - np.abs(upper))))
        pole = upper[worst]
        upper = np.delete(upper, worst)
        denominator = np.real(np.convolve([1.0, -pole], [1.0, -np.conj(pole)]))
        sos[section] = [1.0, 2.0, 1.0, *denominator]
    sos[0, :3] *= gain
    return sos


def _sections_zi(sos: FloatArray) -> FloatArray:
    """Steady-state section states for a unit step (``scipy.signal.sosfilt_zi``)."""
    zi = np.empty((sos.shape[0], 2))
    scale = 1.0
    for section in range(sos.shape[0]):
        b = sos[section, :3]
        a = sos[section, 3:]
        i_minus_a = np.array([[1.0 + a[1], -1.0], [a[2], 1.0]])
        zi[section] = scale * np.linalg.solve(i_minus_a, b[1:] - a[1:] * b[0])
        scale *= np.sum(b) / np.sum(a)
    return zi


def zero_phase(sos: FloatArray, values: ArrayLike) -> FloatArray:
    """
    Filter forward and backward with second-order sections (``scipy.signal.sosfiltfilt``).

    Odd extension of ``3 (2 sections + 1)`` samples at both ends (fewer when sections are of
    first order), the steady-state initial conditions scaled by the first sample of each pass.

    Parameters
    ----------
    sos : numpy.ndarray
        Sections, as :func:`butter_sos` returns them.
    values : array_like
        The signal (one dimension).

    Returns
    -------
    numpy.ndarray
        The filtered signal, a new array.

    """
    sos = np.ascontiguousarray(sos, dtype=float)
    return _forward_backward(sos, _sections_zi(sos), values)


def _forward_backward(sos: FloatArray, zi: FloatArray, values: ArrayLike) -> FloatArray:
    """Return :func:`zero_phase` of ``values`` with the sections' step states ``zi``."""
    x = np.asarray(values, dtype=float)
    taps = 2 * sos.shape[0] + 1 - min(int((sos[:, 2] == 0).sum()), int((sos[:, 5] == 0).sum()))
    edge = 3 * taps
    if x.shape[0] <= edge:
        raise ValueError(f'the signal must be longer than the padding ({edge} samples)')
    ext = np.concatenate((2 * x[:1] - x[edge:0:-1], x, 2 * x[-1:] - x[-2:-(edge + 2):-1]))
    from dcmotor_id.simulation.compiled import kernel  # lazily: no import cycle
    sosfilt = kernel('sosfilt_kernel')
    sosfilt(sos, ext, zi * ext[0])
    ext = ext[::-1].copy()
    sosfilt(sos, ext, zi * ext[0])
    return ext[::-1][edge:-edge].copy()


def smooth(values: ArrayLike, sample_period_s: float | None = None) -> FloatArray:
    """Zero-phase 4th-order low-pass at a tenth of the sample rate (regressors of signals)."""
    return low_pass(values, 0.1, order=4)


def dead_sign(values: ArrayLike, sample_period_s: float | None = None,
              noise: float | None = None) -> FloatArray:
    """
    Sign of a smoothed measured signal, zero within twice its noise level of zero.

    ``noise``: :func:`noise_std` of ``values`` when the caller has it (a record's
    :meth:`~dcmotor_id.core.records.Record.noise_std`; else measured here).
    """
    smoothed = smooth(values)
    deadband = 2.0 * (noise_std(values) if noise is None else noise)
    return np.where(np.abs(smoothed) > deadband, np.sign(smoothed), 0.0)


def central_differences(values: ArrayLike, step: float) -> FloatArray:
    """Differentiate by central differences (one-sided at both ends), ``step`` the period."""
    values = np.asarray(values, dtype=float)
    return np.gradient(values, step)


def integrate_trapezoid(values: ArrayLike, step: float, start: float = 0.0) -> FloatArray:
    """Integrate by the trapezoidal rule, ``start`` at the first sample, ``step`` the period."""
    values = np.asarray(values, dtype=float)
    return start + np.concatenate([[0.0], np.cumsum(0.5 * (values[1:] + values[:-1]) * step)])


def unwrap_turns(position: ArrayLike) -> tuple[FloatArray, int]:
    """
    Return an angle that wraps at a turn unwrapped, and how many wraps were removed.

    An absolute encoder, or a continuous joint's angle, reads within one turn and jumps by
    about 2 pi where it wraps.  Read within one turn, no motion turns more than half a turn in
    a sample (beyond that the angle aliases), so in an angle that stays within one turn, steps
    beyond pi that lie within the largest other step (and 0.05 rad) of a whole number of
    turns are wraps, and ``numpy.unwrap`` removes them.  Otherwise (an angle over more than a
    turn: a multi-turn encoder may advance by more than pi a sample; no such step; other
    steps beyond pi; values that are not finite) the angle is returned as it is, with 0.
    """
    position = np.asarray(position, dtype=float)
    if position.shape[0] < 2 or not np.all(np.isfinite(position)) or \
            float(np.ptp(position)) > 2.0 * np.pi * (1.0 + 1e-6):
        return position, 0
    steps = np.diff(position)
    jumps = np.abs(steps) > np.pi
    if not jumps.any() or jumps.all():
        return position, 0
    largest = float(np.max(np.abs(steps[~jumps])))
    turns = np.round(steps[jumps] / (2.0 * np.pi))
    if np.max(np.abs(steps[jumps] - 2.0 * np.pi * turns)) > max(largest, 0.05):
        return position, 0
    return np.unwrap(position), int(np.count_nonzero(jumps))


def period_mean_speed(position: ArrayLike, sample_period_s: float) -> FloatArray:
    """
    Return the mean speed over each sample period: ``(theta[k+1] - theta[k]) / dt``.

    Free of a differentiating filter's smear (one value fewer than the samples): what the
    one-step test of the electrical equation and the refusal of a derived speed compare.
    """
    return np.diff(np.asarray(position, dtype=float)) / sample_period_s


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
    position = np.asarray(position, dtype=float)
    fs = 1.0 / sample_period_s
    cutoff = min(0.1 * fs, 100.0) if cutoff_hz is None else float(cutoff_hz)
    if not 0 < cutoff < 0.5 * fs:
        raise ValueError(f'cut-off {cutoff} Hz must lie between 0 and the Nyquist {0.5 * fs} Hz')
    sos = butter_sos(order, cutoff / (0.5 * fs))
    return central_differences(zero_phase(sos, position), sample_period_s)
