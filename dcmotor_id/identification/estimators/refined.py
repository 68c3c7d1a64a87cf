"""
The default estimator: exact output error, initialised by continuous-time least squares.

Why this design (bench/README.md has the numbers):

* **Exact model, no Euler bias.**  The fit simulates the motor with the exact ZOH hybrid
  solution of :mod:`dcmotor_id.simulation`, the same one that generates test data, so on
  noise-free data the parameters come back to round-off, at any sample period.
* **Robust to sensor noise.**  Output error compares *simulated* current and speed (driven by
  the voltage alone) with the measured ones, so noise on the measured current and speed never
  enters a regressor: with white noise the estimate is consistent and, with each channel
  weighted by its estimated noise level, it is the maximum-likelihood estimate whose spread
  reaches the Cramer-Rao bound.
* **Honest uncertainty.**  Standard errors come from the Gauss-Newton covariance
  ``s^2 (J^T J)^-1`` at the optimum, with the noise level of each channel estimated from the
  residual; Ka and Ta get theirs by the delta method.  ``info`` carries what the data-based
  (sandwich) covariance of :mod:`dcmotor_id.identification.estimators.uncertainty` needs; identify
  uses it.
* **Initial state and several records.**  Every record has its own estimated initial state
  ``(i0, w0)``; the physical parameters are shared (multi-experiment).
* **Good start.**  Output error is a non-convex fit, so it starts from the best (lowest
  simulation error) of several continuous-time least-squares estimates on low-pass filtered
  signals (a state-variable-filter method, at three cut-offs) and the paper's neurons.
"""

from __future__ import annotations

from typing import Any, Callable, cast, ClassVar, Mapping, Sequence

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import (derived_stderr, derived_values, make_admissible,
                                   MotorParameters, parameter_names, POSITIVE_NAMES, state_matrix)
from dcmotor_id.identification.criterion import (AR_PASSES, ar_settled,
                                                 check_position_error_model, fitted_outputs,
                                                 integrate_speed, noise_level, position_ar,
                                                 whiten)
from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm, StateTerm
from dcmotor_id.identification.estimators.jacobian import record_sparse_jacobian
from dcmotor_id.identification.estimators.normal_equations import NormalEquations
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.identification.estimators.uncertainty import block_scores, JACKKNIFE_MAX_RECORDS
from dcmotor_id.signals.filters import low_pass, noise_std
from dcmotor_id.simulation import (combine_contributions, EXACT_FIELDS, HybridSystem,
                                   motor_forcing, MotorEffects, simulate_mechanical,
                                   simulate_mechanical_effects, simulate_motor_effects)

__all__ = ['OutputErrorModel', 'RefinedEstimator', 'StateTerm', 'STATE_OVERSAMPLE']
_MISFIT = ('the motor model does not reproduce the data. Check that the columns are what their '
           'names say (units, signs: current and speed positive for a positive voltage), and '
           'that the input changes between at least two levels (a single constant input '
           'cannot separate all parameters: record a step between two non-zero levels)')


def _diverged(error: BaseException) -> str:
    """Describe a failure of the simulation during the fit (its message may be empty)."""
    text = str(error)
    if text:
        return text
    return (f'{type(error).__name__} in the simulation: a parameter ran to zero or infinity '
            'on the way')


#: Channels of exogenous terms: the linear ones of :class:`ExogenousTerm` and ``state``
#: (:class:`StateTerm`, an effect simulated exactly inside the model).
_CHANNELS = ('voltage', 'torque', 'current', 'speed', 'state')
#: Sub-steps per sample when state-dependent effects are simulated.
STATE_OVERSAMPLE = 2
#: Samples the start-point search looks at, at most (windows spread over longer records).
START_SAMPLES = 250_000
#: Windows per record of the start-point search on long records.
START_WINDOWS = 5


class OutputErrorModel:
    """
    The motor (or the shaft alone) with exogenous terms, simulated for a parameter dict.

    Parameters
    ----------
    records : list of Record
        Checked records with current and speed (and voltage unless mechanical-only).
    torque_constant : float, optional
        Given for the mechanical-only mode.
    terms : sequence of ExogenousTerm
        Extra linear terms (effects).
    quasi_static : bool
        The La -> 0 limit of the armature (an electrical time constant far below the sample
        period): ``J dw/dt = CPhi (u - CPhi w) / Ra - b w - Mc sgn w`` and
        ``i = (u - CPhi w) / Ra``; La is not a parameter then.
    criterion : str
        ``speed`` (default), ``position`` or ``both``: the channels compared
        (:func:`dcmotor_id.identification.criterion.fitted_outputs`).  With the position, every
        record's
        initial state ends with its initial position and :meth:`simulate` also returns the
        position (the integral of the simulated speed).

    """

    def __init__(self, records: Sequence[Any], torque_constant: float | None = None,
                 terms: Sequence[ExogenousTerm] = (), quasi_static: bool = False,
                 criterion: str = 'speed') -> None:
        self.records = list(records)
        self.torque_constant = torque_constant
        self.mechanical_only = torque_constant is not None
        self.terms = tuple(terms)
        for term in self.terms:
            if term.channel not in _CHANNELS:
                raise ValueError(f'term {term.name}: channel must be one of {_CHANNELS}')
            if len(term.regressors) != len(self.records):
                raise ValueError(f'term {term.name}: one regressor per record is needed')
        self.quasi_static = bool(quasi_static) and not self.mechanical_only
        self.base_names = tuple(name for name in parameter_names(self.mechanical_only)
                                if not (self.quasi_static and name == 'La'))
        # The simulated states (the ODE's), the compared channels, and every record's initial
        # state (the ODE's, then the initial position when the position is compared).
        self.dynamic = ('speed',) if self.mechanical_only else ('current', 'speed')
        self.criterion = criterion
        self.outputs = fitted_outputs(self.mechanical_only, criterion)
        self.states = self.dynamic + (('position',) if 'position' in self.outputs else ())
        # AR(1) coefficient of every record's position error (0: white, compared sample by
        # sample; :func:`dcmotor_id.identification.criterion.position_ar`), set by the fit.
        self.position_ar = [0.0] * len(self.records)
        self.position_rms = [0.0] * len(self.records)
        # The period is a median over the record: computed once, not at every simulation.
        self.sample_periods_s = [rec.sample_period_s for rec in self.records]
        # Mechanical-only mode: the sampled current is the input.  It varies within a sample,
        # so the torque held over [t_k, t_k+1) is its trapezoidal mean (i[k] + i[k+1]) / 2;
        # holding i[k] instead biases J by O(dT) (0.5 % at 1 kHz for motor 2, bench/README.md).
        self.held_currents = [np.append(0.5 * (rec.current[:-1] + rec.current[1:]),
                                        rec.current[-1]) if self.mechanical_only else None
                              for rec in self.records]

    def _state_effects(self, values: Mapping[str, float]) -> tuple[MotorEffects, bool]:
        """
        Return the effects the state terms simulate and whether they need sub-steps.

        Without state terms: no effects.  Effects only on fields the hybrid solver handles
        exactly (:data:`~dcmotor_id.simulation.EXACT_FIELDS`) keep the exact fast path.
        """
        state_terms = [term for term in self.terms if isinstance(term, StateTerm)]
        effects = combine_contributions(term.contribution(values[term.name])
                                        for term in state_terms)
        fields = frozenset().union(*(term.fields() for term in state_terms))
        return effects, bool(fields - EXACT_FIELDS)

    def _channel(self, values, channel, index):
        total = None
        for term in self.terms:
            if term.channel == channel:
                contribution = values[term.name] * term.regressors[index]
                total = contribution if total is None else total + contribution
        return total

    def simulate(self, values: Mapping[str, float], index: int,
                 initial_state: Sequence[float] | np.ndarray) -> dict[str, np.ndarray]:
        """
        Simulate record ``index``; return a dict of output arrays (current, speed, position).

        ``initial_state`` is the ODE's (``(i0, w0)`` or ``(w0,)``), optionally followed by
        the initial position: then ``position``, the integral of the simulated speed, is
        returned too (also when the position is not compared).
        """
        n_dynamic = len(self.dynamic)
        out = self._simulate_dynamic(values, index, initial_state[:n_dynamic])
        speed = out.pop('position_speed')
        if len(initial_state) > n_dynamic:
            out['position'] = integrate_speed(speed, self.sample_periods_s[index],
                                              float(initial_state[n_dynamic]))
        return out

    def _simulate_dynamic(self, values, index, initial_state):
        """Simulate the ODE; ``position_speed`` is the speed state (no output offsets)."""
        rec = self.records[index]
        dt = self.sample_periods_s[index]
        extra_torque = self._channel(values, 'torque', index)
        effects, substeps = self._state_effects(values)
        delta = effects.coulomb_delta_Nm
        if self.mechanical_only:
            held = cast(np.ndarray, self.held_currents[index])
            torque = cast(float, self.torque_constant) * held
            if extra_torque is not None:
                torque = torque + extra_torque
            if substeps:
                speed, _ = simulate_mechanical_effects(
                    values['J'], values['b'], values['Mc'], torque, dt, effects,
                    initial_state[0], oversample=STATE_OVERSAMPLE)
                out = {'speed': speed}
            else:
                out = {'speed': simulate_mechanical(
                    values['J'], values['b'], max(values['Mc'] + delta, 0.0), torque, dt,
                    initial_state[0], max(values['Mc'] - delta, 0.0))}
        elif self.quasi_static:
            out = self._simulate_quasi_static(values, index, initial_state, effects, substeps)
        else:
            params = MotorParameters.from_dict(values)
            extra_voltage = self._channel(values, 'voltage', index)
            if substeps:
                current, speed, _ = simulate_motor_effects(
                    params, rec.voltage, dt, effects, initial_state, extra_voltage,
                    extra_torque, oversample=STATE_OVERSAMPLE)
                out = {'current': current, 'speed': speed}
            else:
                forcing = motor_forcing(params, rec.voltage, extra_voltage, extra_torque)
                system = HybridSystem(state_matrix(params),
                                      max(values['Mc'] + delta, 0.0) / values['J'],
                                      max(values['Mc'] - delta, 0.0) / values['J'])
                states = system.simulate(forcing, initial_state, dt)
                out = {'current': states[:-1, 0], 'speed': states[:-1, 1]}
        out['position_speed'] = out['speed']
        for channel in self.dynamic:
            offset = self._channel(values, channel, index)
            if offset is not None:
                out[channel] = out[channel] + offset
        return out

    def _simulate_quasi_static(self, values, index, initial_state, effects, substeps):
        """
        Simulate the La -> 0 limit: the shaft driven by ``CPhi (u - CPhi w) / Ra``.

        The shaft alone with viscous friction ``b + CPhi^2 / Ra`` and torque ``CPhi u / Ra``
        (``u`` held over each sample, as in the full model); the current sampled at ``t_k``
        is the one settled under ``u[k-1]``: ``(u[k-1] - CPhi w[k]) / Ra`` (``i0`` first).
        """
        rec = self.records[index]
        dt = self.sample_periods_s[index]
        ra, cphi = values['Ra'], values['CPhi']
        voltage = np.asarray(rec.voltage, dtype=float)
        extra_voltage = self._channel(values, 'voltage', index)
        if extra_voltage is not None:
            voltage = voltage + extra_voltage
        torque = cphi * voltage / ra
        extra_torque = self._channel(values, 'torque', index)
        if extra_torque is not None:
            torque = torque + extra_torque
        viscous = values['b'] + cphi ** 2 / ra
        delta = effects.coulomb_delta_Nm
        if substeps:
            speed, _ = simulate_mechanical_effects(values['J'], viscous, values['Mc'], torque,
                                                   dt, effects, initial_state[1],
                                                   oversample=STATE_OVERSAMPLE)
        else:
            speed = simulate_mechanical(values['J'], viscous, max(values['Mc'] + delta, 0.0),
                                        torque, dt, initial_state[1],
                                        max(values['Mc'] - delta, 0.0))
        current = np.empty_like(speed)
        current[0] = initial_state[0]
        current[1:] = (voltage[:-1] - cphi * speed[1:]) / ra
        return {'current': current, 'speed': speed}

    def measured(self, index: int, channel: str) -> np.ndarray:
        """Measured output ``channel`` of record ``index``."""
        return getattr(self.records[index], channel)


def _windows(records, total):
    """Cut :data:`START_WINDOWS` evenly spread windows of ``total`` samples in all."""
    per_record = max(total // len(records), 1)
    windows = []
    for rec in records:
        if len(rec) <= per_record:
            windows.append(rec)
            continue
        width = max(per_record // START_WINDOWS, 1)
        starts = np.linspace(0, len(rec) - width, START_WINDOWS).astype(int)
        windows.extend(rec.slice(int(start), int(start) + width) for start in starts)
    return windows


def _svf_candidates(records, torque_constant, cutoffs_fraction=(0.1, 0.02, 0.004)):
    """Continuous-time least squares on low-pass filtered signals, one estimate per cut-off."""
    mechanical_only = torque_constant is not None
    candidates = []
    for fraction in cutoffs_fraction:
        rows_e, rhs_e, rows_m, rhs_m = [], [], [], []
        for rec in records:
            dt = rec.sample_period_s
            n = len(rec)
            trim = min(int(3.0 / (fraction * 2 * np.pi)) + 2, n // 4)
            if n - 2 * trim < 20:
                continue

            def lowpass(values, fraction=fraction):
                return low_pass(values, fraction, order=4)
            current = lowpass(rec.current)
            speed = lowpass(rec.speed)
            sign = lowpass(np.sign(rec.speed))
            keep = slice(trim, n - trim)
            d_speed = np.gradient(speed, dt)
            if mechanical_only:
                rows_m.append(np.column_stack([d_speed, speed, sign])[keep])
                rhs_m.append((torque_constant * current)[keep])
                continue
            held = np.concatenate([[rec.voltage[0]], 0.5 * (rec.voltage[1:] + rec.voltage[:-1])])
            voltage = lowpass(held)
            d_current = np.gradient(current, dt)
            rows_e.append(np.column_stack([d_current, current, speed])[keep])
            rhs_e.append(voltage[keep])
            rows_m.append(np.column_stack([d_speed, speed, sign])[keep])
            rhs_m.append(current[keep])
        if not rows_m:
            continue
        try:
            if not all(np.all(np.isfinite(part)) for part in rows_m + rhs_m + rows_e + rhs_e):
                # LAPACK's least-squares solver never returns on an inf or NaN (overflowed
                # derivatives of extreme values): skip this start point instead
                raise np.linalg.LinAlgError('non-finite start-point equations')
            mech = np.linalg.lstsq(np.vstack(rows_m), np.concatenate(rhs_m), rcond=None)[0]
            if mechanical_only:
                values = {'J': mech[0], 'b': mech[1], 'Mc': mech[2]}
            else:
                la, ra, cphi = np.linalg.lstsq(np.vstack(rows_e), np.concatenate(rhs_e),
                                               rcond=None)[0]
                values = {'Ra': ra, 'La': la, 'CPhi': cphi, 'J': mech[0] * cphi,
                          'b': mech[1] * cphi, 'Mc': mech[2] * cphi}
        except np.linalg.LinAlgError:
            continue
        candidates.append(values)
    return candidates


class _Pass:
    """
    One evaluation of the fit at a point ``z``: cost and (optionally) normal equations.

    ``hessian``, ``gradient`` and ``blocks`` are in the fit's coordinates ``z``; ``sums`` are
    the unweighted residual sums of squares per record and channel.  An analytic pass keeps
    its per-channel sums (``parts``), so :meth:`reweighted` gives the same pass under new noise
    weights without simulating again.
    """

    def __init__(self, cost, hessian=None, gradient=None, sums=None, blocks=None,
                 block_record=None, parts=None, record_normal=None):
        self.cost = cost
        self.record_normal = record_normal
        self.hessian = hessian
        self.gradient = gradient
        self.sums = sums
        self.blocks = blocks
        self.block_record = block_record
        self.parts = parts

    def reweighted(self, noise, outputs):
        """Return this pass under the noise levels ``noise`` (None: simulate again)."""
        if self.parts is None or self.hessian is None:
            return None
        # ``base``: the weights the records' sums were computed with, not those of a pass
        # reweighted before (rescaling relative to those left J^T J in the first pass's
        # weights when a pass took no step, e.g. warm-started at the optimum: the standard
        # errors were off by the ratio of the first pass's noise guess, 1 % of the spread, to
        # the real noise, 10x too large at 0.1 % noise)
        equations, results, base, chain = self.parts
        new = [np.array([1.0 / level[channel] for channel in outputs]) for level in noise]
        return _assemble(equations, results, new, chain,
                         [(w / w_base) ** 2 for w, w_base in zip(new, base)], base)


class _FitProblem:
    """
    One output-error fit: the model, the coordinates ``z`` it is solved in, and their passes.

    Base parameters are fitted as logarithms (positive, relative steps); term coefficients
    and the free initial states as multiples of their typical magnitude (``scales``).  Pinned
    initial states (``initial_state='measured'``) stay at the records' first samples.

    Parameters
    ----------
    model : OutputErrorModel
        The model and its records.
    start_base : dict
        Start of the base parameters (:meth:`RefinedEstimator._start`).
    initial_state : str
        ``estimate`` or ``measured`` (:func:`free_states`).
    warm_states : sequence, optional
        Start of every record's initial state (used when there is one per record).
    progress : callable, optional
        Called with ``cost=`` at every evaluation.

    """

    def __init__(self, model: OutputErrorModel, start_base: Mapping[str, float],
                 initial_state: str, warm_states: Sequence[Sequence[float]] | None,
                 progress: Callable[..., None] | None) -> None:
        records = model.records
        self.model, self.records, self.progress = model, records, progress
        self.start_base, self.initial_state = start_base, initial_state
        self.names = list(model.base_names) + [term.name for term in model.terms]
        self.n_base = len(model.base_names)
        self.n_state = len(model.states)
        self.free = free_states(model.states, initial_state)
        self.first_samples = np.array([[float(getattr(rec, channel)[0])
                                        for channel in model.states] for rec in records])
        warm = warm_states if warm_states is not None and len(
            warm_states) == len(records) else None
        self.scales, self.z0 = self._coordinates(warm)
        self.pooled = {channel: max(float(np.std(np.concatenate(
            [getattr(rec, channel) for rec in records]))), 1e-12) for channel in model.outputs}
        self.analytic = has_analytic_sensitivities(model)
        self.equations = NormalEquations(model) if self.analytic else None
        if self.equations is not None:
            self.equations.free_states = self.free

    def _coordinates(self, warm):
        """Return the scales of ``z`` and the start point ``z0``."""
        model, start_base = self.model, self.start_base
        floor = {name: 1e-9 * max(start_base.values()) for name in model.base_names}
        start = [np.log(max(start_base[name], floor[name], 1e-300))
                 for name in model.base_names]
        magnitudes = [1.0] * self.n_base + [term.scale for term in model.terms]
        start += [term.initial / term.scale for term in model.terms]
        for index, rec in enumerate(self.records):
            for position, channel in enumerate(model.states):
                if not self.free[position]:
                    continue
                values = getattr(rec, channel)
                scale = max(float(np.std(values)), 1e-9)
                magnitudes.append(scale)
                first = float(values[0]) if warm is None or position >= len(
                    warm[index]) else float(warm[index][position])
                start.append(first / scale)
        return np.array(magnitudes), np.array(start)

    def first_noise(self) -> list[dict[str, float]]:
        """
        Noise level per record and channel of the first pass: 1 % of the pooled spread.

        Records may come from different sensors or ranges; later passes weight by the
        residual level (:meth:`residual_noise`).
        """
        return [{channel: 0.01 * self.pooled[channel] for channel in self.model.outputs}
                for _ in self.records]

    def residual_noise(self, current: Any) -> list[dict[str, float]]:
        """Noise level per record and channel: the residual's RMS at the pass ``current``."""
        return [{channel: max(float(np.sqrt(current.sums[index][position] / len(rec))),
                              1e-13 * self.pooled[channel])
                 for position, channel in enumerate(self.model.outputs)}
                for index, rec in enumerate(self.records)]

    def unpack(self, z: np.ndarray) -> tuple[dict[str, float], np.ndarray, np.ndarray]:
        """Return the parameter values, the records' initial states and ``theta`` at ``z``."""
        theta = z * self.scales
        with np.errstate(over='ignore'):  # a wild step: an infinite cost, rejected
            theta[:self.n_base] = np.exp(z[:self.n_base])
        values = dict(zip(self.names, theta[:len(self.names)]))
        if all(self.free):
            states = theta[len(self.names):].reshape(len(self.records), self.n_state)
        else:
            states = self.first_samples.copy()
            states[:, self.free] = theta[len(self.names):].reshape(len(self.records),
                                                                   sum(self.free))
        return values, states, theta

    def chain_of(self, theta: np.ndarray) -> np.ndarray:
        """Return ``d theta / d z`` (one entry per column of ``z``)."""
        chain = self.scales.copy()
        chain[:self.n_base] = theta[:self.n_base]
        return chain

    def residual(self, z: np.ndarray, noise: Sequence[Mapping[str, float]],
                 only: Any = None) -> list[np.ndarray | None]:
        """
        Return every record's weighted residual at ``z`` (channels concatenated).

        ``only``: the records simulated (the others' parts are None), for the columns of an
        initial state, which move their own record's residual alone.
        """
        model = self.model
        values, states, _ = self.unpack(z)
        parts: list[np.ndarray | None] = []
        for index in range(len(self.records)):
            if only is not None and index not in only:
                parts.append(None)
                continue
            out = model.simulate(values, index, states[index])
            errors = []
            for channel in model.outputs:
                error = out[channel] - model.measured(index, channel)
                if channel == 'position':
                    error = whiten(error, model.position_ar[index])
                errors.append(error / noise[index][channel])
            parts.append(np.concatenate(errors))
        if self.progress is not None:
            self.progress(cost=float(sum(part @ part for part in parts if part is not None)))
        return parts

    def evaluator(self, noise: Sequence[Mapping[str, float]]) -> Callable[..., Any]:
        """Return ``evaluate(z, with_sens)`` under the noise levels ``noise``."""
        return lambda point, with_sens: self.evaluate(point, noise, with_sens)

    def evaluate(self, z: np.ndarray, noise: Sequence[Mapping[str, float]],
                 with_sens: bool) -> Any:
        """Return the :class:`_Pass` at ``z`` (with the normal equations if ``with_sens``)."""
        values, states, theta = self.unpack(z)
        if not np.all(np.isfinite(theta)):
            return _Pass(np.inf)
        try:
            with np.errstate(all='ignore'):
                if self.analytic:
                    result = _analytic_pass(self.equations, values, states, noise,
                                            self.chain_of(theta), with_sens, self.model.outputs)
                    if self.progress is not None:
                        # The numeric pass reports every simulation (in ``residual``).
                        self.progress(cost=float(result.cost))
                    return result
                return _numeric_pass(lambda point, only=None: self.residual(point, noise, only),
                                     z, self.model, noise, with_sens, len(self.names))
        except (ZeroDivisionError, OverflowError, FloatingPointError, ValueError) as error:
            # A parameter ran to zero or infinity on the way (the simulation kernels raise
            # on a division by zero): the data do not fit this model.
            raise FitError(f'the output-error fit diverged ({_diverged(error)}): '
                           + _MISFIT) from None

    def estimate(self, method: str, z: np.ndarray, final: Any,
                 noise: list[dict[str, float]], nfev: int) -> Estimate:
        """Return the :class:`Estimate` at the optimum ``z`` (``final``: its pass)."""
        model, names, n_base = self.model, self.names, self.n_base
        values, states, theta = self.unpack(z)
        n_residuals = sum(len(rec) for rec in self.records) * len(model.outputs)
        dof = max(n_residuals - z.shape[0], 1)
        s2 = float(final.cost) / dof
        cov_z = s2 * np.linalg.pinv(final.hessian)
        chain = self.chain_of(theta)
        covariance = cov_z * np.outer(chain, chain)
        stderr_all = np.sqrt(np.maximum(np.diag(covariance), 0.0))
        parameters = {name: float(values[name]) for name in names}
        stderr = {name: float(stderr_all[position]) for position, name in enumerate(names)}
        if 'La' in model.base_names:
            parameters.update(derived_values(parameters))
            stderr.update(derived_stderr(parameters, covariance[:n_base, :n_base],
                                         list(model.base_names)))
        if any(model.position_ar):
            # The position's residual level (not its AR(1) innovations': the weights).
            noise = [{**level, 'position': max(rms, 1e-13 * self.pooled['position'])}
                     for level, rms in zip(noise, model.position_rms)]
        info = self._info(final, noise, nfev, s2, covariance, chain)
        return Estimate(method, parameters, stderr,
                        [tuple(float(v) for v in row) for row in states], info)

    def _info(self, final, noise, nfev, s2, covariance, chain):
        """Return the estimate's ``info`` (:class:`RefinedEstimator`)."""
        model, records, names = self.model, self.records, self.names
        return {
            'nfev': int(nfev),
            'noise_std': {channel: float(np.sqrt(
                sum(len(rec) * level[channel] ** 2 for rec, level in zip(records, noise))
                / sum(len(rec) for rec in records))) for channel in model.outputs},
            'noise_std_per_record': noise,
            'start': {name: float(self.start_base[name]) for name in model.base_names},
            'residual_rms_weighted': float(np.sqrt(s2)),
            'covariance': covariance[:len(names), :len(names)].tolist(),
            'names': names,
            'quasi_static': model.quasi_static,
            'criterion': model.criterion,
            'initial_state': self.initial_state,
            'position_ar': list(model.position_ar),
            'sensitivities': 'analytic' if self.analytic else 'finite differences',
            # What the data-based covariance needs
            # (dcmotor_id.identification.estimators.uncertainty): the fit's normal equations in its
            # internal coordinates z (theta = chain * dz locally) at the optimum, with the final
            # noise weights: J^T J, the score sums J^T r over blocks of samples and the record of
            # each block.
            'normal_matrix': final.hessian,
            'block_scores': final.blocks,
            'block_record': final.block_record,
            'record_normal_matrices': final.record_normal,
            'chain': chain,
        }


class RefinedEstimator:
    """
    Exact output-error estimator with noise-weighted channels and standard errors.

    Parameters
    ----------
    max_nfev : int
        Bound on the evaluations (simulations, with or without sensitivities) per
        least-squares pass.
    reweight_passes : int
        Passes re-estimating each channel's noise level (2 gives the ML weighting).
    initial : dict, optional
        A start point for the base parameters; skips the automatic initialisation.
    quasi_static : bool
        Fit the La -> 0 limit of the armature (:class:`OutputErrorModel`); no La then.
    initial_state : str
        ``estimate`` (default: every record's initial state is fitted) or ``measured`` (pinned
        to the record's first samples).
    progress : callable, optional
        Called with ``(iteration, cost)`` at every evaluation of the fit
        (:class:`dcmotor_id.core.progress.Progress`; it may raise to stop the fit).
    initial_states : sequence, optional
        Start of every record's initial state (a warm start, e.g. from an earlier fit of the
        same records); default: the first measured samples.  Ignored when pinned.
    criterion : str
        ``speed`` (default), ``position`` or ``both``: the channels compared
        (:class:`OutputErrorModel`).
    position_ar : sequence of float, optional
        Start of every record's AR(1) coefficient of the position error (a warm start, e.g.
        from an earlier fit of the same records; :func:`_update_position_ar`); default white.
    position_error : str
        The position error's model, ``adaptive`` (default) or ``white``
        (:func:`~dcmotor_id.identification.criterion.check_position_error_model`).
    retry : bool
        A fit on the position that does not converge is tried once more with
        :data:`POSITION_NFEV_FACTOR` times ``max_nfev`` (default).  False: the fit keeps its
        bound (the discovery loop's candidate refits with effect terms: a candidate that needs
        more is not the one to keep).

    """

    name: ClassVar[str] = 'refined'
    #: Effect terms are supported (the discovery loop uses this estimator).
    supports_terms: ClassVar[bool] = True

    def __init__(self, max_nfev: int = 100, reweight_passes: int = 2,
                 initial: Mapping[str, float] | None = None, quasi_static: bool = False,
                 initial_state: str = 'estimate',
                 progress: Callable[..., None] | None = None,
                 initial_states: Sequence[Sequence[float]] | None = None,
                 criterion: str = 'speed',
                 position_ar: Sequence[float] | None = None, retry: bool = True,
                 position_error: str = 'adaptive') -> None:
        if initial_state not in ('estimate', 'measured'):
            raise ValueError(f'initial_state must be estimate or measured, not {initial_state}')
        self.max_nfev = max_nfev
        self.reweight_passes = reweight_passes
        self.initial = initial
        self.quasi_static = quasi_static
        self.initial_state = initial_state
        self.progress = progress
        self.initial_states = initial_states
        self.criterion = criterion
        self.position_ar = position_ar
        self.retry = retry
        self.position_error = check_position_error_model(position_error)

    def fit(self, records: Sequence[Any], torque_constant: float | None = None,
            terms: Sequence[ExogenousTerm] = ()) -> Estimate:
        """
        Fit the records; return an :class:`Estimate` with standard errors.

        With the position compared and the initial states estimated, a fit whose initial
        position ends far from the first samples (:func:`moved_start`: the integral's offset
        absorbed a misfit) is repeated with the initial states pinned to the first samples,
        as ``dcmotor-id validate`` starts its simulations; ``info['initial_state']`` then says
        ``measured`` and ``info['moved_start']`` why.
        """
        position = 'position' in fitted_outputs(torque_constant is not None, self.criterion)
        try:
            estimate = self._fit(records, torque_constant, terms, self.initial_state)
        except FitError as error:
            if not position or (terms and not self.retry) or \
                    'did not converge' not in str(error):
                raise
            # The position's initial state (a record that starts at rest: the speed's
            # sensitivity vanishes while stuck) can take the fit many small steps near its
            # optimum: once more, with POSITION_NFEV_FACTOR times the evaluations (a base
            # fit, with its effects or not; the discovery loop's candidate refits, ``retry``
            # false, keep their bound).
            estimate = self._fit(records, torque_constant, terms, self.initial_state,
                                 POSITION_NFEV_FACTOR * self.max_nfev)
        if self.initial_state != 'estimate' or not position:
            return estimate
        moved = moved_start(records, [state[-1] for state in estimate.initial_states])
        if moved is None:
            return estimate
        pinned = self._fit(records, torque_constant, terms, 'measured',
                           position_ar=estimate.info['position_ar'])
        pinned.info['moved_start'] = moved
        return pinned

    def _fit(self, records, torque_constant, terms, initial_state, max_nfev=None,
             position_ar=None):
        """Fit with the initial states estimated or pinned (``initial_state``)."""
        max_nfev = self.max_nfev if max_nfev is None else max_nfev
        model = OutputErrorModel(records, torque_constant, terms, self.quasi_static,
                                 self.criterion)
        warm_ar = self.position_ar if position_ar is None else position_ar
        if warm_ar is not None and len(warm_ar) == len(records):
            model.position_ar = [float(value) for value in warm_ar]
        problem = _FitProblem(model, self._start(model), initial_state, self.initial_states,
                              self.progress)
        z, final, noise, total_nfev = self._passes(problem, max_nfev)
        values = problem.unpack(z)[0]
        degenerate = [name for name in model.base_names if not np.isfinite(values[name])
                      or (name in POSITIVE_NAMES and not 1e-200 < values[name] < 1e200)]
        if degenerate:
            raise FitError(f'the output-error fit diverged ({", ".join(degenerate)} went to zero '
                           'or infinity): ' + _MISFIT)
        if final is None:
            final = problem.evaluate(z, noise, True)
            total_nfev += 1
        return problem.estimate(self.name, z, final, noise, total_nfev)

    def _passes(self, problem, max_nfev):
        """
        Run the weighted least-squares passes; return ``(z, pass, noise, evaluations)``.

        Every pass re-estimates each record's and channel's noise level from its residual
        (which makes the fit the Gaussian maximum-likelihood estimate) and, with the position
        compared, the position error's AR(1) model; the returned pass is None when the last
        one moved that model (the covariance then needs a new simulation).
        """
        model, z0, n_base = problem.model, problem.z0, problem.n_base
        noise = problem.first_noise()
        # Tolerances of 1e-8 leave the parameters within 1e-3 of a standard error of the
        # converged optimum (noise-free: round-off); tighter ones only add iterations spent in
        # the weakly determined initial-state directions of a record that starts at rest.
        z, current, damping = z0, None, None
        total_nfev, converged = 0, True
        passes, extra = max(1, self.reweight_passes), 0
        while passes > 0:
            passes -= 1
            z, current, nfev, converged, damping = _levenberg_marquardt(
                problem.evaluator(noise), z, max_nfev, current=current, damping=damping)
            total_nfev += nfev
            if not np.all(np.isfinite(z)):
                raise FitError('the output-error fit diverged (non-finite parameters): ' + _MISFIT)
            noise = problem.residual_noise(current)
            white = not any(model.position_ar)
            if _update_position_ar(model, *problem.unpack(z)[:2], self.position_error):
                # The position's error model moved: the next pass simulates again, and runs
                # (up to AR_PASSES more) until it settles.  Leaving the white error model, a
                # base parameter the white fit ran below COLLAPSED of its start restarts there:
                # a friction at zero has no gradient (its sign kink) to come back by.
                current = None
                if white:
                    collapsed = z[:n_base] < z0[:n_base] + np.log(COLLAPSED)
                    z = z.copy()
                    z[:n_base][collapsed] = z0[:n_base][collapsed]
                if passes == 0 and extra < AR_PASSES:
                    passes, extra = 1, extra + 1
                continue
            # The next pass (and the covariance) starts from this point under the new weights:
            # an analytic pass is rescaled channel by channel, others are simulated again.
            current = current.reweighted(noise, model.outputs)
        if not converged:
            # Mostly a fit wandering towards a degenerate motor (parameters running to zero or
            # infinity): the data do not fit the model.
            raise FitError('the output-error fit did not converge (the number of function '
                           'evaluations is exceeded): ' + _MISFIT)
        return z, current, noise, total_nfev

    def _start(self, model):
        """Pick the start with the lowest simulation error among the candidates."""
        if self.initial is not None:
            return {name: float(self.initial[name]) for name in model.base_names}
        records, constant = model.records, model.torque_constant
        if not model.terms and sum(len(rec) for rec in records) > START_SAMPLES:
            # A start point needs seconds of data, not hours: windows spread over each record
            # keep the search's time and memory bounded (the fit itself uses every sample).
            records = _windows(records, START_SAMPLES)
            model = OutputErrorModel(records, constant, quasi_static=model.quasi_static,
                                     criterion=model.criterion)
        candidates = _svf_candidates(records, constant)
        try:
            paper = PaperEstimator().fit(records, torque_constant=constant).parameters
            candidates.append({name: paper[name] for name in model.base_names})
        except (FitError, ZeroDivisionError, FloatingPointError, np.linalg.LinAlgError):
            pass
        best, best_cost = None, np.inf
        zero_terms = {term.name: term.initial for term in model.terms}
        for candidate in candidates:
            admissible = make_admissible(candidate)
            if admissible is None:
                continue
            values = {**admissible, **zero_terms}
            cost = 0.0
            with np.errstate(all='ignore'):
                for index, rec in enumerate(records):
                    state = [float(getattr(rec, channel)[0]) for channel in model.states]
                    out = model.simulate(values, index, state)
                    for channel in model.outputs:
                        measured = getattr(rec, channel)
                        error = np.mean((out[channel] - measured) ** 2) / max(
                            np.var(measured), 1e-300)
                        cost += error if np.isfinite(error) else np.inf
            if cost < best_cost:
                best, best_cost = admissible, cost
        if best is None:
            raise FitError('no admissible start point for the output-error fit: the data do '
                           'not look like a DC motor (check signs and units of the columns)')
        return best


def _update_position_ar(model: OutputErrorModel, values: Mapping[str, float],
                        states: np.ndarray, position_error: str = 'adaptive') -> bool:
    """
    Re-estimate every record's AR(1) coefficient of the position error at ``values``.

    :func:`dcmotor_id.identification.criterion.position_ar` of the residual against the
    sensor noise (quantisation included); returns whether a coefficient moved beyond
    :func:`~dcmotor_id.identification.criterion.ar_settled` (never without the position).
    """
    if 'position' not in model.outputs:
        return False
    moved = False
    for index, rec in enumerate(model.records):
        with np.errstate(all='ignore'):
            error = model.simulate(values, index, states[index])['position'] - rec.position
        if not np.all(np.isfinite(error)):
            continue
        model.position_rms[index] = float(np.sqrt(np.mean(error ** 2)))
        rho = position_ar(error, noise_level(rec.position), position_error)
        moved = moved or not ar_settled(model.position_ar[index], rho)
        model.position_ar[index] = rho
    return moved


def has_analytic_sensitivities(model: OutputErrorModel) -> bool:
    """Whether the compiled kernel gives the model's sensitivities (its own simulate only)."""
    return type(model).simulate is OutputErrorModel.simulate and NormalEquations.supports(model)


def _analytic_pass(equations, values, states, noise, chain, with_sens, outputs):
    """Accumulate the normal equations of every record with the analytic sensitivities."""
    weights = [np.array([1.0 / level[channel] for channel in outputs]) for level in noise]
    results = [equations.record(values, index, state, weights[index], with_sens)
               for index, state in enumerate(states)]
    if not with_sens:
        cost = float(sum(result.sums @ w ** 2 for result, w in zip(results, weights)))
        return _Pass(cost, sums=[result.sums for result in results])
    return _assemble(equations, results, weights, chain, [np.ones_like(w) for w in weights])


def _assemble(equations, results, weights, chain, factors, base=None):
    """
    Sum the records' per-channel normal equations into one pass in ``z`` coordinates.

    ``factors[record][channel]`` rescales each channel's sums (the ratio of the squared new
    and old weights when the noise levels were re-estimated); ``weights`` are the new ones,
    ``base`` the ones the records' sums were computed with (default ``weights``).
    ``chain`` (``d theta / d z``) has one entry per column of ``z``: the shared parameters,
    then the records' initial states unless they are pinned.
    """
    size = equations.n_shared + equations.n_state * len(results)
    hessian = np.zeros((size, size))
    gradient = np.zeros(size)
    blocks, block_record, normals = [], [], []
    cost = 0.0
    for index, (result, factor) in enumerate(zip(results, factors)):
        by_hessian, by_gradient, by_blocks = result.by_channel
        columns = equations.columns(index)
        normal = np.tensordot(factor, by_hessian, axes=1)
        hessian[np.ix_(columns, columns)] += normal
        if 1 < len(results) <= JACKKNIFE_MAX_RECORDS:
            full_normal = np.zeros((size, size))
            full_normal[np.ix_(columns, columns)] = normal
            normals.append(full_normal)
        gradient[columns] += factor @ by_gradient
        full = np.zeros((by_blocks.shape[0], size))
        full[:, columns] = np.tensordot(by_blocks, factor, axes=([1], [0]))
        blocks.append(full)
        block_record.append(np.full(by_blocks.shape[0], index))
        cost += float(result.sums @ weights[index] ** 2)
    # Pinned initial states (``initial_state='measured'``) are not in ``z``: ``chain`` covers
    # the shared parameters only, and the states' columns are dropped.
    keep = _kept_columns(equations, len(results), len(chain))
    scale = np.outer(chain, chain)
    return _Pass(cost, hessian[keep][:, keep] * scale, gradient[keep] * chain,
                 [result.sums for result in results], np.vstack(blocks)[:, keep] * chain,
                 np.concatenate(block_record),
                 (equations, results, weights if base is None else base, chain),
                 np.array([normal[keep][:, keep] * scale for normal in normals])
                 if normals else None)


def free_states(states: Sequence[str], initial_state: str) -> list[bool]:
    """Which initial states the fit estimates: all (``estimate``) or none (``measured``)."""
    return [initial_state != 'measured'] * len(states)


#: A base parameter below this fraction of its start when the position's error model leaves
#: white noise restarts from its start (:meth:`RefinedEstimator._passes`).
COLLAPSED = 0.01
#: Evaluations of a position-criterion fit that did not converge, retried, per the usual ones.
POSITION_NFEV_FACTOR = 4
#: Distance of a fitted initial position from the first samples, in their noise levels, beyond
#: which the fit moved the start to absorb a misfit.
MOVED_START_NOISE = 10.0


def moved_start(records: Sequence[Any], positions: Sequence[float]) -> str | None:
    """
    Say which record's fitted initial position is far from its first samples, else None.

    Far: beyond :data:`MOVED_START_NOISE` noise levels of the measured position (at least
    the quantisation's, ``LSB / sqrt(12)``), measured against the mean of the first 20
    samples' departure from their straight line (the record's own start).
    """
    for index, (rec, fitted) in enumerate(zip(records, positions)):
        measured = np.asarray(rec.position, dtype=float)
        steps = np.abs(np.diff(measured[:10_000]))
        lsb = float(np.min(steps[steps > 0])) if np.any(steps > 0) else 0.0
        noise = max(noise_std(measured), lsb / np.sqrt(12.0), 1e-300)
        head = measured[:20]
        line = np.polyval(np.polyfit(np.arange(head.shape[0]), head, 1), 0.0) \
            if head.shape[0] >= 3 else float(head[0])
        gap = abs(float(fitted) - float(line))
        if gap > MOVED_START_NOISE * noise:
            name = rec.source or f'record {index + 1}'
            return (f'{name}: the fitted initial position is {gap:.3g} from the first samples '
                    f'({gap / noise:.0f} noise levels): the offset absorbed a misfit, so the '
                    'initial states were pinned to the first samples')
    return None


def _kept_columns(equations, n_records, n_columns):
    """Return the columns of ``z`` among the passes' (shared, then the free initial states)."""
    free = getattr(equations, 'free_states', None)
    if free is None or all(free) or not any(free):
        # All states fitted, or all pinned (dropped): the first columns.
        return slice(0, n_columns)
    shared, n_state = equations.n_shared, equations.n_state
    return np.array(list(range(shared)) + [shared + index * n_state + state
                                           for index in range(n_records)
                                           for state in range(n_state) if free[state]])


def _numeric_pass(residual, z, model, noise, with_sens, n_shared):
    """
    Accumulate the same sums by forward differences of the simulation (for other models).

    Effects simulated on sub-steps (held over half-samples) and other model variants: the
    residual and its Jacobian are materialised, as a least-squares solver would.
    ``residual(z, only)`` returns the records' parts (None for records not in ``only``);
    the first ``n_shared`` columns of ``z`` are shared, the rest are the records' initial
    states in record order (:func:`record_sparse_jacobian`).
    """
    parts = residual(z)
    r = np.concatenate(parts)
    cost = float(r @ r)
    if not np.isfinite(cost):
        return _Pass(np.inf)
    jac = None
    if with_sens:
        steps = np.sqrt(np.finfo(float).eps) * np.maximum(np.abs(z), 1.0)
        jac = record_sparse_jacobian(residual, z, steps, parts, n_shared)
    sums = []
    position = 0
    for index, rec in enumerate(model.records):
        per_channel = np.zeros(len(model.outputs))
        for channel, name in enumerate(model.outputs):
            part = slice(position, position + len(rec))
            per_channel[channel] = float(r[part] @ r[part]) * noise[index][name] ** 2
            position += len(rec)
        sums.append(per_channel)
    if jac is None:
        return _Pass(cost, sums=sums)
    scores = block_scores(r, jac, [len(rec) for rec in model.records], len(model.outputs))
    return _Pass(cost, jac.T @ jac, jac.T @ r, sums, scores['block_scores'],
                 scores['block_record'], record_normal=scores.get('record_normal_matrices'))


def _levenberg_marquardt(evaluate, z, max_evaluations, xtol=1e-8, ftol=1e-8, gtol=1e-8,
                         current=None, damping=None):
    """
    Levenberg-Marquardt on the accumulated normal equations.

    MINPACK's ``lmder`` criteria on the normal equations alone (it never sees the ``2N x p``
    Jacobian): the step ``(H + mu D) dz = -g`` with ``D`` the largest diagonal of ``H`` seen
    (scale invariance), the damping lowered by the gain ratio of an accepted step (Nielsen's
    rule) and raised tenfold after a rejected one (the cost has kinks where an event crosses a
    sample instant: a quadratic model is trusted less), convergence
    when the relative cost reduction, actual and predicted, is below ``ftol``, the scaled step
    below ``xtol`` of the scaled point, or the largest cosine between the residual and a
    column of the Jacobian below ``gtol``.  After a rejected step the next trial is simulated
    without sensitivities (a fifth of the cost) and only an accepted one with them.

    Returns ``(z, pass, evaluations, converged, damping)``; ``current`` (the pass at ``z``)
    and ``damping`` continue an earlier run (a reweighted pass starts from its optimum).
    """
    nfev = 0
    if current is None:
        current = evaluate(z, True)
        nfev += 1
    if not np.isfinite(current.cost):
        raise FitError('the output-error fit diverged (non-finite residuals at the start): '
                       + _MISFIT)
    scale = np.maximum(np.diag(current.hessian), 0.0)
    mu = 1e-3 if damping is None else damping
    cheap = False
    while nfev < max(int(max_evaluations), 2):
        cost = current.cost
        scale = np.maximum(scale, np.diag(current.hessian))
        if _stationary(current, gtol):
            return z, current, nfev, True, mu
        step, predicted, small = _damped_step(current, z, mu, scale, xtol)
        trial = evaluate(z + step, not cheap)
        nfev += 1
        actual = cost - trial.cost if np.isfinite(trial.cost) else -np.inf
        ratio = actual / predicted if predicted > 0.0 else -1.0
        if ratio > 1e-4:
            z = z + step
            if cheap:
                trial = evaluate(z, True)
                nfev += 1
            current = trial
            cheap = False
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
            if (abs(actual) <= ftol * cost and predicted <= ftol * cost) or small:
                return z, current, nfev, True, mu
        else:
            cheap = True
            mu *= 10.0
            if small or mu > 1e16:
                return z, current, nfev, True, mu
    return z, current, nfev, False, mu


def _stationary(current, gtol):
    """
    Whether the pass ``current`` is at a stationary point of the cost (MINPACK's ``gtol``).

    The cost is zero, or the largest cosine between the residual and a column of the
    Jacobian (from ``J^T r`` and the diagonal of ``J^T J``) is at most ``gtol``.
    """
    hessian, gradient, cost = current.hessian, current.gradient, current.cost
    column_norms = np.sqrt(np.maximum(np.diag(hessian), 0.0))
    if cost <= 0.0:
        return True
    cosines = np.abs(gradient) / np.where(column_norms > 0.0, column_norms, np.inf)
    return float(np.max(cosines, initial=0.0)) / np.sqrt(cost) <= gtol


def _damped_step(current, z, mu, scale, xtol):
    """
    Solve ``(H + mu D) dz = -g`` at the pass ``current``; ``D``: ``scale`` (1 where zero).

    Returns the step, the cost reduction its quadratic model predicts, and whether the step
    scaled by ``D`` is below ``xtol`` of the point's (MINPACK's ``xtol``).
    """
    hessian, gradient = current.hessian, current.gradient
    weights = np.where(scale > 0.0, scale, 1.0)
    try:
        step = np.linalg.solve(hessian + mu * np.diag(weights), -gradient)
    except np.linalg.LinAlgError:
        step = np.linalg.lstsq(hessian + mu * np.diag(weights), -gradient, rcond=None)[0]
    step_norm = float(np.sqrt(np.sum(weights * step ** 2)))
    point_norm = float(np.sqrt(np.sum(weights * z ** 2)))
    predicted = -(2.0 * gradient @ step + step @ hessian @ step)
    return step, predicted, step_norm <= xtol * point_norm
