"""
Residual analysis and the one simulation error per channel: what the model leaves, and why.

The tools of :func:`dcmotor_id.identification.identify.identify`, the discovery loop
(:mod:`dcmotor_id.identification.discovery`) and the report:

* **Output (simulation) error**: the model driven by the measured input alone, minus the
  measurement.  With the right model and white sensor noise it is white and uncorrelated with
  the input; structure in it is model error.  :func:`simulation_error_pct` is its one size
  (percent of the measured signal's spread) and :func:`model_errors` runs a fitted model over
  its records and returns it per channel: every ``{current,speed}_nrmse_pct`` of the results
  comes from there.
* **One-step error**: the measured state propagated over one sample by the exact ZOH solution
  of the identified model, minus the next measurement; it localises errors in time and is
  insensitive to slow drifts of the simulation.
* **Whiteness**: the Ljung-Box portmanteau test on the autocorrelation (chi-square with as
  many degrees of freedom as lags, :func:`chi_square_sf`), and the share of the residual
  that an autoregressive predictor explains from the residual's own past (a size, where the
  test gives only a significance).
* **Cross-correlation** with the inputs and with each candidate effect's regressor, with the
  99 % band ``+/- z_0.995 / sqrt(N)`` of a white residual.

All functions take numpy arrays and return plain floats, lists and dicts (JSON-ready) or
arrays for plotting; none modifies its inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
import math
from statistics import NormalDist
from typing import Any, Mapping, Protocol, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dcmotor_id.signals.filters import noise_std, period_mean_speed
from dcmotor_id.simulation import zoh_matrices

#: Default number of lags of the whiteness test and the correlation plots.
DEFAULT_LAGS = 25
#: Significance level of the whiteness and correlation tests (99 % bands).
ALPHA = 0.01
#: Order of the autoregressive predictor behind :func:`predictable_fraction`.
AR_ORDER = 10
#: Channels whose simulation error is reported, in the order of the JSON results.
ERROR_CHANNELS = ('current', 'speed')
#: Samples per block of :func:`one_step_error` (bounds its temporaries).
ONE_STEP_BLOCK = 1 << 16
#: Rows per block of the autoregressive predictor's QR (:func:`predictable_fraction`).
PREDICTOR_BLOCK = 1 << 15

FloatArray = NDArray[np.float64]
#: ``{current_nrmse_pct, speed_nrmse_pct}``: a value in percent, or None (no such output, or
#: no finite error).
ChannelErrors = dict[str, 'float | None']


class SimulatedModel(Protocol):
    """What :func:`model_errors` needs of a model (``OutputErrorModel`` is one)."""

    records: list
    outputs: tuple

    def simulate(self, values: Mapping[str, float], index: int,
                 initial_state: FloatArray) -> dict[str, FloatArray]:
        """Simulate record ``index`` from ``initial_state``; return the outputs by channel."""


def output_channels(mechanical_only: bool) -> tuple[str, ...]:
    """Return the simulated (output) channels: speed alone in mechanical-only mode."""
    return ('speed',) if mechanical_only else ERROR_CHANNELS


def error_key(channel: str) -> str:
    """Return the result key of a channel's simulation error (``speed_nrmse_pct``)."""
    return f'{channel}_nrmse_pct'


def residual_nrmse_pct(residual: ArrayLike, measured: ArrayLike) -> float | None:
    """
    Return ``rms(residual) / std(measured) * 100``: a residual in percent of the signal spread.

    None for a constant measurement.  The one normalisation of every error of the package
    (simulation, one-step, the residual analysis).
    """
    residual = np.asarray(residual, dtype=float)
    spread = float(np.std(np.asarray(measured, dtype=float)))
    if not spread > 0:
        return None
    return float(np.sqrt(np.mean(residual ** 2))) / spread * 100.0


def simulation_error_pct(simulated: ArrayLike, measured: ArrayLike) -> float | None:
    """
    Return the simulation error in percent of the measured signal's standard deviation.

    :func:`residual_nrmse_pct` of ``simulated - measured``; None when it is not finite (a
    constant measurement, or a simulation that diverged).
    """
    measured = np.asarray(measured, dtype=float)
    # residual_nrmse_pct's arithmetic, squaring the difference in place (one N-sized array).
    spread = float(np.std(measured))
    if not spread > 0:
        return None
    squared = np.asarray(simulated, dtype=float) - measured
    np.multiply(squared, squared, out=squared)
    value = float(np.sqrt(np.mean(squared))) / spread * 100.0
    return value if np.isfinite(value) else None


def channel_errors(simulated: Mapping[str, ArrayLike], measured: Mapping[str, ArrayLike],
                   outputs: Sequence[str]) -> ChannelErrors:
    """
    Return ``{current_nrmse_pct, speed_nrmse_pct}`` of the ``outputs`` channels.

    ``simulated`` and ``measured`` hold each channel's samples (records concatenated); a
    channel that is not an output (the current in mechanical-only mode) is None.
    """
    errors: ChannelErrors = {error_key(channel): None for channel in ERROR_CHANNELS}
    for channel in outputs:
        errors[error_key(channel)] = simulation_error_pct(simulated[channel], measured[channel])
    return errors


def simulate_records(model: SimulatedModel, values: Mapping[str, float],
                     initial_states: Sequence[Sequence[float]]) -> list[dict[str, FloatArray]]:
    """
    Simulate every record of a model from its initial state; return the outputs per record.

    Floating-point warnings are silenced: a wild parameter set may overflow, and its
    simulation error then says so (None, or a large value).
    """
    with np.errstate(all='ignore'):
        return [model.simulate(values, index, np.array(state, dtype=float))
                for index, state in enumerate(initial_states)]


def model_errors(model: SimulatedModel, values: Mapping[str, float],
                 initial_states: Sequence[Sequence[float]]) -> ChannelErrors:
    """
    Simulate a fitted model over its records; return the simulation error per channel.

    Parameters
    ----------
    model : OutputErrorModel
        The model on the records (with the effect terms of the fitted structure).
    values : dict
        The fitted parameters (base and term coefficients).
    initial_states : sequence of sequence of float
        One initial state per record.

    Returns
    -------
    dict
        ``{current_nrmse_pct, speed_nrmse_pct}`` over the records concatenated (the
        current None in mechanical-only mode).

    """
    simulated = simulate_records(model, values, initial_states)
    errors: ChannelErrors = {error_key(channel): None for channel in ERROR_CHANNELS}
    for channel in model.outputs:
        # One channel at a time, the simulation dropped once used (memory).
        errors[error_key(channel)] = simulation_error_pct(
            _joined([out.pop(channel) for out in simulated]),
            _joined([getattr(rec, channel) for rec in model.records]))
    return errors


@dataclass(frozen=True)
class Simulation:
    """
    A fitted model simulated over its records once, for every stage that measures it.

    ``model``: the model on the records (with the effect terms of the fitted structure);
    ``outputs``: its simulated channels per record (:func:`simulate_records`); ``values`` and
    ``initial_states``: what was simulated (:func:`simulated` records them, and gives this
    simulation back to a later stage that asks for the same, :meth:`is_of`).
    """

    model: SimulatedModel
    outputs: list[dict[str, FloatArray]]
    values: dict[str, float] | None = None
    initial_states: tuple[FloatArray, ...] | None = None

    def is_of(self, model: SimulatedModel, values: Mapping[str, float],
              initial_states: Sequence[Sequence[float]]) -> bool:
        """
        Whether this is the simulation of ``model`` at ``values`` from ``initial_states``.

        The same model means the same record objects, torque constant, effect terms and
        armature (what a simulation reads; the channels a model compares do not change what
        it simulates), and the same values and initial states exactly: the simulation would
        be this one, bit for bit.
        """
        if self.values is None or self.initial_states is None:
            return False
        return (_simulates_as(self.model, model) and dict(values) == self.values
                and len(initial_states) == len(self.initial_states)
                and all(np.array_equal(np.asarray(state, dtype=float), own)
                        for state, own in zip(initial_states, self.initial_states)))

    @cached_property
    def errors(self) -> ChannelErrors:
        """Return the simulation error per channel, as :func:`model_errors` gives it."""
        errors: ChannelErrors = {error_key(channel): None for channel in ERROR_CHANNELS}
        for channel in self.model.outputs:
            errors[error_key(channel)] = simulation_error_pct(
                _joined([out[channel] for out in self.outputs]),
                _joined([getattr(rec, channel) for rec in self.model.records]))
        return errors

    def period_mean_speed_error(self) -> float | None:
        """
        Return the speed's simulation error over the sample periods, where a position gave it.

        A speed derived from the position by a low-pass lags and smooths motion near its
        cut-off, so its simulation error measures the filter as well as the model.  Over each
        sample period the position's increment ``(theta[k+1] - theta[k]) / dt`` is the
        measured mean speed, filter-free; the model's is the trapezoid of its speed at the
        period's ends.  Records with a measured speed enter as they are.  None without a
        derived speed among the records (or no speed output).
        """
        records = self.model.records
        if 'speed' not in self.model.outputs or \
                not any(rec.speed_from_position for rec in records):
            return None
        simulated, measured = [], []
        for out, rec in zip(self.outputs, records):
            speed = out['speed']
            if rec.speed_from_position:
                simulated.append(0.5 * (speed[1:] + speed[:-1]))
                measured.append(period_mean_speed(rec.position, rec.sample_period_s))
            else:
                simulated.append(speed)
                measured.append(np.asarray(rec.speed, dtype=float))
        return simulation_error_pct(_joined(simulated), _joined(measured))

    def residual_rms(self, channels: Sequence[str]) -> dict[str, float]:
        """Return the RMS of each channel's simulation residual over all records."""
        return {channel: float(np.sqrt(np.mean(np.concatenate(
            [out[channel] - getattr(rec, channel)
             for out, rec in zip(self.outputs, self.model.records)]) ** 2)))
            for channel in channels}


def simulated(model: SimulatedModel, values: Mapping[str, float],
              initial_states: Sequence[Sequence[float]],
              carried: Simulation | None = None) -> Simulation:
    """
    Return the :class:`Simulation` of a fitted model over its records.

    ``carried``: a simulation an earlier stage ran and handed on (the pipeline's state); it
    is returned when it is of the same model, values and initial states
    (:meth:`Simulation.is_of`), else the model is simulated.
    """
    if carried is not None and carried.is_of(model, values, initial_states):
        return carried
    return Simulation(model, simulate_records(model, values, initial_states), dict(values),
                      tuple(np.array(state, dtype=float) for state in initial_states))


def _simulates_as(one: Any, other: Any) -> bool:
    """Whether two models simulate alike: the same records, torque constant, terms, armature."""
    if one is other:
        return True
    if type(one) is not type(other):
        return False
    fields = ('torque_constant', 'quasi_static')
    return (all(getattr(one, name, None) == getattr(other, name, None) for name in fields)
            and _same_objects(one.records, other.records)
            and _same_objects(getattr(one, 'terms', ()), getattr(other, 'terms', ())))


def _same_objects(one: Sequence[Any], other: Sequence[Any]) -> bool:
    """Whether two sequences hold the same objects (identity), in the same order."""
    return len(one) == len(other) and all(a is b for a, b in zip(one, other))


def _joined(arrays: Sequence[FloatArray]) -> FloatArray:
    """Concatenate arrays; a single one is returned as it is (no copy)."""
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def confidence_band(n_samples: int, level: float = 1.0 - ALPHA) -> float:
    """Half-width of the two-sided band of a white sequence's correlation at ``level``."""
    return float(NormalDist().inv_cdf(0.5 + 0.5 * level) / np.sqrt(max(n_samples, 1)))


def chi_square_sf(dof: int, statistic: float) -> float:
    """
    Survival function of the chi-square distribution with an integer number of degrees of freedom.

    The closed forms of the regularised upper incomplete gamma function ``Q(dof / 2, x / 2)``
    (a finite sum of Poisson terms, plus ``erfc`` for an odd ``dof``), each term taken in
    logarithms so that neither a large statistic nor many degrees of freedom overflow: the value
    of ``scipy.special.chdtrc`` to rounding, without importing :mod:`scipy.special` (a fifth of
    a second of every process).
    """
    if dof < 1:
        raise ValueError(f'degrees of freedom must be a positive integer, got {dof}')
    if not statistic > 0.0:
        return 1.0
    if math.isinf(statistic):
        return 0.0
    half = 0.5 * statistic
    log_half = math.log(half)
    if dof % 2 == 0:
        total = sum(math.exp(i * log_half - half - math.lgamma(i + 1.0))
                    for i in range(dof // 2))
    else:
        total = math.erfc(math.sqrt(half))
        total += sum(math.exp((i - 0.5) * log_half - half - math.lgamma(i + 0.5))
                     for i in range(1, (dof - 1) // 2 + 1))
    return min(total, 1.0)


def autocorrelation(values: ArrayLike, max_lag: int = DEFAULT_LAGS,
                    centred: bool = False) -> FloatArray:
    """
    Normalised autocorrelation ``rho[0..max_lag]`` (``rho[0] = 1``).

    Computed lag by lag in the time domain (``max_lag + 1`` dot products): no padded FFT
    arrays several times the record's size.

    A model residual must be zero-mean white noise, so by default the mean is *not* removed:
    a bias (a constant error) then shows as correlation at every lag instead of passing the
    whiteness test unseen.  ``centred=True`` gives the usual sample autocorrelation.
    """
    x = np.asarray(values, dtype=float)
    if centred:
        x = x - np.mean(x)
    # As many lags as the (zero-padded, circular) correlation of 2^k >= 2 N samples has.
    size = 1 << int(np.ceil(np.log2(2 * x.shape[0])))
    acov = np.array([_lagged_dot(x, x, lag) for lag in range(min(max_lag + 1, size))])
    if acov[0] <= 0:
        return np.zeros(max_lag + 1)
    return acov / acov[0]


def cross_correlation(x: ArrayLike, y: ArrayLike,
                      max_lag: int = DEFAULT_LAGS) -> tuple[NDArray[np.int_], FloatArray]:
    """
    Normalised cross-correlation ``rho[tau] = corr(x[k + tau], y[k])`` for ``|tau| <= L``.

    Computed lag by lag in the time domain (``2 L + 1`` dot products, no FFT arrays).

    Returns
    -------
    lags, rho : numpy.ndarray
        Lags ``-L..L`` [samples] and correlations.  A positive lag at which ``rho`` is large
        means ``x`` follows ``y``.

    """
    x_array = np.asarray(x, dtype=float)
    y_array = np.asarray(y, dtype=float)
    x_array = x_array - np.mean(x_array)
    y_array = y_array - np.mean(y_array)
    scale = np.sqrt(np.sum(x_array * x_array) * np.sum(y_array * y_array))
    lags = np.arange(-max_lag, max_lag + 1)
    if scale <= 0:
        return lags, np.zeros(lags.shape[0])
    rho = np.array([_lagged_dot(x_array, y_array, int(lag)) for lag in lags]) / scale
    return lags, rho


def _lagged_dot(x: FloatArray, y: FloatArray, lag: int) -> float:
    """Return ``sum_k x[k + lag] y[k]`` over the overlap (zero beyond the length)."""
    n = x.shape[0]
    if abs(lag) >= n:
        return 0.0
    if lag >= 0:
        return float(x[lag:] @ y[:n - lag])
    return float(x[:n + lag] @ y[-lag:])


def ljung_box(values: ArrayLike, lags: int = DEFAULT_LAGS,
              alpha: float = ALPHA) -> dict[str, Any]:
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
    p_value = chi_square_sf(lags, statistic)
    return {'statistic': statistic, 'p_value': p_value, 'lags': lags,
            'white': bool(p_value >= alpha)}


def predictable_fraction(values: ArrayLike, order: int = AR_ORDER) -> float:
    """
    Share of the residual's mean square an AR(``order``) predictor explains from its past.

    About ``order / N`` for zero-mean white noise; near 1 for a smooth (model-error) residual
    or a bias (the mean is not removed, as in :func:`autocorrelation`).
    """
    x = np.asarray(values, dtype=float)
    n = x.shape[0]
    if n <= 4 * order:
        return 0.0
    target = x[order:]
    total = float(target @ target)
    if total <= 0:
        return 0.0
    # The least-squares residual of the target on its past is the last diagonal element of
    # R in the QR factorisation of [past | target]; R is accumulated block by block (the
    # rows of the past are built a block at a time, never the N x order matrix).
    r_factor = np.zeros((0, order + 1))
    for first in range(order, n, PREDICTOR_BLOCK):
        last = min(first + PREDICTOR_BLOCK, n)
        block = np.column_stack([x[first - lag:last - lag] for lag in range(1, order + 1)] +
                                [x[first:last]])
        r_factor = np.asarray(np.linalg.qr(np.vstack([r_factor, block]), mode='r'))
    error = float(r_factor[order, order]) ** 2 if r_factor.shape[0] > order else 0.0
    return float(max(0.0, 1.0 - error / total))


def correlation_summary(residual: ArrayLike, signal: ArrayLike, max_lag: int = DEFAULT_LAGS,
                        level: float = 1.0 - ALPHA) -> dict[str, Any]:
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


def analyse_channel(residual: ArrayLike, measured: ArrayLike,
                    inputs: Mapping[str, ArrayLike] | None = None,
                    regressors: Mapping[str, ArrayLike] | None = None,
                    max_lag: int = DEFAULT_LAGS, alpha: float = ALPHA) -> dict[str, Any]:
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
    acf = autocorrelation(residual, max_lag)
    band = confidence_band(residual.shape[0], 1.0 - alpha)
    level = 1.0 - alpha
    return {
        'rms': float(np.sqrt(np.mean(residual ** 2))),
        'nrmse_pct': residual_nrmse_pct(residual, measured),
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


def one_step_error(values: Mapping[str, float], record: Any,
                   torque_constant: float | None = None,
                   voltage_extra: ArrayLike | None = None, torque_extra: ArrayLike | None = None,
                   current_offset: ArrayLike | None = None,
                   speed_offset: ArrayLike | None = None,
                   coulomb_delta: float = 0.0) -> dict[str, FloatArray]:
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
        Effect contributions per sample (as :class:`~dcmotor_id.identification.estimators.refined.
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
    if torque_constant is not None:
        ad, gamma = zoh_matrices([[-values['b'] / values['J']]], dt)
    else:
        a_matrix = np.array([[-values['Ra'] / values['La'], -values['CPhi'] / values['La']],
                             [values['CPhi'] / values['J'], -values['b'] / values['J']]])
        ad, gamma = zoh_matrices(a_matrix, dt)
    channels = ('speed',) if torque_constant is not None else ('current', 'speed')
    out = {channel: np.empty(max(n - 1, 0)) for channel in channels}
    extras = {'voltage': voltage_extra, 'torque': torque_extra,
              'current_offset': current_offset, 'speed_offset': speed_offset,
              'coulomb_delta': coulomb_delta}
    # Blocks of samples (each block overlapping the next by one): the temporaries stay a few
    # MB whatever the record's length; every element is computed as over the whole record.
    for first in range(0, max(n - 1, 0), ONE_STEP_BLOCK):
        last = min(first + ONE_STEP_BLOCK, n - 1) + 1
        block = _one_step_block(values, record, torque_constant, (ad, gamma), (first, last),
                                extras)
        for channel in channels:
            out[channel][first:last - 1] = block[channel]
    return out


def _one_step_block(values, record, torque_constant, zoh, span, extras):
    """
    One-step errors of samples ``first..last - 2`` (:func:`one_step_error` on a block).

    ``zoh``: the ZOH matrices ``(ad, gamma)``; ``span``: ``(first, last)``; ``extras``: the
    effect contributions by name (``voltage``, ``torque``, ``current_offset``,
    ``speed_offset``, ``coulomb_delta``), as :func:`one_step_error` takes them.
    """
    (ad, gamma), (first, last) = zoh, span
    coulomb_delta = extras['coulomb_delta']

    def part(values_or_none):
        return None if values_or_none is None else \
            np.asarray(values_or_none, dtype=float)[first:last]
    zeros = np.zeros(last - first)
    torque_extra, speed_offset = part(extras['torque']), part(extras['speed_offset'])
    torque = zeros if torque_extra is None else torque_extra
    speed_meas = record.speed[first:last] - (zeros if speed_offset is None else speed_offset)
    sign = np.sign(speed_meas)
    friction = np.where(sign > 0, values['Mc'] + coulomb_delta,
                        values['Mc'] - coulomb_delta) * sign
    if torque_constant is not None:
        drive = (torque_constant * record.current[first:last] + torque - friction) / values['J']
        predicted = ad[0, 0] * speed_meas[:-1] + gamma[0, 0] * drive[:-1]
        return {'speed': predicted - speed_meas[1:]}
    current_offset, voltage_extra = part(extras['current_offset']), part(extras['voltage'])
    current_meas = record.current[first:last] - \
        (zeros if current_offset is None else current_offset)
    voltage = record.voltage[first:last] + (zeros if voltage_extra is None else voltage_extra)
    state = np.vstack([current_meas[:-1], speed_meas[:-1]])
    forcing = np.vstack([voltage[:-1] / values['La'],
                         (torque[:-1] - friction[:-1]) / values['J']])
    predicted = ad @ state + gamma @ forcing
    return {'current': predicted[0] - current_meas[1:], 'speed': predicted[1] - speed_meas[1:]}
