"""
The effect discovery loop: trace the residual to an effect the model lacks, add it, repeat.

1. Split every record in time: the first part (70 % by default) trains, the rest is held out.
2. Fit the base model on the training part; simulate the whole record (the held-out part continues
   the simulation from the training part) and analyse the held-out residual
   (:mod:`dcmotor_id.identification.residuals`): Ljung-Box whiteness, predictable share,
   correlation with the inputs and with every candidate's regressor.
3. If the residual is not white, try every effect of the vocabulary
   (:mod:`dcmotor_id.identification.effects`) not yet in the model.  A cheap linearised screen (the
   residual
   regressed on the sensitivities of the base parameters and of the candidate's terms) picks
   each candidate's inner parameters (Stribeck velocity, cogging period, delay); then *all*
   parameters are refitted on the training part and the candidate is scored by the weighted
   mean squared simulation error on the **held-out** part.
4. The best candidate is added when it lowers the held-out error by at least ``min_gain``
   (5 %) and the Bayesian information criterion of the training fit; candidates within 2 % of
   the best one's improvement are a tie, won by the earlier in the vocabulary and reported as
   equivalent.  Repeat until the residual is white or nothing helps.
5. Refit the final structure on all the data (the reported parameters).

``unexplained`` is true when the final held-out residual is still not white *and* an
autoregressive predictor explains at least 5 % of it from its own past (structure of a size
that matters) while no candidate helps: the evidence says how much and where.

:class:`DiscoveryLoop` does all the fitting; what it found is plain data
(:class:`DiscoveryResult`, its search rounds :class:`Round` of screened and refitted
:class:`Candidate` effects).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import parameter_names
from dcmotor_id.core.progress import Progress, TimeBudgetExceeded
from dcmotor_id.identification.criterion import fitted_outputs
from dcmotor_id.identification.effects import SensorDelay, torque_spread, VOCABULARY
from dcmotor_id.identification.estimators.jacobian import jacobian
from dcmotor_id.identification.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.identification.residuals import (ALPHA, analyse_channel, channel_errors,
                                                 ChannelErrors, correlation_summary, DEFAULT_LAGS,
                                                 model_errors, one_step_error, output_channels,
                                                 residual_nrmse_pct, simulate_records)

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.effects import Effect
    from dcmotor_id.identification.estimators.base import Estimate, ExogenousTerm

#: Share of each record held out for selection.
HOLDOUT_FRACTION = 0.3
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
#: Contiguous blocks of the held-out part whose error drops give the noise of the gain.
HELDOUT_BLOCKS = 8
#: Standard errors of the held-out drop a candidate's gain must exceed.
GAIN_NOISE_FACTOR = 2.0
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


class Structure:
    """An ordered list of effects with their inner parameters: ``[(effect class, inner)]``."""

    def __init__(self, items: Sequence[tuple[type[Effect], dict]] = ()) -> None:
        self.items = list(items)

    def __len__(self) -> int:
        """Return the number of effects."""
        return len(self.items)

    def names(self) -> list[str]:
        """Vocabulary names in the order added."""
        return [cls.name for cls, _ in self.items]

    def plus(self, cls: type[Effect], inner: dict) -> Structure:
        """Return a new structure with one more effect."""
        return Structure(self.items + [(cls, dict(inner))])

    def transformed(self, records: Sequence[Record]) -> list[Record]:
        """Apply the data effects (sensor delays) to the records."""
        out = list(records)
        for cls, inner in self.items:
            if cls.TRANSFORM:
                out = cls.transform(out, inner)
        return out

    def terms(self, records: Sequence[Record], base: dict, torque_constant: float | None = None,
              initial: dict | None = None) -> tuple[ExogenousTerm, ...]:
        """All exogenous terms of the structure on (transformed) records."""
        terms: list[ExogenousTerm] = []
        for cls, inner in self.items:
            terms.extend(cls.terms(records, inner, base, torque_constant, initial))
        return tuple(terms)

    def effects(self, values: dict) -> list[Effect]:
        """Return the fitted effect instances for a parameter dict."""
        return [cls.from_fit(values, inner) for cls, inner in self.items]


def _slice_terms(terms, stops):
    return tuple(replace(term, regressors=tuple(reg[:stop] for reg, stop in
                                                zip(term.regressors, stops)))
                 for term in terms)


def _with_initial(terms, values):
    return tuple(replace(term, initial=float(values.get(term.name, term.initial)))
                 for term in terms)


def _part(arrays, stops, part):
    """
    Concatenate the training (``train``) or held-out (``heldout``) part of per-record arrays.

    A single record's part is a view (no copy): callers only read it.
    """
    pieces = [values[:stop] if part == 'train' else values[stop:]
              for values, stop in zip(arrays, stops)]
    return pieces[0] if len(pieces) == 1 else np.concatenate(pieces)


@dataclass
class Fit:
    """A structure fitted on the training parts and simulated over the whole records."""

    structure: Structure
    estimate: Estimate
    records: list
    stops: list
    simulated: list
    terms: tuple
    train_cost: float = 0.0
    heldout_cost: float = 0.0
    n_train: int = 0
    info: dict = field(default_factory=dict)

    @property
    def values(self) -> dict:
        """Fitted parameters (base and term coefficients)."""
        return self.estimate.parameters

    def channel_simulated(self, channel: str, part: str) -> np.ndarray:
        """Return the simulation of one channel on a part (train or heldout), concatenated."""
        return _part([sim[channel] for sim in self.simulated], self.stops, part)

    def channel_measured(self, channel: str, part: str) -> np.ndarray:
        """Measurement of one channel on a part, concatenated."""
        return _part([getattr(rec, channel) for rec in self.records], self.stops, part)

    def channel_residual(self, channel: str, part: str) -> np.ndarray:
        """Model minus measurement of one channel on a part, concatenated."""
        pieces = [(sim[channel][:stop] - getattr(rec, channel)[:stop]) if part == 'train' else
                  (sim[channel][stop:] - getattr(rec, channel)[stop:])
                  for rec, sim, stop in zip(self.records, self.simulated, self.stops)]
        return pieces[0] if len(pieces) == 1 else np.concatenate(pieces)

    def errors(self, outputs: Sequence[str], part: str = 'heldout') -> ChannelErrors:
        """
        ``{current_nrmse_pct, speed_nrmse_pct}`` on a part (current None if no output).

        In percent of each channel's spread over the *whole* records joined: a held-out part
        in a steady tail has a tiny spread of its own, which would make any error look huge.
        """
        errors = channel_errors({channel: self.channel_simulated(channel, part)
                                 for channel in outputs},
                                {channel: self.channel_measured(channel, part)
                                 for channel in outputs}, outputs)
        for channel in outputs:
            key = f'{channel}_nrmse_pct'
            own = float(np.std(self.channel_measured(channel, part)))
            whole = float(np.std(np.concatenate([getattr(rec, channel)
                                                 for rec in self.records])))
            value = errors.get(key)
            if value is not None and whole > 0:
                errors[key] = value * own / whole
        return errors


@dataclass(frozen=True, eq=False)
class Candidate:
    """
    One effect tried in a search round: its screen, then (maybe) its refit and score.

    Attributes
    ----------
    effect : type
        The effect class (of the vocabulary).
    inner : dict
        Its inner parameters (from the screen's grid; after a refit, the refitted ones).
    start : dict
        Start values of its coefficients (from the linearised screen).
    screen_explained : float
        Share of the residual's sum of squares the linearised screen explains.
    fit : Fit or None
        The structure with the candidate refitted on the training parts (None: not refitted,
        or the refit failed).
    problem : str or None
        Why the refitted candidate is not admissible (physics, collapse), or None.
    gain : float or None
        Relative drop of the held-out cost against the current structure.
    bic_delta : float or None
        Change of the training BIC.
    insample_gain : float or None
        Relative drop of the training cost (the part the candidate was fitted on).
    gain_noise : float or None
        Noise of ``gain``: :data:`GAIN_NOISE_FACTOR` standard errors of the drop, from its
        spread over :data:`HELDOUT_BLOCKS` contiguous blocks of the held-out part
        (:func:`heldout_gain_noise`); the gain must exceed it.

    """

    effect: type[Effect]
    inner: dict
    start: dict
    screen_explained: float
    fit: Fit | None = None
    problem: str | None = None
    gain: float | None = None
    bic_delta: float | None = None
    insample_gain: float | None = None
    gain_noise: float | None = None

    @property
    def name(self) -> str:
        """Vocabulary name of the effect."""
        return self.effect.name

    @property
    def fitted(self) -> Fit:
        """Return the refit (of a candidate that was refitted: :attr:`fit` is set)."""
        if self.fit is None:
            raise ValueError(f'{self.name} was not refitted')
        return self.fit

    def describe(self) -> dict:
        """Return the refitted effect's ``{"name", "parameters"}``."""
        values = self.fitted.values
        return self.fitted.structure.effects(values)[-1].describe(values)


@dataclass
class Round:
    """One search round: the candidates scored, the one chosen and its JSON report."""

    candidates: list[Candidate]
    chosen: Candidate | None
    report: dict


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
        self.position_ar: list[float] | None = None

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
                                    initial_states=initial_states, position_ar=self.position_ar)
        if not start and terms:
            raise ValueError('a structure with effects needs a start point')
        estimate = estimator.fit(train, torque_constant=self.torque_constant,
                                 terms=_slice_terms(terms, stops))
        if self.position_ar is None:  # the base's error model warm-starts the candidates'
            self.position_ar = estimate.info.get('position_ar')
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


def open_loop_outputs(structure: Structure, estimate: Estimate, records: Sequence[Record],
                      torque_constant: float | None = None) -> list[dict[str, np.ndarray]]:
    """
    Simulate a fitted structure open loop, as ``dcmotor-id validate`` does; per record.

    The fit's effect terms are regressors of *measured* signals (the speed's magnitude, the
    measured position's angle), which on the held-out part would feed the measurement into
    the prediction; here every effect is driven by the simulated state
    (:func:`dcmotor_id.identification.validate.simulate`), so that a candidate is judged as
    the model will be used.  The position starts at the fitted initial position.
    """
    from dcmotor_id.identification.validate import Model, simulate

    values = estimate.parameters
    effects = [{'name': effect.name, 'parameters': dict(effect.parameters)}
               for effect in structure.effects(values) if not type(effect).TRANSFORM]
    mechanical = torque_constant is not None
    model = Model({name: float(values[name]) for name in parameter_names(mechanical)},
                  'mechanical' if mechanical else 'full', torque_constant, effects)
    n_dynamic = 1 if mechanical else 2
    outputs = []
    for rec, state in zip(records, estimate.initial_states):
        with np.errstate(all='ignore'):
            out = simulate(model, rec, np.asarray(state[:n_dynamic], dtype=float))
        if len(state) > n_dynamic and rec.position is not None:
            out['position'] = out['position'] + (float(state[n_dynamic]) - float(rec.position[0]))
        outputs.append(out)
    return outputs


def _pct_or_none(value: float | None) -> float | None:
    return None if value is None else float(value) * 100.0


def heldout_gain_noise(current: Fit, candidate: Fit, outputs: Sequence[str],
                       weights: dict[str, float]) -> float:
    """
    Noise of a candidate's relative held-out gain: two standard errors of the error drop.

    The weighted squared held-out errors of both fits (the held-out cost's terms) are
    subtracted sample by sample and summed over :data:`HELDOUT_BLOCKS` contiguous blocks;
    the blocks' spread gives the standard error of the total drop (blocks far longer than the
    residual's correlation are nearly independent; shorter ones make it conservative).
    Returns ``GAIN_NOISE_FACTOR`` times it relative to the current held-out cost (``inf``
    when it cannot be computed).
    """
    drop = None
    for channel in outputs:
        before = current.channel_residual(channel, 'heldout')
        after = candidate.channel_residual(channel, 'heldout')
        # A data effect (a sensor delay) shifts the records by a few samples: the common end.
        common = min(before.shape[0], after.shape[0])
        before, after = before[before.shape[0] - common:], after[after.shape[0] - common:]
        if common < 2 * HELDOUT_BLOCKS:
            return float('inf')
        term = (before ** 2 - after ** 2) / (max(weights.get(channel, 1.0), 1e-300) ** 2
                                             * before.shape[0])
        drop = term if drop is None else drop + term
    if drop is None or not np.all(np.isfinite(drop)) or current.heldout_cost <= 0.0:
        return float('inf')
    sums = np.array([part.sum() for part in np.array_split(drop, HELDOUT_BLOCKS)])
    stderr = float(np.sqrt(HELDOUT_BLOCKS) * np.std(sums, ddof=1))
    return GAIN_NOISE_FACTOR * stderr / current.heldout_cost


def never_worse(base: Fit, final: Fit, reason: str) -> tuple[Fit, str]:
    """Return the final structure, or the base one when it is not better on the held-out part."""
    if final is base or final.heldout_cost < base.heldout_cost:
        return final, reason
    return base, (reason + '; the effects found did not lower the held-out error of the base '
                  'model, which is kept')


def refit_start(values: dict, records: Sequence[Record],
                torque_constant: float | None = None) -> dict[str, float]:
    """
    Start point of a refit: the fitted base values, with b and Mc lifted off zero.

    The fit works on logarithms, so a friction that a missing effect drove to zero would
    stay there; a floor of 2 % of the driving torque's spread lets it come back.
    """
    names = [name for name in parameter_names(torque_constant is not None) if name in values]
    start = {name: float(values[name]) for name in names}
    floors = friction_floors(start, records, torque_constant)
    start['Mc'] = max(start['Mc'], floors['Mc'])
    start['b'] = max(start['b'], floors['b'])
    return start


def friction_floors(values: dict, records: Sequence[Record],
                    torque_constant: float | None = None) -> dict[str, float]:
    """Return the least start of Mc and b in a refit: 2 % of the driving torque's spread."""
    spread = torque_spread(records, values, torque_constant)
    speed = max(float(np.std(np.concatenate([rec.speed for rec in records]))), 1e-12)
    return {'Mc': 0.02 * spread, 'b': 0.02 * spread / speed}


#: Blocks of the excitation measure of :func:`excited_stop`.
EXCITATION_BLOCKS = 200
#: Bounds of the training part as shares of the moving extent: enough to fit (a record of
#: two steps keeps part of the second level to train on), enough to judge.
TRAIN_SHARE_BOUNDS = (0.6, 0.85)


def excited_stop(record: Record, holdout_fraction: float = HOLDOUT_FRACTION,
                 channels: Sequence[str] = ('speed',)) -> int:
    """
    End of a record's training part: the rest carries the held-out share of its excitation.

    Within the moving extent (:func:`moving_extent`) the excitation is the change of each
    channel's block means beyond their noise (:data:`EXCITATION_BLOCKS` blocks; standstill and
    steady speed add nothing), each channel normalised to its total.  The training part ends
    at the last block boundary before which at most ``1 - holdout_fraction`` of it lies,
    within :data:`TRAIN_SHARE_BOUNDS` of the moving extent; without measurable excitation,
    at ``1 - holdout_fraction`` of the extent.
    """
    from dcmotor_id.identification.identifiability import noise_level

    first, last = moving_extent(np.asarray(record.speed, dtype=float))
    size = last - first
    fallback = first + size * (1.0 - holdout_fraction)
    blocks = min(EXCITATION_BLOCKS, size // 5)
    stop = fallback
    if blocks >= 4:
        edges = np.linspace(0, size, blocks + 1).astype(int)
        weight = np.zeros(blocks - 1)
        for channel in channels:
            values = np.asarray(getattr(record, channel), dtype=float)[first:last]
            means = np.add.reduceat(values, edges[:-1]) / np.diff(edges)
            floor = 4.0 * noise_level(values) * np.sqrt(2.0 / max(int(np.min(np.diff(edges))),
                                                                  1))
            change = np.abs(np.diff(means))
            change[change <= floor] = 0.0
            if change.sum() > 0:
                weight += change / change.sum()
        if weight.sum() > 0:
            share = np.cumsum(weight) / weight.sum()
            below = np.flatnonzero(share <= 1.0 - holdout_fraction)
            stop = first + (edges[int(below[-1]) + 1] if below.shape[0] else edges[1])
    low, high = TRAIN_SHARE_BOUNDS
    stop = min(max(stop, first + low * size), first + high * size)
    return min(max(int(round(stop)), 1), len(record) - 1)


def moving_extent(speed: np.ndarray) -> tuple[int, int]:
    """
    Return the first and one past the last sample where a speed moves beyond its noise.

    The whole record when it never leaves the noise band (the caller decides then).
    """
    from dcmotor_id.signals.filters import low_pass, noise_std

    speed = np.asarray(speed, dtype=float)
    smooth = low_pass(speed, 0.05, order=2)
    noise = noise_std(speed)
    level = max(min(10.0 * noise, 0.2 * float(np.max(np.abs(smooth)))), 1e-300)
    moving = np.flatnonzero(np.abs(smooth - smooth[0]) > level)
    if moving.shape[0] < 2:
        return 0, speed.shape[0]
    # Keep a little standstill after the motion ends: the stop is part of the dynamics.
    margin = max(speed.shape[0] // 50, 1)
    return 0, min(int(moving[-1]) + 1 + margin, speed.shape[0])


def refit_all_data(structure: Structure, records: Sequence[Record],
                   torque_constant: float | None, values: dict, start: dict,
                   **options: Any) -> tuple[list[Record], tuple, Estimate]:
    """
    Fit a structure on all of the records (no hold-out).

    The effects' coefficients start from ``values``, the base parameters from ``start``
    (:func:`refit_start`); return the (transformed) records, the terms and the estimate.
    ``options`` go to the :class:`~dcmotor_id.identification.estimators.refined.RefinedEstimator`.
    """
    prepared = structure.transformed(records)
    terms = _with_initial(structure.terms(prepared, values, torque_constant), values)
    estimator = RefinedEstimator(initial=start, **options)
    return prepared, terms, estimator.fit(prepared, torque_constant=torque_constant,
                                          terms=terms)


@dataclass(eq=False)
class DiscoveryResult:
    """
    What the loop found, with everything the report plots (plain data, built by the loop).

    Attributes
    ----------
    holdout_fraction, min_gain : float
        The loop's settings.
    outputs : tuple of str
        The simulated channels.
    torque_constant : float or None
        Mechanical-only mode.
    source_records : list of Record
        The records the loop ran on.
    base, final : Fit
        Base and final structure fitted on the training parts.
    steps : list of dict
        One report per search round (candidates scored, effect added, errors).
    analysis_before, analysis_after : dict
        Held-out residual analyses of the base and the final model.
    reason : str
        Why the loop stopped.
    unexplained : bool
        Structure that matters remains in the final residual.
    records, terms, estimate :
        The final structure refitted on all the data.
    effects : list of Effect
        The effects found, with the all-data values.
    base_estimate : Estimate
        The base structure refitted on all the data.
    error_before, error_after : dict
        Held-out simulation error of the base and the final model.
    out_of_time : bool
        The time budget ran out: the structure is the best so far and, when there was no
        time for the all-data refit, ``estimate`` is the training-part fit.
    quasi_static : bool
        The quasi-static armature (La -> 0) was fitted.

    """

    holdout_fraction: float
    min_gain: float
    outputs: tuple
    torque_constant: float | None
    source_records: list
    base: Fit
    final: Fit
    steps: list
    analysis_before: dict
    analysis_after: dict
    reason: str
    unexplained: bool
    records: list
    terms: tuple
    estimate: Estimate
    effects: list
    base_estimate: Estimate
    error_before: ChannelErrors
    error_after: ChannelErrors
    out_of_time: bool = False
    quasi_static: bool = False
    criterion: str = 'speed'

    def errors_on(self, records: Sequence[Record]) -> dict[str, ChannelErrors]:
        """
        Simulate the all-data base and final models on other records; return their errors.

        Each record is simulated from its first measured sample (speed, and current in the
        full mode) with the measured input; data effects (delays) are applied first.

        Returns
        -------
        dict
            ``before`` and ``after``, each ``{current_nrmse_pct, speed_nrmse_pct}``.

        """
        tc = self.torque_constant
        return {'before': structure_errors(Structure(), self.base_estimate, records, tc),
                'after': structure_errors(self.final.structure, self.estimate, records, tc)}

    def effects_json(self) -> list[dict]:
        """``[{"name", "parameters"}]`` in the order added, with the all-data values."""
        return [effect.describe(self.estimate.parameters) for effect in self.effects]

    def evidence(self) -> dict[str, dict[str, Any]]:
        """Summary of the final residual analysis (JSON-ready)."""
        out = {}
        for channel, item in self.analysis_after.items():
            out[channel] = {
                'ljung_box_statistic': item['ljung_box']['statistic'],
                'ljung_box_p_value': item['ljung_box']['p_value'],
                'lags': item['ljung_box']['lags'],
                'predictable_fraction': item['predictable_fraction'],
                'acf_outside_band': item['acf_outside_band'],
                'input_correlation': {name: value['max_abs']
                                      for name, value in item['inputs'].items()},
                'nrmse_pct': item['nrmse_pct'],
            }
        return out

    def summary(self) -> dict[str, Any]:
        """JSON-ready account of the loop."""
        return {
            'holdout_fraction': self.holdout_fraction,
            'min_gain_pct': self.min_gain * 100.0,
            'reason': self.reason,
            'base_heldout_parameters': {key: float(value) for key, value in
                                        self.base.values.items()},
            'steps': self.steps,
            'evidence_before': _evidence(self.analysis_before),
            'evidence_after': self.evidence(),
        }


def errors_by_step(found: DiscoveryResult, records: Sequence[Record]) -> list[dict[str, Any]]:
    """
    Errors on other records after each effect added (all-data refits), in order.

    The base and the final structure are the result's all-data fits; every structure in
    between is refitted here on the loop's records.

    Returns
    -------
    list of dict
        ``{'effects': [names], current_nrmse_pct, speed_nrmse_pct}``, the base model
        first.

    """
    items = found.final.structure.items
    tc = found.torque_constant
    out = []
    for count in range(len(items) + 1):
        structure = Structure(items[:count])
        if count == 0:
            estimate = found.base_estimate
        elif count == len(items):
            estimate = found.estimate
        else:
            estimate = refit_all_data(
                structure, found.source_records, tc, found.estimate.parameters,
                refit_start(found.final.values, found.source_records, tc),
                quasi_static=found.quasi_static, criterion=found.criterion)[2]
        errors = structure_errors(structure, estimate, records, tc)
        out.append({'effects': structure.names(), **errors})
    return out


def structure_errors(structure: Structure, estimate: Estimate, records: Sequence[Record],
                     torque_constant: float | None = None) -> ChannelErrors:
    """
    Simulate a fitted structure on records, each from its first sample; return the errors.

    Returns
    -------
    dict
        ``{current_nrmse_pct, speed_nrmse_pct}`` (current None in mechanical-only mode).

    """
    prepared = structure.transformed(records)
    values = estimate.parameters
    terms = structure.terms(prepared, values, torque_constant, values)
    model = OutputErrorModel(prepared, torque_constant, terms,
                             bool(estimate.info.get('quasi_static')))
    states = [[float(getattr(rec, channel)[0]) for channel in model.outputs]
              for rec in prepared]
    return model_errors(model, values, states)


def _evidence(analysis):
    return {channel: {'ljung_box_p_value': item['ljung_box']['p_value'],
                      'predictable_fraction': item['predictable_fraction'],
                      'nrmse_pct': item['nrmse_pct']}
            for channel, item in analysis.items()}


def discover(records: Sequence[Record], torque_constant: float | None = None,
             **options: Any) -> DiscoveryResult:
    """Run the discovery loop on prepared records; return a :class:`DiscoveryResult`."""
    return DiscoveryLoop(records, torque_constant, **options).run()
