"""
Residual analysis: is what the model leaves white, and what does it correlate with.

The tools of the discovery loop (:mod:`dcmotor_id.discovery`) and of the report:

* **Output (simulation) error**: the model driven by the measured input alone, minus the
  measurement.  With the right model and white sensor noise it is white and uncorrelated with
  the input; structure in it is model error.
* **One-step error**: the measured state propagated over one sample by the exact ZOH solution
  of the identified model, minus the next measurement; it localises errors in time and is
  insensitive to slow drifts of the simulation.
* **Whiteness**: the Ljung-Box portmanteau test on the autocorrelation (chi-square with as
  many degrees of freedom as lags, :func:`scipy.stats.chi2`), and the share of the residual
  that an autoregressive predictor explains from the residual's own past (a size, where the
  test gives only a significance).
* **Cross-correlation** with the inputs and with each candidate effect's regressor, with the
  99 % band ``+/- z_0.995 / sqrt(N)`` of a white residual.

All functions take numpy arrays and return plain floats, lists and dicts (JSON-ready) or
arrays for plotting; none modifies its inputs.
"""

import numpy as np
from scipy.linalg import expm
from scipy.stats import chi2, norm

from dcmotor_id.signals import noise_std

#: Default number of lags of the whiteness test and the correlation plots.
DEFAULT_LAGS = 25
#: Significance level of the whiteness and correlation tests (99 % bands).
ALPHA = 0.01
#: Order of the autoregressive predictor behind :func:`predictable_fraction`.
AR_ORDER = 10


def confidence_band(n_samples, level=1.0 - ALPHA):
    """Half-width of the two-sided band of a white sequence's correlation at ``level``."""
    return float(norm.ppf(0.5 + 0.5 * level) / np.sqrt(max(n_samples, 1)))


def autocorrelation(values, max_lag=DEFAULT_LAGS, centred=False):
    """
    Normalised autocorrelation ``rho[0..max_lag]`` (``rho[0] = 1``), by FFT.

    A model residual must be zero-mean white noise, so by default the mean is *not* removed:
    a bias (a constant error) then shows as correlation at every lag instead of passing the
    whiteness test unseen.  ``centred=True`` gives the usual sample autocorrelation.
    """
    x = np.asarray(values, dtype=float)
    if centred:
        x = x - np.mean(x)
    n = x.shape[0]
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spectrum = np.fft.rfft(x, size)
    acov = np.fft.irfft(spectrum * np.conj(spectrum), size)[:max_lag + 1]
    if acov[0] <= 0:
        return np.zeros(max_lag + 1)
    return acov / acov[0]


def cross_correlation(x, y, max_lag=DEFAULT_LAGS):
    """
    Normalised cross-correlation ``rho[tau] = corr(x[k + tau], y[k])`` for ``|tau| <= L``.

    Returns
    -------
    lags, rho : numpy.ndarray
        Lags ``-L..L`` [samples] and correlations.  A positive lag at which ``rho`` is large
        means ``x`` follows ``y``.

    """
    x = np.asarray(x, dtype=float) - np.mean(x)
    y = np.asarray(y, dtype=float) - np.mean(y)
    n = x.shape[0]
    scale = np.sqrt(np.sum(x * x) * np.sum(y * y))
    lags = np.arange(-max_lag, max_lag + 1)
    if scale <= 0:
        return lags, np.zeros(lags.shape[0])
    size = 1 << int(np.ceil(np.log2(2 * n)))
    full = np.fft.irfft(np.fft.rfft(x, size) * np.conj(np.fft.rfft(y, size)), size)
    rho = np.concatenate([full[size - max_lag:], full[:max_lag + 1]]) / scale
    return lags, rho


def ljung_box(values, lags=DEFAULT_LAGS, alpha=ALPHA):
    """
    Ljung-Box test of whiteness.

    ``Q = N (N + 2) sum_{k=1}^{h} rho_k^2 / (N - k)`` is chi-square with ``h`` degrees of
    freedom for a white sequence; ``rho`` is the uncentred autocorrelation, so the test is of
    *zero-mean* whiteness (a bias fails it).

    Returns
    -------
    dict
        ``statistic``, ``p_value``, ``lags``, ``white`` (``p_value >= alpha``).

    """
    n = np.asarray(values).shape[0]
    lags = int(min(lags, max(n // 5, 1)))
    rho = autocorrelation(values, lags)[1:]
    statistic = float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, lags + 1))))
    p_value = float(chi2.sf(statistic, lags))
    return {'statistic': statistic, 'p_value': p_value, 'lags': lags,
            'white': bool(p_value >= alpha)}


def predictable_fraction(values, order=AR_ORDER):
    """
    Share of the residual's mean square an AR(``order``) predictor explains from its past.

    About ``order / N`` for zero-mean white noise; near 1 for a smooth (model-error) residual
    or a bias (the mean is not removed, as in :func:`autocorrelation`).
    """
    x = np.asarray(values, dtype=float)
    n = x.shape[0]
    if n <= 4 * order:
        return 0.0
    past = np.column_stack([x[order - lag:n - lag] for lag in range(1, order + 1)])
    target = x[order:]
    total = float(target @ target)
    if total <= 0:
        return 0.0
    coefficients = np.linalg.lstsq(past, target, rcond=None)[0]
    error = target - past @ coefficients
    return float(max(0.0, 1.0 - (error @ error) / total))


def correlation_summary(residual, signal, max_lag=DEFAULT_LAGS, level=1.0 - ALPHA):
    """
    Largest cross-correlation of a residual with a signal over ``|lag| <= max_lag``.

    Returns
    -------
    dict
        ``max_abs`` correlation, the ``lag`` where it occurs, the ``band`` and whether the
        correlation is ``outside`` it.

    """
    lags, rho = cross_correlation(residual, signal, max_lag)
    band = confidence_band(np.asarray(residual).shape[0], level)
    position = int(np.argmax(np.abs(rho)))
    return {'max_abs': float(abs(rho[position])), 'lag': int(lags[position]),
            'band': band, 'outside': bool(abs(rho[position]) > band)}


def analyse_channel(residual, measured, inputs=None, regressors=None, max_lag=DEFAULT_LAGS,
                    alpha=ALPHA):
    """
    Analyse one output channel's residual.

    Parameters
    ----------
    residual : numpy.ndarray
        Model minus measurement.
    measured : numpy.ndarray
        The measurement (for the normalised error).
    inputs : dict, optional
        Input signals by name (voltage, or the current in mechanical-only mode).
    regressors : dict, optional
        Candidate effects' regressors by effect name.
    max_lag : int
        Lags of the whiteness test and the correlations.
    alpha : float
        Significance level.

    Returns
    -------
    dict
        ``rms``, ``nrmse_pct``, ``noise_std`` (robust estimate from the measurement),
        ``ljung_box``, ``predictable_fraction``, ``acf_outside_band`` (share of lags
        ``1..max_lag`` outside the band), ``inputs`` and ``regressors`` correlation summaries.

    """
    residual = np.asarray(residual, dtype=float)
    measured = np.asarray(measured, dtype=float)
    spread = float(np.std(measured))
    rms = float(np.sqrt(np.mean(residual ** 2)))
    acf = autocorrelation(residual, max_lag)
    band = confidence_band(residual.shape[0], 1.0 - alpha)
    level = 1.0 - alpha
    return {
        'rms': rms,
        'nrmse_pct': rms / spread * 100.0 if spread > 0 else None,
        'noise_std': noise_std(measured),
        'ljung_box': ljung_box(residual, max_lag, alpha),
        'predictable_fraction': predictable_fraction(residual),
        'acf_outside_band': float(np.mean(np.abs(acf[1:]) > band)),
        'band': band,
        'inputs': {name: correlation_summary(residual, values, max_lag, level)
                   for name, values in (inputs or {}).items()},
        'regressors': {name: correlation_summary(residual, values, max_lag, level)
                       for name, values in (regressors or {}).items()},
    }


def zoh_matrices(a_matrix, sample_period_s):
    """Exact ZOH discretisation ``(Ad, Gamma)`` with ``Gamma = int_0^dt exp(A s) ds``."""
    a_matrix = np.atleast_2d(np.asarray(a_matrix, dtype=float))
    n = a_matrix.shape[0]
    block = np.zeros((2 * n, 2 * n))
    block[:n, :n] = a_matrix
    block[:n, n:] = np.eye(n)
    exponential = expm(block * sample_period_s)
    return exponential[:n, :n], exponential[:n, n:]


def one_step_error(values, record, torque_constant=None, voltage_extra=None, torque_extra=None,
                   current_offset=None, speed_offset=None, coulomb_delta=0.0):
    """
    One-step prediction error of the identified model on one record.

    The measured state ``[i, w]`` (or ``w`` alone in mechanical-only mode), corrected for any
    sensor offset, is propagated one sample with the exact ZOH solution, the Coulomb friction
    taking the sign of the measured speed; the prediction minus the next measurement is
    returned (stick-slip within a sample is not modelled here, unlike in the simulation).

    Parameters
    ----------
    values : dict
        Parameters (``Ra, La, CPhi, J, b, Mc`` or ``J, b, Mc``).
    record : Record
        The record.
    torque_constant : float, optional
        Mechanical-only mode.
    voltage_extra, torque_extra, current_offset, speed_offset : numpy.ndarray, optional
        Effect contributions per sample (as :class:`~dcmotor_id.estimators.refined.
        OutputErrorModel` adds them).
    coulomb_delta : float
        Asymmetry of the Coulomb friction [N m].

    Returns
    -------
    dict
        ``current`` (full mode) and ``speed`` arrays of length ``N - 1``.

    """
    n = len(record)
    dt = record.sample_period_s
    zeros = np.zeros(n)
    torque_extra = zeros if torque_extra is None else torque_extra
    speed_meas = record.speed - (zeros if speed_offset is None else speed_offset)
    sign = np.sign(speed_meas)
    friction = np.where(sign > 0, values['Mc'] + coulomb_delta,
                        values['Mc'] - coulomb_delta) * sign
    if torque_constant is not None:
        ad, gamma = zoh_matrices([[-values['b'] / values['J']]], dt)
        drive = (torque_constant * record.current + torque_extra - friction) / values['J']
        predicted = ad[0, 0] * speed_meas[:-1] + gamma[0, 0] * drive[:-1]
        return {'speed': predicted - speed_meas[1:]}
    current_meas = record.current - (zeros if current_offset is None else current_offset)
    voltage = record.voltage + (zeros if voltage_extra is None else voltage_extra)
    a_matrix = np.array([[-values['Ra'] / values['La'], -values['CPhi'] / values['La']],
                         [values['CPhi'] / values['J'], -values['b'] / values['J']]])
    ad, gamma = zoh_matrices(a_matrix, dt)
    state = np.vstack([current_meas[:-1], speed_meas[:-1]])
    forcing = np.vstack([voltage[:-1] / values['La'],
                         (torque_extra[:-1] - friction[:-1]) / values['J']])
    predicted = ad @ state + gamma @ forcing
    return {'current': predicted[0] - current_meas[1:], 'speed': predicted[1] - speed_meas[1:]}
