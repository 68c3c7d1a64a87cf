"""
The voltage-to-speed model of records without a current: kS, kV, kA (WPILib's convention).

Without the current, voltage and speed determine only combinations of the motor's
parameters.  With ``La`` neglected the motor is the first-order model of WPILib's
``SimpleMotorFeedforward``::

    u = kS sgn(w) + kV w + kA dw/dt,   kS = Ra Mc/CPhi,  kV = CPhi + Ra b/CPhi,  kA = Ra J/CPhi

and Ra, CPhi, J, b, Mc are not separable (any ``Ra`` fits with ``J, b, Mc`` scaled along).
The fit:

1. start: ``u`` regressed on ``sgn w``, ``w`` and ``dw/dt`` (speed and its derivative
   zero-phase filtered, :func:`regression_start`);
2. output error: the speed simulated exactly under the zero-order-held voltage (the shaft
   model of :func:`~dcmotor_id.simulation.simulate_mechanical` with ``J = kA``,
   ``b = kV``, ``Mc = kS`` and the voltage as its torque: stiction at rest included) fitted
   to the measured speed with :func:`scipy.optimize.least_squares`, one initial speed per
   record;
3. armature lag: where the armature's time constant ``Ta = La/Ra`` shapes the speed, the
   first-order model misreads it as inertia (``kA + Ta Ra b/CPhi``).  The second-order model
   is the exact motor with ``Ra`` fixed at 1 Ohm (the speed does not depend on ``Ra`` when
   ``La, J, b, Mc`` scale with it), ``La = Ta``, ``CPhi = c kV`` (``0 < c <= 1``),
   ``J = kA CPhi``, ``b = (kV - CPhi) CPhi``, ``Mc = kS CPhi``; it is kept when it lowers the
   Bayesian information criterion by :data:`BIC_MARGIN`.  Even a lag far below the sample
   period matters: unmodelled, 0.06 ms on paper motor 2 under a 20 Hz PRBS shifts kS by 5 %.
   ``c`` is poorly determined (it is fitted, not reported: CPhi is not separable in
   practice), and the standard errors of ``kS, kV, kA`` include its spread.

One voltage level in one direction (a step from rest, :func:`one_level_step`) gives a final
speed and a time constant, two numbers for three: ``kS + kV w = u`` ties kS to kV.  kS is then
held at 0 (:class:`FrictionAtZero`): kV is the apparent ``u/w`` at the final speed
(``kV + kS/w``) and kA the time constant times it (``kA u/(u - kS)``), upper bounds of the
true ones when ``kS >= 0``.  The model is then linear and its armature lag trades against kA
(:data:`ONE_LEVEL_NOTE`): the first-order model is kept.

Standard errors: Gauss-Newton (the residual variance over the degrees of freedom times the
inverse of ``J^T J``), scaled by the residual's correlation (:func:`correlation_factor`),
carried to ``kS, kV, kA`` by their derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Callable, Mapping, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import FitError, NotIdentifiableError
from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.signals.filters import central_differences, low_pass, noise_std
from dcmotor_id.simulation import simulate_mechanical, simulate_motor

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: The parameters and their units.
NAMES = ('kS', 'kV', 'kA')
UNITS = {'kS': 'V', 'kV': 'V s/rad', 'kA': 'V s^2/rad'}
#: What each parameter is, in the motor's parameters.
COMBINATIONS = {'kS': 'Ra Mc / CPhi', 'kV': 'CPhi + Ra b / CPhi', 'kA': 'Ra J / CPhi'}
#: The plain statement of what is not separable.
NOT_SEPARABLE = ('not separable without the current: voltage and speed determine only '
                 'kS = Ra Mc/CPhi, kV = CPhi + Ra b/CPhi and kA = Ra J/CPhi; record the '
                 'armature current to identify the motor parameters')
#: The second-order (armature lag) model must lower the BIC by this much to be kept.
BIC_MARGIN = 10.0
#: Said when the time budget ran out during the armature-lag fit.
BUDGET_NOTE = ('the time budget (--max-time) ran out during the armature-lag fit: the '
               'first-order model is kept (kA may hold an armature or drive lag as inertia); '
               'give more time to fit the lag')
#: Said when kS was held at 0 (one voltage level in one direction): no armature-lag fit.
ONE_LEVEL_NOTE = ('one voltage level in one direction: the armature-lag model was not fitted '
                  '(with kS held at 0 the model is linear, and a lag trades against kA: the '
                  'response gives kA + Ta Ra b/CPhi and Ta kA, not each, as no friction '
                  'reverses or breaks away); kA is the first-order one, the acceleration gain '
                  'of a feedforward that neglects the jerk (a lag of the drive or the speed '
                  'sensor included)')
#: Cut-off of the zero-phase filter of the regression start, as a fraction of the sample rate.
START_CUTOFF = 0.05


@dataclass(frozen=True)
class VoltageSpeedFit:
    """
    The voltage-to-speed model fitted to records.

    Attributes
    ----------
    values, stderr : dict
        ``kS`` [V], ``kV`` [V s/rad], ``kA`` [V s^2/rad] and their standard errors.
    start : dict
        The regression start's values.
    initial_speeds : list of float
        Fitted speed at each record's first sample [rad/s].
    nrmse_start_pct, nrmse_pct : float
        Simulation error of the start and of the fit, in percent of the speed's spread.
    noise_std : float
        Standard deviation of the speed residual [rad/s].
    armature_time_constant_s : float or None
        ``Ta = La/Ra`` when the second-order model was kept, else None.
    armature_stderr_s : float or None
        Its standard error.
    acceleration_gain, acceleration_gain_stderr : float or None
        With the armature lag: ``kA + Ta Ra b/CPhi`` [V s^2/rad], the coefficient of
        ``dw/dt`` in the voltage (:func:`acceleration_gain`), and its standard error.
    notes : tuple of str
        What the fit left out (the armature-lag fit, when the time budget ran out).
    theta : tuple of float
        The fitted parameter vector (log kA, log kV, kS and, with the lag, the lag's share
        and ``c``, :func:`motor_of`): the start of further fits.
    states : list of list of float
        Every record's fitted initial state (the speed, and with the lag the current at
        1 Ohm).
    coefficients, coefficient_stderr : dict
        The effects' coefficients (in volts, for a fit with effects) and their standard
        errors, by name.
    correlation_factor : float
        The factor the Gauss-Newton standard errors were scaled by.
    speeds : list of numpy.ndarray
        The simulated speed of every record.
    friction_at_zero : bool
        Whether kS was held at 0 (one voltage level in one direction, :func:`one_level_step`):
        kV and kA are then the apparent ``u/w`` at the final speed and its time constant
        times it, and their standard errors those of these apparent values.

    """

    values: dict[str, float]
    stderr: dict[str, float]
    start: dict[str, float]
    initial_speeds: list[float]
    nrmse_start_pct: float
    nrmse_pct: float
    noise_std: float
    armature_time_constant_s: float | None = None
    armature_stderr_s: float | None = None
    correlation_factor: float = 1.0
    speeds: list[np.ndarray] = field(default_factory=list, repr=False)
    acceleration_gain: float | None = None
    acceleration_gain_stderr: float | None = None
    notes: tuple[str, ...] = ()
    theta: tuple[float, ...] = ()
    states: list[list[float]] = field(default_factory=list, repr=False)
    coefficients: dict[str, float] = field(default_factory=dict)
    coefficient_stderr: dict[str, float] = field(default_factory=dict)
    friction_at_zero: bool = False


def channels(record: Record) -> tuple[np.ndarray, np.ndarray]:
    """Return a prepared record's voltage and speed (both present: checked when prepared)."""
    assert record.voltage is not None and record.speed is not None
    return record.voltage, record.speed


def regression_start(records: Sequence[Record]) -> dict[str, float]:
    """
    Return ``kS, kV, kA`` from ``u`` regressed on ``sgn w, w, dw/dt`` (filtered, zero phase).

    One voltage level in one direction (:func:`one_level_step`) ties ``sgn w`` to the
    constant: ``kS`` is taken as 0 and ``u`` regressed on ``w`` and ``dw/dt`` alone.  The
    values of :func:`regression_fit`.

    Raises
    ------
    NotIdentifiableError
        When the voltage reads 0 V while the motor moves (:func:`zero_voltage_moving`), or
        the regressors are (nearly) dependent (a motor that hardly moves or runs at one speed).

    """
    return regression_fit(records)[0]


def regression_fit(records: Sequence[Record]) -> tuple[dict[str, float], dict[str, float]]:
    """
    Return the regression's ``kS, kV, kA`` (:func:`regression_start`) and standard errors.

    The standard errors are the least squares' on the samples the residual is worth (its
    :func:`correlation_factor` squared per sample); NaN for a value held at a bound (kS
    taken as 0, kS below 0 raised to 0, kV or kA not above 0 replaced).  Raises as
    :func:`regression_start`.
    """
    zero = zero_voltage_moving(records)
    if zero:
        raise NotIdentifiableError(zero)
    columns = slice(1, 3) if one_level_step(records) else slice(0, 3)
    rows, targets = [], []
    for record in records:
        dt = record.sample_period_s
        measured_voltage, measured_speed = channels(record)
        speed = low_pass(measured_speed, START_CUTOFF)
        voltage = low_pass(measured_voltage, START_CUTOFF)
        slope = central_differences(speed, dt)
        moving = np.abs(speed) > 3.0 * noise_std(measured_speed)
        rows.append(np.column_stack([np.sign(speed), speed, slope])[moving][:, columns])
        targets.append(voltage[moving])
    matrix, target = np.concatenate(rows), np.concatenate(targets)
    if matrix.shape[0] < 10 or np.linalg.cond(matrix / np.abs(matrix).max(0)) > 1e8:
        raise NotIdentifiableError(
            'voltage and speed do not determine kS, kV and kA: the motor hardly moves or runs '
            'at one speed; record steps and ramps of the voltage in both directions (a SysId '
            'routine)')
    solution, stderr = np.zeros(3), np.full(3, np.nan)
    solution[columns] = np.linalg.lstsq(matrix, target, rcond=None)[0]
    stderr[columns] = _least_squares_stderr(matrix, target - matrix @ solution[columns])
    kv = max(float(solution[1]), 1e-9)
    ka = float(solution[2]) if solution[2] > 0 else 0.05 * kv
    held = [not solution[0] > 0, not solution[1] > 1e-9, not solution[2] > 0]
    return ({'kS': max(float(solution[0]), 0.0), 'kV': kv, 'kA': ka},
            {name: float('nan') if at_bound else float(error)
             for name, error, at_bound in zip(NAMES, stderr, held)})


def _least_squares_stderr(matrix: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Return the standard errors of a least-squares fit on the samples its residual is worth."""
    dof = max(matrix.shape[0] - matrix.shape[1], 1)
    variance = float(residual @ residual) / dof * correlation_factor(residual) ** 2
    try:
        covariance = np.linalg.pinv(matrix.T @ matrix) * variance
    except np.linalg.LinAlgError:
        return np.full(matrix.shape[1], np.nan)
    return np.sqrt(np.maximum(np.diag(covariance), 0.0))


#: Spread of the voltage while moving, relative to its size, below which it holds one level.
ONE_LEVEL_SPREAD = 0.01


def moving_voltage(records: Sequence[Record]) -> tuple[np.ndarray, np.ndarray]:
    """Return the voltage and the speed's sign over the samples where the motor moves."""
    voltages, signs = [], []
    for record in records:
        voltage, speed = channels(record)
        moving = np.abs(speed) > 3.0 * record.noise_std('speed')
        voltages.append(voltage[moving])
        signs.append(np.sign(speed[moving]))
    return np.concatenate(voltages), np.concatenate(signs)


def zero_voltage_moving(records: Sequence[Record]) -> str:
    """
    Say when the voltage reads 0 V at every sample where the motor moves ('' when it does not).

    A logger that leaves its voltage field unset (as the SEED lab step logs of
    ryg-delta/SEED_Lab_SP24) gives a column of zeros while the speed rises: no voltage drives
    the model, and a fit returns kS, kV and kA at their lower bounds with no error at all.
    """
    voltage, _ = moving_voltage(records)
    if voltage.size == 0 or np.any(voltage != 0.0):
        return ''
    top = max(float(np.max(np.abs(record.speed))) for record in records
              if record.speed is not None)
    return (f'the voltage reads 0 V at every sample while the motor moves (the speed reaches '
            f'{top:.4g} rad/s): that column is not the voltage that drives the motor (a logger '
            'that leaves its voltage field unset); give the column of the voltage at the motor '
            '(--column voltage=NAME), or add the applied voltage to the file')


def one_level_step(records: Sequence[Record]) -> str:
    """
    Say why one voltage level in one direction cannot give kS, kV, kA ('' when it is not so).

    The speed's response to one step is a first-order lag: its final speed and its time
    constant are two numbers for three unknowns, and ``kS + kV w = u`` at the final speed ties
    kS to kV (the regressors ``sgn w``, ``w`` and ``dw/dt`` are dependent).  The fit then holds
    kS at 0 (:func:`fit_voltage_speed`).
    """
    voltage, signs = moving_voltage(records)
    if voltage.size == 0 or np.unique(signs).size > 1:
        return ''
    size = float(np.max(np.abs(voltage)))
    if size == 0.0 or float(np.std(voltage)) > ONE_LEVEL_SPREAD * size:
        return ''
    return (f'the voltage holds one level ({float(np.median(voltage)):.4g} V) in one direction '
            "while the motor moves: the speed's response to one step gives its final speed and "
            'its time constant, two numbers for kS, kV and kA, and kS + kV w = u at the final '
            'speed ties kS to kV; record steps of two or more voltage levels, or both '
            'directions (a SysId routine: ramps and steps both ways)')


def one_magnitude(records: Sequence[Record]) -> str:
    """
    Say when the voltage holds one magnitude in both directions ('' when it does not).

    The steady states then give one equation ``kS + kV w = |u|``: only the reversals, where
    ``sgn w`` changes within the response, separate kS from kV, and the two trade against
    each other beyond what their standard errors say.
    """
    voltage, signs = moving_voltage(records)
    if voltage.size == 0 or np.unique(signs).size < 2:
        return ''
    size = float(np.max(np.abs(voltage)))
    if size == 0.0 or float(np.std(np.abs(voltage))) > ONE_LEVEL_SPREAD * size:
        return ''
    return (f'the voltage takes one magnitude ({size:.4g} V) in both directions: the steady '
            'states give only kS + kV w = |u|, and kS and kV are separated by the reversals '
            'alone, so they trade against each other beyond their standard errors; record two '
            'or more voltage levels to separate them')


def _first_order(theta: np.ndarray, record: Record, initial_speed: float) -> np.ndarray:
    """Speed of the first-order model (``theta`` = log kA, log kV, kS)."""
    return simulate_mechanical(math.exp(theta[0]), math.exp(theta[1]), theta[2],
                               channels(record)[0], record.sample_period_s, initial_speed)


def motor_of(theta: np.ndarray) -> MotorParameters:
    """
    Return the motor (``Ra`` = 1 Ohm) of the second-order parameters.

    ``theta`` = log kA, log kV, kS, log(Ta kV/kA), c with ``CPhi = c kV``: the armature's
    time constant as a share of the mechanical one (at most 1: the two poles of the voltage
    to the speed would otherwise swap their roles).
    """
    ka, kv, ks, share = math.exp(theta[0]), math.exp(theta[1]), theta[2], theta[4]
    ta = math.exp(theta[3]) * ka / kv
    cphi = share * kv
    return MotorParameters(1.0, ta, cphi, ka * cphi, (kv - cphi) * cphi, ks * cphi)


def simulate_speed(values: Mapping[str, float], voltage: np.ndarray, sample_period_s: float,
                   initial_speed: float, lag: tuple[float, float] | None = None,
                   initial_drop: float | None = None) -> np.ndarray:
    """
    Return the speed [rad/s] of a reported voltage-to-speed model under ``voltage`` [V].

    Parameters
    ----------
    values : mapping
        ``kS`` [V], ``kV`` [V s/rad], ``kA`` [V s^2/rad].
    voltage : numpy.ndarray
        Zero-order-held voltage, one value per sample.
    sample_period_s : float
        Sample period [s].
    initial_speed : float
        Speed at the first sample [rad/s].
    lag : tuple of float, optional
        The armature lag as reported: ``(Ta [s], kA + Ta Ra b/CPhi [V s^2/rad])``; the exact
        second-order model then.
    initial_drop : float, optional
        With the lag: the armature current times ``Ra`` at the first sample [V]; None: the
        quasi-static ``u - CPhi w`` (the current settled).

    """
    voltage = np.asarray(voltage, dtype=float)
    theta = theta_of(values, lag)
    if lag is None:
        return simulate_mechanical(math.exp(theta[0]), math.exp(theta[1]), theta[2], voltage,
                                   sample_period_s, initial_speed)
    motor = motor_of(theta)
    current = initial_drop if initial_drop is not None else (  # at Ra = 1 Ohm
        float(voltage[0]) - motor.CPhi * initial_speed if voltage.size else 0.0)
    return simulate_motor(motor, voltage, sample_period_s, (current, initial_speed))[1]


def theta_of(values: Mapping[str, float], lag: tuple[float, float] | None = None) -> np.ndarray:
    """
    Return the fit's parameter vector of a reported model (:func:`simulate_speed`'s arguments).

    3 entries (log kA, log kV, kS) without the lag, 5 with it (:func:`motor_of`).
    """
    ka, kv, ks = float(values['kA']), float(values['kV']), float(values['kS'])
    if lag is None:
        return np.array([math.log(ka), math.log(kv), ks])
    ta, gain = lag
    share = 1.0 - (gain - ka) / (ta * kv)  # CPhi/kV
    return np.array([math.log(ka), math.log(kv), ks, math.log(ta * kv / ka),
                     min(max(share, 1e-3), 1.0)])


def _second_order(theta: np.ndarray, record: Record, initial: np.ndarray) -> np.ndarray:
    """Speed of the exact motor with the armature lag (see :func:`motor_of`)."""
    motor = motor_of(theta)
    _, speed = simulate_motor(motor, channels(record)[0], record.sample_period_s,
                              (initial[1], initial[0]))
    return speed


def _first_order_state(theta: np.ndarray, record: Record, initial: np.ndarray) -> np.ndarray:
    """:func:`_first_order` with the initial state as a vector (its speed alone)."""
    return _first_order(theta, record, initial[0])


#: Initial states per record of each model: the speed; the speed and the current at 1 Ohm.
STATES = {_first_order_state: 1, _second_order: 2}


def states_of(model) -> int:
    """Return the initial states per record of a model (:data:`STATES`, or its ``states``)."""
    return int(getattr(model, 'states', 0) or STATES[model])


def _residual(model, records: Sequence[Record], size: int):
    """Return the residual function of the output-error fit (parameters then initial states)."""
    states = states_of(model)

    def residual(x: np.ndarray) -> np.ndarray:
        parts = []
        for index, record in enumerate(records):
            initial = x[size + states * index:size + states * (index + 1)]
            parts.append(model(x[:size], record, initial) - channels(record)[1])
        return np.concatenate(parts)
    return residual


def _fit(model, records: Sequence[Record], theta: np.ndarray, limits: tuple[list, list],
         progress: Progress | None = None, initial: Sequence[Sequence[float]] | None = None,
         max_nfev: int = 400):
    """
    Run the output-error fit, reporting each evaluation to ``progress``; return scipy's.

    ``limits``: the lower and the upper bounds of ``theta``.  ``initial``: the records'
    initial states to start from (default: the first measured speed, and no current).
    """
    lower, upper = limits
    from scipy.optimize import least_squares  # lazily: the command line's start stays light
    states = states_of(model)
    if initial is None:
        initial = [[float(channels(rec)[1][0])] + [0.0] * (states - 1) for rec in records]
    x0 = np.concatenate([theta, np.ravel(initial)])
    bounds = (np.array(lower + [-np.inf] * x0[theta.size:].size),
              np.array(upper + [np.inf] * x0[theta.size:].size))
    x0 = np.clip(x0, bounds[0] + 1e-12, bounds[1] - 1e-12)
    residual = _residual(model, records, theta.size)

    def reported(x: np.ndarray) -> np.ndarray:
        values = residual(x)
        if progress is not None:  # raises TimeBudgetExceeded past the deadline
            progress.update(cost=0.5 * float(values @ values))
        return values
    return least_squares(reported, x0, bounds=bounds, x_scale='jac', method='trf',
                         xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev)


#: Index of kS in the fit's parameter vector (log kA, log kV, kS, ...).
KS_INDEX = 2


@dataclass(frozen=True)
class FrictionAtZero:
    """
    A voltage-to-speed model with kS held at 0: its parameter vector lacks kS.

    Attributes
    ----------
    base : callable
        The model (:func:`_first_order_state` or :func:`_second_order`) given kS = 0.

    """

    base: Callable[[np.ndarray, Record, np.ndarray], np.ndarray]

    @property
    def states(self) -> int:
        """Return the base model's initial states per record."""
        return states_of(self.base)

    def __call__(self, theta: np.ndarray, record: Record, initial: np.ndarray) -> np.ndarray:
        """Return the base model's speed with kS = 0 put into ``theta``."""
        return self.base(np.insert(theta, KS_INDEX, 0.0), record, initial)


def _fit_friction_at_zero(model, records: Sequence[Record], theta: np.ndarray,
                          limits: tuple[list, list], progress: Progress | None = None):
    """
    Run :func:`_fit` with kS held at 0; return scipy's result with kS put back.

    ``theta`` and ``limits`` as for :func:`_fit` (kS's entry ignored); the result's ``x``
    holds kS = 0, its Jacobian a zero column there and ``held`` kS's index (no variance:
    :func:`_covariance`).
    """
    keep = [k for k in range(theta.size) if k != KS_INDEX]
    lower, upper = limits
    result = _fit(FrictionAtZero(model), records, np.delete(theta, KS_INDEX),
                  ([lower[k] for k in keep], [upper[k] for k in keep]), progress)
    result.x = np.insert(result.x, KS_INDEX, 0.0)
    result.jac = np.insert(result.jac, KS_INDEX, 0.0, axis=1)
    result.held = (KS_INDEX,)
    return result


def correlation_factor(residual: np.ndarray, lags: int = 200) -> float:
    """
    Return the factor on standard errors for a correlated residual (at least 1).

    ``sqrt(1 + 2 sum rho_k)`` over the lags until the autocorrelation first turns negative
    (the effective sample count of a mean; conservative for a regression).
    """
    centred = residual - residual.mean()
    variance = float(centred @ centred)
    if variance == 0:
        return 1.0
    total = 0.0
    for lag in range(1, min(lags, centred.size - 1)):
        rho = float(centred[:-lag] @ centred[lag:]) / variance
        if rho <= 0:
            break
        total += rho
    return math.sqrt(1.0 + 2.0 * total)


def _covariance(result, residual: np.ndarray) -> tuple[np.ndarray, float]:
    """
    Gauss-Newton covariance of the fitted vector, scaled by the residual's correlation.

    The entries the result names ``held`` (kS held at 0, :func:`_fit_friction_at_zero`) were
    not fitted: their rows and columns are 0.
    """
    free = np.setdiff1d(np.arange(result.x.size), list(getattr(result, 'held', ())))
    dof = max(residual.size - free.size, 1)
    variance = float(residual @ residual) / dof
    factor = correlation_factor(residual)
    jac = result.jac[:, free]
    covariance = np.zeros((result.x.size, result.x.size))
    covariance[np.ix_(free, free)] = np.linalg.pinv(jac.T @ jac) * variance * factor ** 2
    return covariance, factor


def _combinations(theta: np.ndarray, covariance: np.ndarray) -> tuple[dict, dict]:
    """Return ``kS, kV, kA`` and their standard errors (log-parametrised kA, kV)."""
    values = {'kS': float(theta[2]), 'kV': math.exp(theta[1]), 'kA': math.exp(theta[0])}
    stderr = {'kS': math.sqrt(max(covariance[2, 2], 0.0)),
              'kV': values['kV'] * math.sqrt(max(covariance[1, 1], 0.0)),
              'kA': values['kA'] * math.sqrt(max(covariance[0, 0], 0.0))}
    return values, stderr


def _bic(residual: np.ndarray, count: int) -> float:
    n = residual.size
    return n * math.log(float(residual @ residual) / n) + count * math.log(n)


def _nrmse_pct(records: Sequence[Record], residual: np.ndarray) -> float:
    spread = np.concatenate([channels(rec)[1] for rec in records])
    scale = float(spread.max() - spread.min()) or 1.0
    return 100.0 * math.sqrt(float(np.mean(residual ** 2))) / scale


def acceleration_gain(theta: np.ndarray, covariance: np.ndarray) -> tuple[float, float]:
    """
    Return ``kA + Ta Ra b/CPhi`` and its standard error from the second-order parameters.

    The exact motor's voltage is ``u = kS sgn w + kV w + (kA + Ta Ra b/CPhi) dw/dt + Ta kA
    d2w/dt2`` (and the friction's reversals through the lag): the speed's linear response
    fixes the coefficients of ``w``, ``dw/dt`` and ``d2w/dt2``, so this gain is well
    determined, while ``kA`` and ``Ta Ra b/CPhi = Ta (kV - CPhi)`` come apart only where the
    friction, acting behind the armature, reverses or breaks away.  It is the acceleration
    gain of a feedforward that neglects the jerk, and what a first-order fit tends to.
    """
    lag = math.exp(theta[3]) * (1.0 - theta[4])  # Ta Ra b/CPhi over kA (Ta kV/kA (1 - c))
    gain = math.exp(theta[0]) * (1.0 + lag)
    slope = np.array([1.0, 0.0, 0.0, lag / (1.0 + lag),
                      -math.exp(theta[3]) / (1.0 + lag)])  # of log gain
    return gain, gain * math.sqrt(max(float(slope @ covariance[:5, :5] @ slope), 0.0))


def _second_fit(records: Sequence[Record], first, progress: Progress | None):
    """Run the armature-lag fit from the first-order one; None when the time budget ran out."""
    dt = records[0].sample_period_s
    share = max(0.1, 2.0 * dt / math.exp(first.x[0] - first.x[1]))
    try:
        if progress is not None:
            progress.set_stage('voltage-speed fit: armature lag')
        return _fit(_second_order, records,
                    np.concatenate([first.x[:3], [math.log(min(share, 0.5)), 0.5]]),
                    ([-np.inf, -np.inf, 0.0, -15.0, 1e-3], [np.inf, np.inf, np.inf, 0.0, 1.0]),
                    progress)
    except TimeBudgetExceeded:
        return None


def fit_voltage_speed(records: Sequence[Record],
                      progress: Progress | None = None) -> VoltageSpeedFit:
    """
    Fit ``kS, kV, kA`` to records of voltage and speed (no current).

    ``progress`` names the two fits and bounds them in time: past its deadline during the
    armature-lag fit, the first-order model is kept (``notes`` says so).  One voltage level
    in one direction (:func:`one_level_step`): kS is held at 0 (``friction_at_zero``), kV
    and kA are the apparent ones (:func:`_fit_friction_at_zero`), and the first-order model
    is kept (:data:`ONE_LEVEL_NOTE`).

    Raises
    ------
    NotIdentifiableError
        Data that do not determine the combinations (see :func:`regression_start`).
    FitError
        The output-error fit does not converge to finite values.
    TimeBudgetExceeded
        The deadline passed before the first-order fit ended.

    """
    start = regression_start(records)
    at_zero = bool(one_level_step(records))  # kS tied to kV: held at 0
    fitter = _fit_friction_at_zero if at_zero else _fit
    theta = np.array([math.log(start['kA']), math.log(start['kV']), start['kS']])
    start_residual = _residual(_first_order_state, records, 3)(
        np.concatenate([theta, [float(channels(rec)[1][0]) for rec in records]]))
    if progress is not None:
        progress.set_stage('voltage-speed fit: first order')
    first = fitter(_first_order_state, records, theta, ([-np.inf, -np.inf, 0.0],
                   [np.inf, np.inf, np.inf]), progress)
    if not np.all(np.isfinite(first.x)):
        raise FitError('the voltage-to-speed fit did not converge; check that the voltage and '
                       'the speed are in SI units (V, rad/s) and of one sign convention')
    if at_zero:  # linear: kA trades against a lag (ONE_LEVEL_NOTE)
        return replace(summary(first, _first_order_state, records, start,
                               _nrmse_pct(records, start_residual), [ONE_LEVEL_NOTE]),
                       friction_at_zero=True)
    second = _second_fit(records, first, progress)
    chosen, size, notes = first, 3, []
    if second is None:
        notes.append(BUDGET_NOTE)
    elif (np.all(np.isfinite(second.x))
            and _bic(second.fun, second.x.size) < _bic(first.fun, first.x.size) - BIC_MARGIN):
        chosen, size = second, 5
    model = _first_order_state if size == 3 else _second_order
    return summary(chosen, model, records, start, _nrmse_pct(records, start_residual), notes)


def summary(chosen, model, records: Sequence[Record], start: dict[str, float],
            nrmse_start_pct: float, notes: Sequence[str] = (),
            names: Sequence[str] = ()) -> VoltageSpeedFit:
    """
    Return the :class:`VoltageSpeedFit` of an output-error fit (scipy's result).

    ``model`` is the fit's model (first or second order, or one with effects whose
    coefficients, named ``names``, follow the base parameters: its ``size`` is the base's).
    """
    size = int(getattr(model, 'size', 3 if model is _first_order_state else 5))
    count = size + len(names)
    covariance, factor = _covariance(chosen, chosen.fun)
    extra: dict = {}
    if size == 5:
        ta = math.exp(chosen.x[3] + chosen.x[0] - chosen.x[1])
        slope = np.array([1.0, -1.0, 0.0, 1.0, 0.0])  # of log Ta
        gain = acceleration_gain(chosen.x, covariance)
        extra = {'armature_time_constant_s': ta,
                 'armature_stderr_s': ta * math.sqrt(max(float(
                     slope @ covariance[:5, :5] @ slope), 0.0)),
                 'acceleration_gain': gain[0], 'acceleration_gain_stderr': gain[1]}
    values, stderr = _combinations(chosen.x[:size], covariance)
    initial = chosen.x[count:].reshape(len(records), states_of(model))
    return VoltageSpeedFit(
        values, stderr, start, [float(state[0]) for state in initial], nrmse_start_pct,
        _nrmse_pct(records, chosen.fun), float(np.std(chosen.fun)), correlation_factor=factor,
        speeds=[model(chosen.x[:count], rec, initial[k]) for k, rec in enumerate(records)],
        notes=tuple(notes), theta=tuple(float(x) for x in chosen.x[:size]),
        states=[[float(x) for x in state] for state in initial],
        coefficients={name: float(chosen.x[size + k]) for k, name in enumerate(names)},
        coefficient_stderr={name: math.sqrt(max(float(covariance[size + k, size + k]), 0.0))
                            for k, name in enumerate(names)}, **extra)
