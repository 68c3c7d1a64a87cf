"""
The discovery loop: trace the residual to an effect the model lacks, add it, repeat.

1. Split every record in time: the first part (70 % by default) trains, the rest is held out.
2. Fit the base model on the training part; simulate the whole record (the held-out part
   continues the simulation from the training part) and analyse the held-out residual
   (:mod:`dcmotor_id.residuals`): Ljung-Box whiteness, predictable share, correlation with the
   inputs and with every candidate's regressor.
3. If the residual is not white, try every effect of the vocabulary
   (:mod:`dcmotor_id.effects`) not yet in the model.  A cheap linearised screen (the residual
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
"""

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import qr

from dcmotor_id.effects import SensorDelay, torque_spread, VOCABULARY
from dcmotor_id.errors import DcMotorIdError
from dcmotor_id.estimators.base import nrmse_pct
from dcmotor_id.estimators.refined import OutputErrorModel, RefinedEstimator
from dcmotor_id.residuals import ALPHA, analyse_channel, DEFAULT_LAGS

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
#: Bound on the Jacobian evaluations of a candidate's refit (per parameter, as in
#: :class:`~dcmotor_id.estimators.refined.RefinedEstimator`).
CANDIDATE_MAX_NFEV = 30


class Structure:
    """An ordered list of effects with their inner parameters: ``[(effect class, inner)]``."""

    def __init__(self, items=()):
        self.items = list(items)

    def __len__(self):
        """Return the number of effects."""
        return len(self.items)

    def names(self):
        """Vocabulary names in the order added."""
        return [cls.name for cls, _ in self.items]

    def plus(self, cls, inner):
        """Return a new structure with one more effect."""
        return Structure(self.items + [(cls, dict(inner))])

    def transformed(self, records):
        """Apply the data effects (sensor delays) to the records."""
        out = list(records)
        for cls, inner in self.items:
            if cls.TRANSFORM:
                out = cls.transform(out, inner)
        return out

    def terms(self, records, base, torque_constant=None, initial=None):
        """All exogenous terms of the structure on (transformed) records."""
        terms = []
        for cls, inner in self.items:
            terms.extend(cls.terms(records, inner, base, torque_constant, initial))
        return tuple(terms)

    def effects(self, values):
        """Return the fitted effect instances for a parameter dict."""
        return [cls.from_fit(values, inner) for cls, inner in self.items]


def _slice_terms(terms, stops):
    return tuple(replace(term, regressors=tuple(reg[:stop] for reg, stop in
                                                zip(term.regressors, stops)))
                 for term in terms)


def _with_initial(terms, values):
    return tuple(replace(term, initial=float(values.get(term.name, term.initial)))
                 for term in terms)


@dataclass
class Fit:
    """A structure fitted on the training parts and simulated over the whole records."""

    structure: Structure
    estimate: object
    records: list
    stops: list
    simulated: list
    terms: tuple
    train_cost: float = 0.0
    heldout_cost: float = 0.0
    n_train: int = 0
    info: dict = field(default_factory=dict)

    @property
    def values(self):
        """Fitted parameters (base and term coefficients)."""
        return self.estimate.parameters

    def channel_residual(self, channel, part):
        """Model minus measurement of one channel, ``part`` train or heldout, concatenated."""
        pieces = []
        for rec, sim, stop in zip(self.records, self.simulated, self.stops):
            error = sim[channel] - getattr(rec, channel)
            pieces.append(error[:stop] if part == 'train' else error[stop:])
        return np.concatenate(pieces)

    def channel_measured(self, channel, part):
        """Measurement of one channel on a part, concatenated."""
        pieces = []
        for rec, stop in zip(self.records, self.stops):
            values = getattr(rec, channel)
            pieces.append(values[:stop] if part == 'train' else values[stop:])
        return np.concatenate(pieces)

    def errors(self, outputs, part='heldout'):
        """``{current_nrmse_pct, speed_nrmse_pct}`` on a part (current None if no output)."""
        out = {'current_nrmse_pct': None, 'speed_nrmse_pct': None}
        for channel in outputs:
            value = nrmse_pct(self.channel_residual(channel, part) +
                              self.channel_measured(channel, part),
                              self.channel_measured(channel, part))
            out[f'{channel}_nrmse_pct'] = value if np.isfinite(value) else None
        return out


class DiscoveryLoop:
    """
    Residual analysis and effect discovery on a set of prepared records.

    Parameters
    ----------
    records : list of Record
        Prepared records (:func:`dcmotor_id.identify.prepare_records`).
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

    """

    def __init__(self, records, torque_constant=None, vocabulary=VOCABULARY,
                 holdout_fraction=HOLDOUT_FRACTION, min_gain=MIN_GAIN, max_effects=MAX_EFFECTS,
                 max_lag=DEFAULT_LAGS, alpha=ALPHA):
        self.records = list(records)
        self.torque_constant = torque_constant
        self.mechanical_only = torque_constant is not None
        self.outputs = ('speed',) if self.mechanical_only else ('current', 'speed')
        self.candidates = [cls for cls in vocabulary if cls.applies(self.mechanical_only)]
        self.holdout_fraction = float(holdout_fraction)
        self.min_gain = float(min_gain)
        self.max_effects = int(max_effects)
        self.max_lag = int(max_lag)
        self.alpha = float(alpha)
        self.weights = None

    # ------------------------------------------------------------------ fitting
    def _stops(self, records):
        return [max(int(round(len(rec) * (1.0 - self.holdout_fraction))), 1) for rec in records]

    def fit(self, structure, start=None, initial=None, max_nfev=100):
        """Fit a structure on the training parts and simulate the whole records."""
        records = structure.transformed(self.records)
        stops = self._stops(records)
        base = start or {}
        terms = _with_initial(structure.terms(records, base, self.torque_constant, initial),
                              initial or {})
        train = [rec.slice(0, stop) for rec, stop in zip(records, stops)]
        estimator = RefinedEstimator(max_nfev=max_nfev, initial=start or None)
        if not start and terms:
            raise ValueError('a structure with effects needs a start point')
        estimate = estimator.fit(train, torque_constant=self.torque_constant,
                                 terms=_slice_terms(terms, stops))
        model = OutputErrorModel(records, self.torque_constant, terms)
        simulated = []
        with np.errstate(all='ignore'):
            for index, state in enumerate(estimate.initial_states):
                simulated.append(model.simulate(estimate.parameters, index,
                                                np.array(state, dtype=float)))
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
        pieces = []
        for rec, stop in zip(fitted.records, fitted.stops):
            values = getattr(rec, name)
            pieces.append(values[:stop] if part == 'train' else values[stop:])
        return {name: np.concatenate(pieces)}

    def _candidate_regressors(self, fitted, part):
        regressors = {}
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
            pieces = [reg[:stop] if part == 'train' else reg[stop:]
                      for reg, stop in zip(terms[0].regressors, fitted.stops)]
            joined = np.concatenate(pieces)
            if np.std(joined) > 0:
                regressors[cls.name] = joined
        return regressors

    def analyse(self, fitted, part='heldout'):
        """Residual analysis of a fit on a part: per output channel (JSON-ready)."""
        inputs = self._inputs(fitted, part)
        regressors = self._candidate_regressors(fitted, part)
        return {channel: analyse_channel(fitted.channel_residual(channel, part),
                                         fitted.channel_measured(channel, part), inputs,
                                         regressors, self.max_lag, self.alpha)
                for channel in self.outputs}

    def _negligible(self, analysis):
        return all(item['nrmse_pct'] is not None and item['nrmse_pct'] < NEGLIGIBLE_NRMSE_PCT
                   for item in analysis.values())

    def explained(self, analysis):
        """White residual on every channel (Bonferroni over channels), or an exact model."""
        if self._negligible(analysis):
            return True
        level = self.alpha / len(analysis)
        return all(item['ljung_box']['p_value'] >= level for item in analysis.values())

    def material(self, analysis):
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
                                       _slice_terms(terms, fitted.stops))

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

        def simulate(vals):
            return [model.simulate(vals, index, np.array(states[index], dtype=float))
                    for index in range(len(train))]
        nominal = simulate(values)
        measured = [{channel: getattr(rec, channel) for channel in self.outputs}
                    for rec in train]
        residual = self._stack(measured, fitted.stops) - self._stack(nominal, fitted.stops)
        columns = []
        names = list(model.base_names) + [term.name for term in fitted.terms]
        for name in names:
            step = 1e-6 * abs(values[name]) or 1e-9
            moved = dict(values)
            moved[name] = values[name] + step
            with np.errstate(all='ignore'):
                columns.append((self._stack(simulate(moved), fitted.stops)
                                - self._stack(nominal, fitted.stops)) / step)
        # Initial-state sensitivities are left out: they decay within a few time constants.
        matrix = np.column_stack(columns) if columns else np.zeros((residual.shape[0], 0))
        matrix = matrix[:, np.all(np.isfinite(matrix), axis=0)]
        return residual, matrix, nominal

    def _term_responses(self, fitted, terms, nominal):
        """
        Sensitivities of the training outputs to a candidate's coefficients.

        Finite differences through the model from the candidate's start values, with the
        coefficient's typical magnitude as the (secant) step, so stick-slip events do not make
        the difference noisy; for a linear term this is its exact linear response.
        """
        train, model = self._train_model(fitted, fitted.terms + tuple(terms))
        start = dict(fitted.values)
        start.update({term.name: term.initial for term in terms})
        states = fitted.estimate.initial_states
        columns = []
        for term in terms:
            values = dict(start)
            values[term.name] = term.initial + term.scale
            with np.errstate(all='ignore'):
                moved = [model.simulate(values, index, np.array(states[index], dtype=float))
                         for index in range(len(train))]
            columns.append((self._stack(moved, fitted.stops)
                            - self._stack(nominal, fitted.stops)) / term.scale)
        return np.column_stack(columns)

    @staticmethod
    def _projector(matrix):
        if matrix.shape[1] == 0:
            return None
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

    def screen(self, fitted, cls, residual, q, nominal):
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
        structure = current.structure.plus(cls, inner)
        initial = dict(current.values)
        initial.update(start_terms)
        try:
            with np.errstate(all='ignore'):  # a wild candidate may overflow; it is scored
                return self.fit(structure, start=self._base(current), initial=initial,
                                max_nfev=CANDIDATE_MAX_NFEV)
        except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
            return None

    def _base(self, fitted):
        """
        Start point of a refit: the fitted base values, with b and Mc lifted off zero.

        The fit works on logarithms, so a friction that a missing effect drove to zero would
        stay there; a floor of 2 % of the driving torque's spread lets it come back.
        """
        names = ('J', 'b', 'Mc') if self.mechanical_only else \
            ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')
        start = {name: float(fitted.values[name]) for name in names}
        spread = torque_spread(self.records, start, self.torque_constant)
        speed = max(float(np.std(np.concatenate([rec.speed for rec in self.records]))), 1e-12)
        start['Mc'] = max(start['Mc'], 0.02 * spread)
        start['b'] = max(start['b'], 0.02 * spread / speed)
        return start

    def screen_candidate(self, current, cls, residual, q, nominal):
        """
        Linearised screen of one candidate: its inner parameters, start and explained share.

        Returns a dict (``cls``, ``inner``, ``start``, ``screen_explained``) or None when the
        candidate has nothing to offer (no grid point, or a delay that rounds to zero samples).
        """
        total = max(float(residual @ residual), 1e-300)
        if cls.TRANSFORM:
            best = None
            for channel in SensorDelay.channels(self.mechanical_only):
                gained, estimate = self._delay_estimate(current, channel, residual, q, nominal)
                samples = int(np.round(estimate))
                if samples != 0 and (best is None or gained / total > best['screen_explained']):
                    best = {'cls': cls, 'inner': {'channel': channel, 'samples': samples},
                            'start': {}, 'screen_explained': gained / total}
            return best
        found = self.screen(current, cls, residual, q, nominal)
        if found is None:
            return None
        gained, inner, start_terms = found
        return {'cls': cls, 'inner': inner, 'start': start_terms,
                'screen_explained': gained / total}

    def refit_candidate(self, current, item):
        """Refit all parameters with the candidate added; fill ``fit`` and ``problem``."""
        if item['cls'].TRANSFORM:
            fitted = self._refit_delay(current, item['inner']['channel'],
                                       item['inner']['samples'])
        else:
            fitted = self._try(current, item['cls'], item['inner'], item['start'])
        if fitted is not None and np.isfinite(fitted.heldout_cost):
            item['fit'] = fitted
            item['inner'] = fitted.structure.items[-1][1]
            item['problem'] = self._problem(current, fitted)

    def _problem(self, current, fitted):
        """Why a candidate's fit is not acceptable (physics, collapse), or None."""
        effect = fitted.structure.effects(fitted.values)[-1]
        reason = effect.problem(fitted.values, fitted.records)
        if reason:
            return reason
        for name in ('b', 'Mc'):
            before, after = current.values[name], fitted.values[name]
            if before > 0 and after < 0.01 * before:
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
    def run(self):
        """Run the loop; return a :class:`DiscoveryResult`."""
        base = self.fit(Structure())
        current = base
        steps = []
        analysis_before = self.analyse(base)
        analysis = analysis_before
        reason = 'explained'
        while True:
            if self.explained(analysis):
                reason = 'the residual is white' if not self._negligible(analysis) else \
                    'the model reproduces the data exactly'
                break
            if len(current.structure) >= self.max_effects:
                reason = f'stopped at {self.max_effects} effects'
                break
            step = self._step(current, analysis)
            steps.append(step['report'])
            if step['chosen'] is None:
                reason = 'no candidate lowers the held-out error enough'
                break
            current = step['chosen']
            analysis = self.analyse(current)
        return DiscoveryResult(self, base, current, steps, analysis_before, analysis, reason)

    def _step(self, current, analysis):
        residual, matrix, nominal = self._base_sensitivities(current)
        q = self._projector(matrix)
        present = set(current.structure.names())
        screened = []
        for cls in self.candidates:
            if cls.name in present:
                continue
            item = self.screen_candidate(current, cls, residual, q, nominal)
            if item is not None:
                item['fit'] = None
                screened.append(item)
        # Refit the candidates the linearised screen supports, and the best few anyway (the
        # screen is a linearisation: a strongly nonlinear effect may look smaller than it is).
        screened.sort(key=lambda item: -item['screen_explained'])
        for rank, item in enumerate(screened):
            if rank < SCREEN_TOP or item['screen_explained'] >= SCREEN_SHARE * self.min_gain:
                self.refit_candidate(current, item)
        results = []
        for item in screened:
            if item['fit'] is not None:
                item['gain'] = 1.0 - item['fit'].heldout_cost / current.heldout_cost
                item['bic_delta'] = self._bic(item['fit']) - self._bic(current)
            else:
                item['gain'], item['bic_delta'] = None, None
            results.append(item)
        order = {cls.name: position for position, cls in enumerate(self.candidates)}
        refitted = sorted((item for item in results if item['fit'] is not None),
                          key=lambda item: item['fit'].heldout_cost)
        screened_out = sorted((item for item in results if item['fit'] is None),
                              key=lambda item: -item['screen_explained'])
        results = refitted + screened_out
        chosen = None
        equivalent = []
        admissible = [item for item in refitted if not item.get('problem')]
        drop = current.heldout_cost - admissible[0]['fit'].heldout_cost if admissible else 0.0
        if drop > 0:
            ties = [item for item in admissible
                    if current.heldout_cost - item['fit'].heldout_cost >= TIE_SHARE * drop]
            winner = min(ties, key=lambda item: order[item['cls'].name])
            if winner['gain'] >= self.min_gain and winner['bic_delta'] < 0:
                chosen = winner
                equivalent = [item for item in ties if item is not winner]
        report = {
            'error_before': current.errors(self.outputs),
            'candidates': [self._candidate_report(item, analysis) for item in results],
            'added': None,
        }
        if chosen is not None:
            fitted = chosen['fit']
            effect = fitted.structure.effects(fitted.values)[-1]
            report['added'] = effect.describe(fitted.values)
            report['error_after'] = fitted.errors(self.outputs)
            report['gain_pct'] = chosen['gain'] * 100.0
            report['equivalent'] = [
                item['fit'].structure.effects(item['fit'].values)[-1].describe(
                    item['fit'].values) for item in equivalent]
        return {'chosen': chosen['fit'] if chosen else None, 'report': report}

    def _candidate_report(self, item, analysis):
        correlation = max((channel['regressors'].get(item['cls'].name, {}).get('max_abs', 0.0)
                           for channel in analysis.values()), default=0.0)
        return {
            'name': item['cls'].name,
            'inner': dict(item['inner']),
            'refitted': item['fit'] is not None,
            'rejected': item.get('problem'),
            'heldout_gain_pct': None if item['gain'] is None else item['gain'] * 100.0,
            'bic_delta': item['bic_delta'],
            'screen_explained_pct': item['screen_explained'] * 100.0,
            'regressor_correlation': correlation,
        }

    def refit_all(self, fitted):
        """Refit a structure on all the data (no hold-out), from the training values."""
        records = fitted.structure.transformed(self.records)
        terms = _with_initial(fitted.structure.terms(records, fitted.values,
                                                     self.torque_constant), fitted.values)
        estimator = RefinedEstimator(initial=self._base(fitted))
        return records, terms, estimator.fit(records, torque_constant=self.torque_constant,
                                             terms=terms)


class DiscoveryResult:
    """
    What the loop found, with everything the report plots.

    Attributes
    ----------
    loop : DiscoveryLoop
        The loop (records, settings).
    base, final : Fit
        Base and final structure fitted on the training parts.
    steps : list of dict
        One report per search round (candidates scored, effect added, errors).
    analysis_before, analysis_after : dict
        Held-out residual analyses of the base and the final model.
    reason : str
        Why the loop stopped.
    records, terms, estimate :
        The final structure refitted on all the data.

    """

    def __init__(self, loop, base, final, steps, analysis_before, analysis_after, reason):
        self.loop = loop
        self.base = base
        self.final = final
        self.steps = steps
        self.analysis_before = analysis_before
        self.analysis_after = analysis_after
        self.reason = reason
        self.unexplained = loop.material(analysis_after)
        self.records, self.terms, self.estimate = loop.refit_all(final)
        self.effects = final.structure.effects(self.estimate.parameters)
        if len(final.structure):
            self.base_estimate = loop.refit_all(base)[2]
        else:
            self.base_estimate = self.estimate

    def errors_on(self, records):
        """
        Simulate the all-data base and final models on other records; return their errors.

        Each record is simulated from its first measured sample (speed, and current in the
        full mode) with the measured input; data effects (delays) are applied first.

        Returns
        -------
        dict
            ``before`` and ``after``, each ``{current_nrmse_pct, speed_nrmse_pct}``.

        """
        tc = self.loop.torque_constant
        return {'before': structure_errors(Structure(), self.base_estimate, records, tc),
                'after': structure_errors(self.final.structure, self.estimate, records, tc)}

    def errors_by_step(self, records):
        """
        Errors on other records after each effect added (all-data refits), in order.

        Returns
        -------
        list of dict
            ``{'effects': [names], current_nrmse_pct, speed_nrmse_pct}``, the base model
            first.

        """
        items = self.final.structure.items
        out = []
        for count in range(len(items) + 1):
            structure = Structure(items[:count])
            if count == 0:
                estimate = self.base_estimate
            elif count == len(items):
                estimate = self.estimate
            else:
                prepared = structure.transformed(self.loop.records)
                values = self.estimate.parameters
                terms = _with_initial(structure.terms(prepared, values,
                                                      self.loop.torque_constant), values)
                estimate = RefinedEstimator(initial=self.loop._base(self.final)).fit(
                    prepared, torque_constant=self.loop.torque_constant, terms=terms)
            errors = structure_errors(structure, estimate, records, self.loop.torque_constant)
            out.append({'effects': structure.names(), **errors})
        return out

    @property
    def error_before(self):
        """Held-out simulation error of the base model."""
        return self.base.errors(self.loop.outputs)

    @property
    def error_after(self):
        """Held-out simulation error of the final model."""
        return self.final.errors(self.loop.outputs)

    def effects_json(self):
        """``[{"name", "parameters"}]`` in the order added, with the all-data values."""
        return [effect.describe(self.estimate.parameters) for effect in self.effects]

    def evidence(self):
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

    def summary(self):
        """JSON-ready account of the loop."""
        return {
            'holdout_fraction': self.loop.holdout_fraction,
            'min_gain_pct': self.loop.min_gain * 100.0,
            'reason': self.reason,
            'base_heldout_parameters': {key: float(value) for key, value in
                                        self.base.values.items()},
            'steps': self.steps,
            'evidence_before': _evidence(self.analysis_before),
            'evidence_after': self.evidence(),
        }


def structure_errors(structure, estimate, records, torque_constant=None):
    """
    Simulate a fitted structure on records, each from its first sample; return the errors.

    Returns
    -------
    dict
        ``{current_nrmse_pct, speed_nrmse_pct}`` (current None in mechanical-only mode).

    """
    outputs = ('speed',) if torque_constant is not None else ('current', 'speed')
    prepared = structure.transformed(records)
    values = estimate.parameters
    terms = structure.terms(prepared, values, torque_constant, values)
    model = OutputErrorModel(prepared, torque_constant, terms)
    sims = {channel: [] for channel in outputs}
    with np.errstate(all='ignore'):
        for index, rec in enumerate(prepared):
            state = np.array([float(getattr(rec, channel)[0]) for channel in outputs])
            simulated = model.simulate(values, index, state)
            for channel in outputs:
                sims[channel].append(simulated[channel])
    errors = {'current_nrmse_pct': None, 'speed_nrmse_pct': None}
    for channel in outputs:
        measured = np.concatenate([getattr(rec, channel) for rec in prepared])
        value = nrmse_pct(np.concatenate(sims[channel]), measured)
        errors[f'{channel}_nrmse_pct'] = value if np.isfinite(value) else None
    return errors


def _evidence(analysis):
    return {channel: {'ljung_box_p_value': item['ljung_box']['p_value'],
                      'predictable_fraction': item['predictable_fraction'],
                      'nrmse_pct': item['nrmse_pct']}
            for channel, item in analysis.items()}


def discover(records, torque_constant=None, **options):
    """Run the discovery loop on prepared records; return a :class:`DiscoveryResult`."""
    return DiscoveryLoop(records, torque_constant, **options).run()
