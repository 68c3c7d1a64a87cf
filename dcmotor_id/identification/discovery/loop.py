"""The discovery loop (:class:`DiscoveryLoop`): fit, analyse, screen, refit, judge, repeat."""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import parameter_names
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.criterion import fitted_outputs
from dcmotor_id.identification.discovery.judging import heldout_gain_noise, never_worse
from dcmotor_id.identification.discovery.parts import excited_stop, HOLDOUT_FRACTION
from dcmotor_id.identification.discovery.refitting import (friction_floors, open_loop_outputs,
                                                           refit_all_data, refit_start)
from dcmotor_id.identification.discovery.result import DiscoveryResult
from dcmotor_id.identification.discovery.structure import (_part, _slice_terms, _with_initial,
                                                           Candidate, Fit, Round, Structure)
from dcmotor_id.identification.effects import SensorDelay, VOCABULARY
from dcmotor_id.identification.estimators.jacobian import jacobian
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.residuals import (ALPHA, analyse_channel, correlation_summary,
                                                 DEFAULT_LAGS, one_step_error, output_channels,
                                                 residual_nrmse_pct, simulate_records)

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate


#: Least relative drop of the held-out error for an effect to be added.
MIN_GAIN = 0.05
#: Candidates explaining at least this share of the best one's improvement tie with it.
TIE_SHARE = 0.98
#: Share of the residual an AR predictor must explain for structure to count as material.
MATERIAL_FRACTION = 0.05
#: Held-out error (percent of the signal spread) below which the model is exact.
NEGLIGIBLE_NRMSE_PCT = 1e-6
#: Most effects added.
MAX_EFFECTS = 4
#: Share of ``min_gain`` the linearised screen must explain for a candidate to be refitted.
SCREEN_SHARE = 0.5
#: Candidates refitted whatever their screen, best screen first.
SCREEN_TOP = 2
#: Candidates refitted whatever their screen when the model misfits far above the noise (the
#: linearised screen then ranks, it does not gate: a decisive nonlinear effect can screen low).
SCREEN_TOP_MISFIT = 4
#: Held-out residual RMS above this multiple of the sensor noise is a misfit.
MISFIT_FACTOR = 3.0
#: Term channels the one-step error represents, and its argument for each (a ``state`` term,
#: an effect simulated inside the model, has no one-step form there).
ONE_STEP_TERMS = {'voltage': 'voltage_extra', 'torque': 'torque_extra',
                  'current': 'current_offset', 'speed': 'speed_offset'}
#: Bound on the Jacobian evaluations of a candidate's refit (per parameter, as in
#: :class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`).
CANDIDATE_MAX_NFEV = 30
#: Blocks per record's held-out part of the gain's t statistic (:meth:`DiscoveryLoop.gain_t`).
GAIN_BLOCKS = 8
#: Share of a refit's residual RMS an effect's own part of the outputs must exceed.
OWN_PART_SHARE = 0.5
#: Noise levels of an effect's own part beyond which its held-out gain needs no t test.
OWN_PART_STRONG = 3.0
#: Least t of the held-out gain for an effect to be added.
GAIN_T = 2.0


class DiscoveryLoop:
    """
    Residual analysis and effect discovery on a set of prepared records.

    Parameters
    ----------
    records : list of Record
        Prepared records (:func:`dcmotor_id.identification.identify.prepare_records`).
    torque_constant : float, optional
        Mechanical-only mode.
    vocabulary : sequence of Effect classes
        Candidates, in tie-breaking order.
    holdout_fraction : float
        Share of each record held out.
    min_gain : float
        Least relative drop of the held-out error to add an effect.
    max_effects : int
        Most effects added.
    max_lag : int
        Lags of the whiteness test and correlations.
    alpha : float
        Significance level of the tests.
    progress : Progress, optional
        Progress report and time budget; when the budget runs out the loop stops with the
        best structure so far (``out_of_time`` in the result).
    initial_state : str
        ``estimate`` or ``measured``
    (:class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`).
    quasi_static : bool
        Fit the quasi-static armature (La -> 0; the electrical time constant below the sample
        period) throughout.
    criterion : str
        ``speed`` (default), ``position`` or ``both``: the channels fitted and judged
        (:mod:`dcmotor_id.identification.criterion`); the held-out errors also report the
        speed (and the current) when they are not compared.

    """

    def __init__(self, records: Sequence[Record], torque_constant: float | None = None,
                 vocabulary: Sequence[type[Effect]] = VOCABULARY,
                 holdout_fraction: float = HOLDOUT_FRACTION, min_gain: float = MIN_GAIN,
                 max_effects: int = MAX_EFFECTS, max_lag: int = DEFAULT_LAGS,
                 alpha: float = ALPHA, progress: Progress | None = None,
                 initial_state: str = 'estimate', quasi_static: bool = False,
                 criterion: str = 'speed') -> None:
        self.records = list(records)
        self.torque_constant = torque_constant
        self.mechanical_only = torque_constant is not None
        self.criterion = criterion
        self.outputs = fitted_outputs(self.mechanical_only, criterion)
        self.error_channels = output_channels(self.mechanical_only) + tuple(
            channel for channel in self.outputs if channel == 'position')
        self.candidates = [cls for cls in vocabulary if cls.applies(self.mechanical_only)]
        self.holdout_fraction = float(holdout_fraction)
        self.min_gain = float(min_gain)
        self.max_effects = int(max_effects)
        self.max_lag = int(max_lag)
        self.alpha = float(alpha)
        self.weights: dict[str, float] | None = None
        self.progress = progress
        self.initial_state = initial_state
        self.quasi_static = bool(quasi_static) and not self.mechanical_only
        self.anchor: Fit | None = None

    # ------------------------------------------------------------------ fitting
    def _stops(self, records):
        """
        End of every record's training part (:func:`excited_stop`).

        The held-out part carries the held-out share of the record's *excitation*, not of its
        samples: a record that ends at standstill or in a steady-speed tail would otherwise
        hold out a part where nothing happens, which cannot judge a model.
        """
        return [excited_stop(rec, self.holdout_fraction, self.outputs) for rec in records]

    def _estimator(self, **options: Any) -> RefinedEstimator:
        return RefinedEstimator(initial_state=self.initial_state, progress=self.progress,
                                quasi_static=self.quasi_static, criterion=self.criterion,
                                **options)

    def fit(self, structure: Structure, start: dict | None = None, initial: dict | None = None,
            max_nfev: int = 100,
            initial_states: Sequence[Sequence[float]] | None = None) -> Fit:
        """
        Fit a structure on the training parts and simulate the whole records.

        ``initial_states`` (one per record, e.g. of an earlier fit) warm-start the fit's
        initial states; the training parts start where the records do.
        """
        records = structure.transformed(self.records)
        stops = self._stops(records)
        base = start or {}
        terms = _with_initial(structure.terms(records, base, self.torque_constant, initial),
                              initial or {})
        train = [rec.slice(0, stop) for rec, stop in zip(records, stops)]
        estimator = self._estimator(max_nfev=max_nfev, initial=start or None,
                                    initial_states=initial_states)
        if not start and terms:
            raise ValueError('a structure with effects needs a start point')
        estimate = estimator.fit(train, torque_constant=self.torque_constant,
                                 terms=_slice_terms(terms, stops))
        model = OutputErrorModel(records, self.torque_constant, terms, self.quasi_static,
                                 self.criterion)
        simulated = simulate_records(model, estimate.parameters, estimate.initial_states)
        if self.criterion != 'speed' and len(structure) and not self.quasi_static:
            simulated = open_loop_outputs(structure, estimate, records, self.torque_constant)
        fitted = Fit(structure, estimate, records, stops, simulated, terms)
        if self.weights is None:
            self.weights = {channel: max(estimate.info['noise_std'][channel], 1e-300)
                            for channel in self.outputs}
        fitted.train_cost = self._cost(fitted, 'train')
        fitted.heldout_cost = self._cost(fitted, 'heldout')
        fitted.n_train = int(sum(stops)) * len(self.outputs)
        return fitted

    def _cost(self, fitted, part):
        total = 0.0
        for channel in self.outputs:
            error = fitted.channel_residual(channel, part)
            value = float(np.mean(error ** 2)) / self.weights[channel] ** 2
            total += value if np.isfinite(value) else np.inf
        return total

    def _bic(self, fitted):
        n = max(fitted.n_train, 1)
        n_parameters = len(fitted.estimate.parameters) + len(fitted.records) * len(self.outputs)
        return float(n * np.log(max(fitted.train_cost, 1e-300)) + n_parameters * np.log(n))

    # ------------------------------------------------------------------ analysis
    def _inputs(self, fitted, part):
        name = 'current' if self.mechanical_only else 'voltage'
        return {name: _part([getattr(rec, name) for rec in fitted.records], fitted.stops, part)}

    def _candidate_regressors(self, fitted, part):
        """Yield ``(effect name, regressor on the part)``, one candidate at a time."""
        base = fitted.values
        for cls in self.candidates:
            if cls.TRANSFORM:
                continue
            grid = cls.inner_grid(fitted.records, base, self.torque_constant)
            if not grid:
                continue
            inner = grid[len(grid) // 2]
            terms = cls.terms(fitted.records, inner, base, self.torque_constant)
            if not terms:
                continue
            joined = _part(terms[0].regressors, fitted.stops, part)
            del terms
            if np.std(joined) > 0:
                yield cls.name, joined
            del joined

    def analyse(self, fitted: Fit, part: str = 'heldout') -> dict[str, dict[str, Any]]:
        """
        Residual analysis of a fit on a part: per output channel (JSON-ready).

        Each channel's :func:`~dcmotor_id.identification.residuals.analyse_channel` of the output
        error, plus
        ``one_step_nrmse_pct``, the one-step prediction error on the same part (None when the
        structure has an effect the one-step model does not represent).  The loop decides on
        the output error alone; the one-step error is reported beside it.  The candidates'
        regressors are built and correlated one at a time (memory: one regressor at once).
        """
        inputs = self._inputs(fitted, part)
        one_step = self.one_step_errors(fitted, part)
        residuals = {channel: fitted.channel_residual(channel, part) for channel in self.outputs}
        analysis = {}
        for channel in self.outputs:
            analysis[channel] = analyse_channel(
                residuals[channel], fitted.channel_measured(channel, part), inputs, None,
                self.max_lag, self.alpha)
        del inputs
        level = 1.0 - self.alpha
        for name, regressor in self._candidate_regressors(fitted, part):
            for channel in self.outputs:
                analysis[channel]['regressors'][name] = correlation_summary(
                    residuals[channel], regressor, self.max_lag, level)
        for channel in self.outputs:
            analysis[channel]['one_step_nrmse_pct'] = one_step.get(channel)
        return analysis

    def one_step_errors(self, fitted: Fit, part: str = 'heldout') -> dict[str, float | None]:
        """
        One-step prediction error of a fit on a part, percent of the signal spread, by channel.

        :func:`~dcmotor_id.identification.residuals.one_step_error` on every record with the fit's
        linear
        effect terms; a prediction belongs to the part of the sample it predicts.  Empty when
        the structure has a term the one-step model does not represent.
        """
        if self.quasi_static or any(term.channel not in ONE_STEP_TERMS
                                    for term in fitted.terms):
            return {}
        values = fitted.values
        channels = [channel for channel in self.outputs if channel != 'position']
        errors: dict[str, list[np.ndarray]] = {channel: [] for channel in channels}
        for index, rec in enumerate(fitted.records):
            extras: dict[str, Any] = {}
            for term in fitted.terms:
                key = ONE_STEP_TERMS[term.channel]
                contribution = values[term.name] * term.regressors[index]
                extras[key] = extras[key] + contribution if key in extras else contribution
            with np.errstate(all='ignore'):
                predicted = one_step_error(values, rec, self.torque_constant, **extras)
            for channel in channels:
                errors[channel].append(predicted[channel])
        # Prediction k is of sample k + 1: the parts start one sample earlier.
        stops = [max(stop - 1, 0) for stop in fitted.stops]
        return {channel: residual_nrmse_pct(
            _part(errors[channel], stops, part),
            _part([getattr(rec, channel)[1:] for rec in fitted.records], stops, part))
            for channel in channels}

    def misfit(self, fitted: Fit) -> bool:
        """Whether the held-out residual is far above the sensor noise on some channel."""
        from dcmotor_id.identification.identifiability import noise_level

        for channel in self.outputs:
            residual = fitted.channel_residual(channel, 'heldout')
            noise = np.sqrt(np.mean([noise_level(getattr(rec, channel)) ** 2
                                     for rec in fitted.records]))
            if residual.shape[0] and noise > 0 and \
                    np.sqrt(np.mean(residual ** 2)) > MISFIT_FACTOR * noise:
                return True
        return False

    def _negligible(self, analysis):
        return all(item['nrmse_pct'] is not None and item['nrmse_pct'] < NEGLIGIBLE_NRMSE_PCT
                   for item in analysis.values())

    def explained(self, analysis: dict) -> bool:
        """White residual on every channel (Bonferroni over channels), or an exact model."""
        if self._negligible(analysis):
            return True
        level = self.alpha / len(analysis)
        return all(item['ljung_box']['p_value'] >= level for item in analysis.values())

    def material(self, analysis: dict) -> bool:
        """Structure that matters: not white and at least 5 % predictable from its past."""
        if self.explained(analysis):
            return False
        level = self.alpha / len(analysis)
        return any(item['ljung_box']['p_value'] < level and
                   item['predictable_fraction'] >= MATERIAL_FRACTION
                   for item in analysis.values())

    # ------------------------------------------------------------------ screening
    def _train_model(self, fitted, terms):
        train = [rec.slice(0, stop) for rec, stop in zip(fitted.records, fitted.stops)]
        return train, OutputErrorModel(train, self.torque_constant,
                                       _slice_terms(terms, fitted.stops), self.quasi_static,
                                       self.criterion)

    def _stack(self, outputs_per_record, stops):
        parts = []
        for channel in self.outputs:
            for out, stop in zip(outputs_per_record, stops):
                parts.append(np.asarray(out[channel][:stop]) / self.weights[channel])
        return np.concatenate(parts)

    def _base_sensitivities(self, fitted):
        """Weighted residual and sensitivities of the fitted parameters (training part)."""
        train, model = self._train_model(fitted, fitted.terms)
        values = dict(fitted.values)
        states = fitted.estimate.initial_states
        nominal = simulate_records(model, values, states)
        measured = [{channel: getattr(rec, channel) for channel in self.outputs}
                    for rec in train]
        residual = self._stack(measured, fitted.stops) - self._stack(nominal, fitted.stops)
        names = list(model.base_names) + [term.name for term in fitted.terms]
        point = np.array([values[name] for name in names], dtype=float)

        def stacked(vector):
            moved = {**values, **dict(zip(names, vector))}
            with np.errstate(all='ignore'):
                return self._stack(simulate_records(model, moved, states), fitted.stops)
        steps = np.where(point != 0.0, 1e-6 * np.abs(point), 1e-9)
        matrix = (jacobian(stacked, point, steps, central=False,
                           f0=self._stack(nominal, fitted.stops))
                  if names else np.zeros((residual.shape[0], 0)))
        # Initial-state sensitivities are left out: they decay within a few time constants.
        matrix = matrix[:, np.all(np.isfinite(matrix), axis=0)]
        return residual, matrix, nominal

    def _term_responses(self, fitted, terms, nominal):
        """
        Sensitivities of the training outputs to a candidate's coefficients.

        Finite differences through the model from the candidate's start values, with the
        coefficient's typical magnitude as the (secant) step, so stick-slip events do not make
        the difference noisy; for a linear term this is its exact linear response.
        """
        _, model = self._train_model(fitted, fitted.terms + tuple(terms))
        start = dict(fitted.values)
        start.update({term.name: term.initial for term in terms})
        names = [term.name for term in terms]

        def stacked(vector):
            moved = {**start, **dict(zip(names, vector))}
            return self._stack(simulate_records(model, moved, fitted.estimate.initial_states),
                               fitted.stops)
        return jacobian(stacked, [term.initial for term in terms],
                        [term.scale for term in terms], central=False,
                        f0=self._stack(nominal, fitted.stops))

    @staticmethod
    def _projector(matrix):
        if matrix.shape[1] == 0:
            return None
        from scipy.linalg import qr  # lazily: only a search round needs it (import time)
        q, r, _ = qr(matrix, mode='economic', pivoting=True)
        keep = np.abs(np.diag(r)) > 1e-10 * max(abs(r[0, 0]), 1e-300)
        return q[:, keep]

    @staticmethod
    def _explained(q, residual, columns):
        """Residual sum of squares explained by ``columns`` beyond the base sensitivities."""
        if q is not None:
            residual = residual - q @ (q.T @ residual)
            columns = columns - q @ (q.T @ columns)
        coefficients, *_ = np.linalg.lstsq(columns, residual, rcond=None)
        fitted = columns @ coefficients
        return float(fitted @ fitted), coefficients

    def screen(self, fitted: Fit, cls: type[Effect], residual: np.ndarray,
               q: np.ndarray | None, nominal: list) -> tuple[float, dict, dict] | None:
        """Best inner parameters of a candidate by the linearised fit; with start values."""
        best = None
        for inner in cls.inner_grid(fitted.records, fitted.values, self.torque_constant):
            terms = cls.terms(fitted.records, inner, fitted.values, self.torque_constant)
            columns = self._term_responses(fitted, terms, nominal)
            if not np.all(np.isfinite(columns)) or np.allclose(columns, 0.0):
                continue
            gained, coefficients = self._explained(q, residual, columns)
            if best is None or gained > best[0]:
                # A coefficient without effect at the start (the Stribeck velocity while the
                # excess is zero) keeps its start value.
                norms = np.linalg.norm(columns, axis=0)
                moved = norms > 1e-9 * np.max(norms)
                best = (gained, inner, {
                    term.name: float(term.initial + (c if active else 0.0))
                    for term, c, active in zip(terms, coefficients, moved)})
        return best

    def _delay_estimate(self, fitted, channel, residual, q, nominal):
        """Linearised delay of one channel's sensor [samples] (positive: the sensor is late)."""
        outs = []
        for out, rec, stop in zip(nominal, fitted.records, fitted.stops):
            sens = {name: np.zeros(stop) for name in self.outputs}
            sens[channel] = -np.gradient(out[channel][:stop])
            outs.append(sens)
        column = self._stack(outs, fitted.stops)[:, None]
        gained, coefficients = self._explained(q, residual, column)
        return gained, float(coefficients[0])

    # ------------------------------------------------------------------ candidates
    def _try(self, current, cls, inner, start_terms):
        """
        Refit the structure with a candidate from the screen's start; return the Fit or None.

        The screen's start is a linearisation at the current fit: from a poor base it can
        overshoot so far that the refit does not converge, so a failed refit is tried once
        more from the candidate's own neutral start (its terms at their defaults).
        """
        structure = current.structure.plus(cls, inner)
        fitted, initial = None, dict(current.values)
        for terms in ((start_terms, {}) if start_terms else ({},)):
            initial = dict(current.values)
            initial.update(terms)
            fitted = self._try_from(structure, self._base(current), initial,
                                    current.estimate.initial_states)
            if fitted is not None:
                break
        if self.anchor is None or len(current.structure):
            return fitted
        # The position criterion: the integral of a model that lacks an effect drifts, and
        # its fit may end far from the physical values (EMPS without its force offset: the
        # mass doubles, the Coulomb friction vanishes).  The candidate is also fitted from the
        # speed-criterion values; the lower training cost wins (a fit's local minimum, not a
        # selection: the held-out part is not looked at).  Only from the base model: once an
        # effect is in, the fit starts from a model that follows the position.
        anchored = self._try_from(structure, self._base(self.anchor), {
            **initial, **{name: value for name, value in self.anchor.values.items()
                          if name in self.anchor.estimate.parameters}}, None)
        return min((fit for fit in (fitted, anchored) if fit is not None),
                   key=lambda fit: fit.train_cost, default=None)

    def _try_from(self, structure, start, initial, initial_states):
        """Fit a structure from a start point; None when the fit fails."""
        try:
            with np.errstate(all='ignore'):  # a wild candidate may overflow; it is scored
                return self.fit(structure, start=start, initial=initial,
                                max_nfev=CANDIDATE_MAX_NFEV, initial_states=initial_states)
        except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
            return None

    def _anchor_fit(self) -> Fit | None:
        """Fit the base model on the speed (training parts) when the criterion is not the speed."""
        if self.criterion == 'speed':
            return None
        loop = DiscoveryLoop(self.records, self.torque_constant, self.candidates,
                             self.holdout_fraction, progress=self.progress,
                             initial_state=self.initial_state, quasi_static=self.quasi_static)
        try:
            return loop.fit(Structure())
        except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
            return None

    def _base(self, fitted):
        return refit_start(fitted.values, self.records, self.torque_constant)

    def screen_candidate(self, current: Fit, cls: type[Effect], residual: np.ndarray,
                         q: np.ndarray | None, nominal: list) -> Candidate | None:
        """
        Linearised screen of one candidate: its inner parameters, start and explained share.

        Returns the :class:`Candidate` (not refitted) or None when the candidate has nothing
        to offer (no grid point, or a delay that rounds to zero samples).
        """
        total = max(float(residual @ residual), 1e-300)
        if cls.TRANSFORM:
            best = None
            for channel in SensorDelay.channels(self.mechanical_only):
                gained, estimate = self._delay_estimate(current, channel, residual, q, nominal)
                samples = int(np.round(estimate))
                if samples != 0 and (best is None or gained / total > best.screen_explained):
                    best = Candidate(cls, {'channel': channel, 'samples': samples}, {},
                                     gained / total)
            return best
        found = self.screen(current, cls, residual, q, nominal)
        if found is None:
            return None
        gained, inner, start_terms = found
        return Candidate(cls, inner, start_terms, gained / total)

    def refit_candidate(self, current: Fit, candidate: Candidate) -> Candidate:
        """Refit all parameters with the candidate added; return it with its fit and problem."""
        if candidate.effect.TRANSFORM:
            fitted = self._refit_delay(current, candidate.inner['channel'],
                                       candidate.inner['samples'])
        else:
            fitted = self._try(current, candidate.effect, candidate.inner, candidate.start)
        if fitted is None or not np.isfinite(fitted.heldout_cost):
            return candidate
        return replace(candidate, fit=fitted, inner=fitted.structure.items[-1][1],
                       problem=self._problem(current, fitted))

    def score(self, current: Fit, candidate: Candidate) -> Candidate:
        """Return the candidate with its held-out gain and BIC change (None if not refitted)."""
        if candidate.fit is None:
            return candidate
        return replace(candidate, gain=1.0 - candidate.fit.heldout_cost / current.heldout_cost,
                       bic_delta=self._bic(candidate.fit) - self._bic(current),
                       insample_gain=1.0 - candidate.fit.train_cost / current.train_cost,
                       gain_noise=heldout_gain_noise(current, candidate.fit, self.outputs,
                                                     self.weights or {}))

    def _problem(self, current, fitted):
        """Why a candidate's fit is not acceptable (physics, collapse), or None."""
        effect = fitted.structure.effects(fitted.values)[-1]
        reason = effect.problem(fitted.values, fitted.records)
        if reason:
            return reason
        floor = friction_floors(current.values, self.records, self.torque_constant)
        for name in ('b', 'Mc'):
            before, after = current.values[name], fitted.values[name]
            # A friction already at zero cannot collapse (it was 5e-193 in a lab record).
            if before > 0.05 * floor[name] and after < 0.01 * before:
                return (f'{name} collapses from {before:.4g} to {after:.3g}: the candidate '
                        'takes over the base friction instead of adding to it')
        return None

    def _refit_delay(self, current, channel, samples):
        """Gauss-Newton on the integer delay: shift, refit, re-estimate the remainder."""
        fitted = None
        tried = set()
        for _ in range(4):
            if samples == 0 or samples in tried:
                break
            tried.add(samples)
            attempt = self._try(current, SensorDelay, {'channel': channel, 'samples': samples},
                                {})
            if attempt is None:
                break
            if fitted is not None and attempt.train_cost >= fitted.train_cost:
                break
            fitted = attempt
            res, matrix, nom = self._base_sensitivities(fitted)
            _, more = self._delay_estimate(fitted, channel, res, self._projector(matrix), nom)
            step = int(np.round(more))
            if step == 0:
                break
            samples += step
        return fitted

    # ------------------------------------------------------------------ the loop
    def run(self, estimate: Estimate | None = None) -> DiscoveryResult:
        """
        Run the loop, refit the base and final structures on all the data; return it.

        ``estimate``, the base model already fitted on all of the records (same model: mode,
        quasi-static armature), warm-starts the base fit on the training parts and is reused
        when no effect is added.
        """
        if self.progress is not None:
            self.progress.set_stage('discovery: base model on the training parts')
        if estimate is None:
            base = self.fit(Structure())
        else:
            start = {name: float(estimate.parameters[name])
                     for name in parameter_names(self.mechanical_only)
                     if name in estimate.parameters}
            base = self.fit(Structure(), start=start, initial_states=estimate.initial_states)
        current = base
        if base.estimate.info.get('initial_state') == 'measured':
            # The position criterion pinned the base's initial states (its fitted start moved
            # to absorb a misfit): the candidates start pinned too, without a second fit.
            self.initial_state = 'measured'
        self.anchor = self._anchor_fit()
        steps = []
        analysis_before = self.analyse(base)
        analysis = analysis_before
        reason = 'explained'
        out_of_time = False
        try:
            while True:
                if self.explained(analysis):
                    reason = 'the residual is white' if not self._negligible(analysis) else \
                        'the model reproduces the data exactly'
                    break
                if len(current.structure) >= self.max_effects:
                    reason = f'stopped at {self.max_effects} effects'
                    break
                step = self._round(current, analysis)
                steps.append(step.report)
                if step.chosen is None:
                    reason = 'no candidate lowers the held-out error enough'
                    break
                current = step.chosen.fitted
                analysis = self.analyse(current)
        except TimeBudgetExceeded:
            out_of_time = True
            reason = 'the time budget ran out: the best structure so far is kept'
        current, reason = never_worse(base, current, reason)
        try:
            if out_of_time:
                raise TimeBudgetExceeded('no time left for the all-data refit')
            if self.progress is not None:
                self.progress.set_stage('discovery: final refit on all the data')
            if len(current.structure) == 0 and estimate is not None:
                # The base model on all of the data is the one given: no refit.
                records, terms, base_estimate = list(self.records), (), estimate
            else:
                records, terms, estimate = self.refit_all(current)
                base_estimate = self.refit_all(base)[2] if len(current.structure) else estimate
        except TimeBudgetExceeded:
            # The training-part fits are what there is: report them, said so in the result.
            out_of_time = True
            records, terms = current.records, current.terms
            estimate, base_estimate = current.estimate, base.estimate
        return DiscoveryResult(
            holdout_fraction=self.holdout_fraction, min_gain=self.min_gain,
            outputs=self.outputs, torque_constant=self.torque_constant,
            source_records=list(self.records), base=base, final=current, steps=steps,
            analysis_before=analysis_before, analysis_after=analysis, reason=reason,
            unexplained=self.material(analysis), records=records, terms=terms,
            estimate=estimate, effects=current.structure.effects(estimate.parameters),
            base_estimate=base_estimate, error_before=base.errors(self.error_channels),
            error_after=current.errors(self.error_channels), out_of_time=out_of_time,
            quasi_static=self.quasi_static, criterion=self.criterion)

    def _round(self, current: Fit, analysis: dict) -> Round:
        """One search round: screen every absent effect, refit the promising, choose."""
        residual, matrix, nominal = self._base_sensitivities(current)
        q = self._projector(matrix)
        present = set(current.structure.names())
        screened = []
        for cls in self.candidates:
            if cls.name in present:
                continue
            candidate = self.screen_candidate(current, cls, residual, q, nominal)
            if candidate is not None:
                screened.append(candidate)
        # Refit the candidates the linearised screen supports, and the best few anyway (the
        # screen is a linearisation: a strongly nonlinear effect may look smaller than it is).
        screened.sort(key=lambda candidate: -candidate.screen_explained)
        threshold = SCREEN_SHARE * self.min_gain
        top = SCREEN_TOP_MISFIT if self.misfit(current) else SCREEN_TOP
        scored = []
        for rank, candidate in enumerate(screened):
            if rank < top or candidate.screen_explained >= threshold:
                if self.progress is not None:
                    self.progress.set_stage(f'discovery: candidate {candidate.name}')
                candidate = self.score(current, self.refit_candidate(current, candidate))
            scored.append(candidate)
        order = {cls.name: position for position, cls in enumerate(self.candidates)}
        refitted = sorted((candidate for candidate in scored if candidate.fit is not None),
                          key=lambda candidate: candidate.fitted.heldout_cost)
        screened_out = sorted((candidate for candidate in scored if candidate.fit is None),
                              key=lambda candidate: -candidate.screen_explained)
        chosen = None
        equivalent: list[Candidate] = []
        while chosen is None:
            admissible = [candidate for candidate in refitted if not candidate.problem]
            chosen, equivalent = self._choose(current, admissible, order)
            if chosen is None:
                break
            doubt = self._unearned(current, chosen)
            if doubt:
                # Rejected, and the next best is considered in its place.
                refitted = [replace(candidate, problem=doubt) if candidate is chosen
                            else candidate for candidate in refitted]
                chosen = None
        results = refitted + screened_out
        report: dict[str, Any] = {
            'error_before': current.errors(self.error_channels),
            'candidates': [self._candidate_report(candidate, analysis)
                           for candidate in results],
            'added': None,
        }
        if chosen is not None:
            report['added'] = chosen.describe()
            report['error_after'] = chosen.fitted.errors(self.error_channels)
            report['gain_pct'] = chosen.gain * 100.0
            report['equivalent'] = [candidate.describe() for candidate in equivalent]
        return Round(results, chosen, report)

    def _choose(self, current, admissible, order):
        """Return the best admissible candidate when it gains enough (and its ties), else None."""
        drop = current.heldout_cost - admissible[0].fitted.heldout_cost if admissible else 0.0
        if not drop > 0:
            return None, []
        ties = [candidate for candidate in admissible
                if current.heldout_cost - candidate.fitted.heldout_cost >= TIE_SHARE * drop]
        winner = min(ties, key=lambda candidate: order[candidate.name])
        # Refitted candidates are scored: gain, bic_delta and gain_noise are set.
        noise = winner.gain_noise
        if winner.gain >= self.min_gain and winner.bic_delta < 0 and (
                noise is None or winner.gain > noise):
            return winner, [candidate for candidate in ties if candidate is not winner]
        return None, []

    def gain_t(self, current: Fit, fitted: Fit) -> float:
        """
        Student t of the held-out gain over contiguous blocks (its size against its noise).

        Every record's held-out part is cut into :data:`GAIN_BLOCKS` blocks; the gain of a
        block is the drop of its weighted squared residual.  A gain that a few blocks carry
        while the others lose (a model fitting noise, or trading one stretch for another) has
        a small t.
        """
        weights = self.weights or {}

        def squared(fit: Fit, index: int) -> np.ndarray:
            start = fit.stops[index]
            total = np.zeros(fit.simulated[index][self.outputs[0]].shape[0] - start)
            for channel in self.outputs:
                total += ((fit.simulated[index][channel][start:]
                           - getattr(fit.records[index], channel)[start:])
                          / weights.get(channel, 1.0)) ** 2
            return total

        drops = []
        for index in range(len(current.stops)):
            old, new = squared(current, index), squared(fitted, index)
            size = min(old.shape[0], new.shape[0])
            for block in np.array_split(np.arange(size), GAIN_BLOCKS):
                if block.shape[0]:
                    drops.append(float(np.mean(old[block]) - np.mean(new[block])))
        drops_array = np.array(drops)
        if drops_array.shape[0] < 2 or not np.all(np.isfinite(drops_array)):
            return 0.0
        spread = float(np.std(drops_array, ddof=1)) / np.sqrt(drops_array.shape[0])
        mean = float(np.mean(drops_array))
        return mean / spread if spread > 0 else (np.inf if mean > 0 else 0.0)

    def _unearned(self, current: Fit, candidate: Candidate) -> str | None:
        """
        Why a winning candidate has not earned its place on held-out data, or None.

        Its own part of the simulated outputs must exceed the noise (:meth:`own_part`); unless
        it stands far out of it (:data:`OWN_PART_STRONG` noise levels), its held-out gain must
        stand out of the gain's own noise over blocks (:meth:`gain_t` at least
        :data:`GAIN_T`).  An effect beyond a physical size limit (a cogging ripple larger than
        the Coulomb friction) always needs twice that t and twice the gain.
        """
        own = self.own_part(candidate)
        if own is not None and own[0] <= 1.0:
            return (f'its own part of the simulated outputs is below the noise ({own[1]}): its '
                    'held-out gain comes from moving the other parameters')
        required, gain = GAIN_T, self.min_gain
        strong = own is not None and own[0] >= OWN_PART_STRONG
        values = candidate.fitted.values
        size = ''
        if candidate.name == 'cogging':
            amplitude = float(np.hypot(values.get('cogging.sin_Nm', 0.0),
                                       values.get('cogging.cos_Nm', 0.0)))
            if amplitude > values.get('Mc', 0.0):
                required, gain, strong = 2.0 * GAIN_T, 2.0 * self.min_gain, False
                size = (f' (a ripple of {amplitude:.3g} N m, larger than the Coulomb friction '
                        f'{values.get("Mc", 0.0):.3g} N m, needs t >= {required:g} and a gain of '
                        f'{100 * gain:.0f} %)')
        achieved = float(candidate.gain or 0.0)
        if strong and achieved >= gain:
            return None
        t = self.gain_t(current, candidate.fitted)
        if t >= required and achieved >= gain:
            return None
        return (f'its held-out gain ({100 * achieved:.3g} %, t = {t:.2g} over '
                f'{GAIN_BLOCKS} blocks per record) does not stand out of its own noise{size}')

    def own_part(self, candidate: Candidate) -> tuple[float, str] | None:
        """
        Size of an effect's own part of the simulated outputs, in noise levels, and its text.

        The refit is simulated again with the effect's coefficients at zero; the largest
        channel's RMS difference over its noise (the sensor noise, or :data:`OWN_PART_SHARE` of
        the refit's residual RMS when larger: input noise integrated by the motor, or misfit).
        An effect below one noise level explains no part of the signal that stands out: a gain
        it brings comes from moving the other parameters (extra freedom, not an effect).  None
        for data effects (delays), which are not judged so.
        """
        from dcmotor_id.identification.identifiability import noise_level

        fitted = candidate.fitted
        prefix = f'{candidate.name}.'
        terms = [term for term in fitted.terms if term.name.startswith(prefix)]
        if not terms or candidate.effect.TRANSFORM:
            return None
        values = dict(fitted.values)
        for term in terms:
            values[term.name] = 0.0
        model = OutputErrorModel(fitted.records, self.torque_constant, fitted.terms,
                                 self.quasi_static)
        without = simulate_records(model, values, fitted.estimate.initial_states)
        ratio, texts = 0.0, []
        for channel in self.outputs:
            difference = np.concatenate([sim[channel] - out[channel] for sim, out
                                         in zip(fitted.simulated, without)])
            sensor = np.sqrt(np.mean([noise_level(getattr(rec, channel)) ** 2
                                      for rec in fitted.records]))
            misfit = float(fitted.estimate.info.get('noise_std', {}).get(channel, 0.0))
            noise = max(float(sensor), OWN_PART_SHARE * misfit, 1e-300)
            rms = float(np.sqrt(np.mean(difference ** 2)))
            if not np.isfinite(rms):
                return None
            ratio = max(ratio, rms / noise)
            texts.append(f'{channel} {rms:.3g} against a noise of {noise:.3g}')
        return ratio, ', '.join(texts)

    @staticmethod
    def _candidate_report(candidate, analysis):
        correlation = max((channel['regressors'].get(candidate.name, {}).get('max_abs', 0.0)
                           for channel in analysis.values()), default=0.0)
        return {
            'name': candidate.name,
            'inner': dict(candidate.inner),
            'refitted': candidate.fit is not None,
            'rejected': candidate.problem,
            'heldout_gain_pct': None if candidate.gain is None else candidate.gain * 100.0,
            'heldout_gain_noise_pct': _pct_or_none(candidate.gain_noise),
            'insample_gain_pct': _pct_or_none(candidate.insample_gain),
            'bic_delta': candidate.bic_delta,
            'screen_explained_pct': candidate.screen_explained * 100.0,
            'regressor_correlation': correlation,
        }

    def refit_all(self, fitted: Fit) -> tuple[list[Record], tuple, Estimate]:
        """Refit a structure on all the data (no hold-out), from the training values."""
        return refit_all_data(fitted.structure, self.records, self.torque_constant,
                              fitted.values, self._base(fitted), progress=self.progress,
                              initial_states=fitted.estimate.initial_states,
                              initial_state=self.initial_state,
                              quasi_static=self.quasi_static, criterion=self.criterion)


def _pct_or_none(value: float | None) -> float | None:
    return None if value is None else float(value) * 100.0


def discover(records: Sequence[Record], torque_constant: float | None = None,
             **options: Any) -> DiscoveryResult:
    """Run the discovery loop on prepared records; return a :class:`DiscoveryResult`."""
    return DiscoveryLoop(records, torque_constant, **options).run()
