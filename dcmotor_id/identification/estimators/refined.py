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
from dcmotor_id.core.model import (make_admissible, MotorParameters, parameter_names,
                                   POSITIVE_NAMES, state_matrix)
from dcmotor_id.identification.error_model.criterion import (AR_PASSES, ar_settled,
                                                             check_position_error_model,
                                                             fitted_outputs, integrate_speed,
                                                             noise_level, position_ar)
from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm, StateTerm
from dcmotor_id.identification.estimators.least_squares import (FitProblem,
                                                                levenberg_marquardt, MISFIT,
                                                                nonnegative_lstsq)
from dcmotor_id.identification.estimators.normal_equations import NormalEquations
from dcmotor_id.identification.estimators.paper import PaperEstimator
from dcmotor_id.signals.filters import low_pass, noise_std
from dcmotor_id.simulation import (combine_contributions, EXACT_FIELDS, held_input,
                                   HybridSystem, motor_forcing, MotorEffects, simulate_mechanical,
                                   simulate_mechanical_effects, simulate_motor_effects)

__all__ = ['OutputErrorModel', 'PinnedModel', 'RefinedEstimator', 'StateTerm',
           'STATE_OVERSAMPLE']


#: Channels of exogenous terms: the linear ones of :class:`ExogenousTerm` and ``state``
#: (:class:`StateTerm`, an effect simulated exactly inside the model).
_CHANNELS = ('voltage', 'torque', 'current', 'speed', 'state')
#: Sub-steps per sample when state-dependent effects are simulated.
STATE_OVERSAMPLE = 2
#: Samples the start-point search looks at, at most (windows spread over longer records).
START_SAMPLES = 250_000
#: Windows per record of the start-point search on long records.
START_WINDOWS = 5
#: Start points tried, best first, while the fit from the one before fails (no convergence).
START_TRIES = 3


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
        (:func:`dcmotor_id.identification.error_model.criterion.fitted_outputs`).  With the
        position, every
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
        # sample; :func:`dcmotor_id.identification.error_model.criterion.position_ar`), set by the
        # fit.
        self.position_ar = [0.0] * len(self.records)
        self.position_rms = [0.0] * len(self.records)
        # The period is a median over the record: computed once, not at every simulation.
        self.sample_periods_s = [rec.sample_period_s for rec in self.records]
        # Mechanical-only mode: the sampled current is the input.  It varies within a sample,
        # so the torque held over [t_k, t_k+1) is its trapezoidal mean (i[k] + i[k+1]) / 2
        # (held_input); holding i[k] instead biases J by O(dT) (0.5 % at 1 kHz for motor 2,
        # bench/README.md).
        self.held_currents = [held_input(rec.current) if self.mechanical_only else None
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


class PinnedModel(OutputErrorModel):
    """
    The output-error model with some base parameters held at given values (a profile's fit).

    ``pinned``: name -> value of the base parameters that are not fitted (e.g. ``{'J': 1e-6}``
    for a point of J's likelihood profile); the others are the fit's ``base_names``.  Its own
    :meth:`simulate` leaves the compiled sensitivities to the plain model: the fit takes
    numeric ones (:func:`has_analytic_sensitivities`).
    """

    def __init__(self, records: Sequence[Any], torque_constant: float | None,
                 terms: Sequence[ExogenousTerm], quasi_static: bool, criterion: str,
                 pinned: Mapping[str, float]) -> None:
        super().__init__(records, torque_constant, terms, quasi_static, criterion)
        unknown = set(pinned) - set(self.base_names)
        if unknown:
            raise ValueError(f'pinned parameters not in the model: {sorted(unknown)}')
        self.pinned = {name: float(value) for name, value in pinned.items()}
        self.base_names = tuple(name for name in self.base_names if name not in self.pinned)

    def simulate(self, values: Mapping[str, float], index: int,
                 initial_state: Sequence[float] | np.ndarray) -> dict[str, np.ndarray]:
        """Simulate record ``index`` with the pinned values added to ``values``."""
        return super().simulate({**values, **self.pinned}, index, initial_state)


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
            matrix, rhs = np.vstack(rows_m), np.concatenate(rhs_m)
            # Where the free solution puts J, b or Mc below zero, the bounded one is a
            # candidate too (taking magnitudes can start far from the data); where it does
            # not, the bounded one is the free one (the same solve, not repeated).
            bounded, held = nonnegative_lstsq(matrix, rhs, (True, True, True))
            free = np.linalg.lstsq(matrix, rhs, rcond=None)[0] if held.any() else bounded
            mechs = [free] + ([bounded] if held.any() else [])
            cphi = 1.0
            electrical: dict[str, float] = {}
            if not mechanical_only:
                la, ra, cphi = np.linalg.lstsq(np.vstack(rows_e), np.concatenate(rhs_e),
                                               rcond=None)[0]
                electrical = {'Ra': ra, 'La': la, 'CPhi': cphi}
        except np.linalg.LinAlgError:
            continue
        candidates.extend({**electrical, 'J': mech[0] * cphi, 'b': mech[1] * cphi,
                           'Mc': mech[2] * cphi} for mech in mechs)
    return candidates


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
        (:func:`~dcmotor_id.identification.error_model.criterion.check_position_error_model`).
    retry : bool
        A fit on the position that does not converge is tried once more with
        :data:`POSITION_NFEV_FACTOR` times ``max_nfev`` (default).  False: the fit keeps its
        bound (the discovery loop's candidate refits with effect terms: a candidate that needs
        more is not the one to keep).
    pinned : dict, optional
        Base parameters held at these values, not fitted (:class:`PinnedModel`: a point of a
        likelihood profile); the estimate gives them with a NaN standard error.

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
                 position_error: str = 'adaptive',
                 pinned: Mapping[str, float] | None = None) -> None:
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
        self.pinned = dict(pinned or {})

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
        model = (PinnedModel(records, torque_constant, terms, self.quasi_static, self.criterion,
                             self.pinned) if self.pinned else
                 OutputErrorModel(records, torque_constant, terms, self.quasi_static,
                                  self.criterion))
        warm_ar = self.position_ar if position_ar is None else position_ar
        if warm_ar is not None and len(warm_ar) == len(records):
            model.position_ar = [float(value) for value in warm_ar]
        failure = None
        for start in self._starts(model)[:START_TRIES]:
            problem = FitProblem(model, start, initial_state, self.initial_states,
                                 self.progress, has_analytic_sensitivities(model))
            try:
                z, final, noise, total_nfev = self._passes(problem, max_nfev)
                break
            except FitError as error:  # the next start, as a user would try one
                failure = failure or error
        else:
            raise failure or FitError('no start point for the output-error fit: ' + MISFIT)
        values = problem.unpack(z)[0]
        degenerate = [name for name in model.base_names if not np.isfinite(values[name])
                      or (name in POSITIVE_NAMES and not 1e-200 < values[name] < 1e200)]
        if degenerate:
            raise FitError(f'the output-error fit diverged ({", ".join(degenerate)} went to zero '
                           'or infinity): ' + MISFIT)
        if final is None:
            final = problem.evaluate(z, noise, True)
            total_nfev += 1
        estimate = problem.estimate(self.name, z, final, noise, total_nfev)
        estimate.parameters.update(self.pinned)
        estimate.stderr.update({name: float('nan') for name in self.pinned})
        return estimate

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
            z, current, nfev, converged, damping = levenberg_marquardt(
                problem.evaluator(noise), z, max_nfev, current=current, damping=damping)
            total_nfev += nfev
            if not np.all(np.isfinite(z)):
                raise FitError('the output-error fit diverged (non-finite parameters): ' + MISFIT)
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
                           'evaluations is exceeded): ' + MISFIT)
        return z, current, noise, total_nfev

    def _starts(self, model):
        """Return the admissible start candidates, lowest simulation error first."""
        if self.initial is not None:
            return [{name: float(self.initial[name]) for name in model.base_names}]
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
        zero_terms = {term.name: term.initial for term in model.terms}
        scored = []
        for candidate in candidates:
            admissible = make_admissible(candidate)
            if admissible is not None:
                cost = _start_cost(model, records, {**admissible, **zero_terms})
                if np.isfinite(cost):
                    scored.append((cost, len(scored), admissible))
        if not scored:
            raise FitError('no admissible start point for the output-error fit: the data do '
                           'not look like a DC motor (check signs and units of the columns)')
        return [admissible for _, _, admissible in sorted(scored)]


def _start_cost(model: OutputErrorModel, records: Sequence[Any],
                values: Mapping[str, float]) -> float:
    """Return a start point's simulation error (sum of the channels' NRMSE squared)."""
    cost = 0.0
    with np.errstate(all='ignore'):
        for index, rec in enumerate(records):
            state = [float(getattr(rec, channel)[0]) for channel in model.states]
            out = model.simulate(values, index, state)
            for channel in model.outputs:
                measured = getattr(rec, channel)
                error = np.mean((out[channel] - measured) ** 2) / max(np.var(measured), 1e-300)
                cost += error if np.isfinite(error) else np.inf
    return float(cost)


def _update_position_ar(model: OutputErrorModel, values: Mapping[str, float],
                        states: np.ndarray, position_error: str = 'adaptive') -> bool:
    """
    Re-estimate every record's AR(1) coefficient of the position error at ``values``.

    :func:`dcmotor_id.identification.error_model.criterion.position_ar` of the residual against the
    sensor noise (quantisation included); returns whether a coefficient moved beyond
    :func:`~dcmotor_id.identification.error_model.criterion.ar_settled` (never without the
    position).
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
    the quantisation's, ``LSB / sqrt(12)``) from the first sample, the position the fitted
    initial state stands for.  (A straight line through the first 20 samples, the reference
    before, misreads a start that accelerates: a shaft driven from rest by a step of
    current is a parabola there, whose line starts up to a hundred noise levels below it,
    so that an exact fit was pinned to a filtered speed and bent its friction, issue 29.)
    """
    for index, (rec, fitted) in enumerate(zip(records, positions)):
        measured = np.asarray(rec.position, dtype=float)
        steps = np.abs(np.diff(measured[:10_000]))
        lsb = float(np.min(steps[steps > 0])) if np.any(steps > 0) else 0.0
        noise = max(noise_std(measured), lsb / np.sqrt(12.0), 1e-300)
        gap = abs(float(fitted) - float(measured[0]))
        if gap > MOVED_START_NOISE * noise:
            name = rec.source or f'record {index + 1}'
            return (f'{name}: the fitted initial position is {gap:.3g} from the first samples '
                    f'({gap / noise:.0f} noise levels): the offset absorbed a misfit, so the '
                    'initial states were pinned to the first samples')
    return None
