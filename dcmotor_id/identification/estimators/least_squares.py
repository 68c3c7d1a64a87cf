"""
The weighted least-squares problem of an output-error fit, and its solver.

:class:`FitProblem` holds one fit of the output-error model
(:class:`~dcmotor_id.identification.estimators.refined.OutputErrorModel`) in the optimiser's
coordinates (log parameters, scaled initial states): its residual weighted by the channels'
noise levels, the analytic (compiled) or numeric sensitivities, the estimate at the optimum.
:func:`levenberg_marquardt` minimises it; :data:`MISFIT` is what a fit that fails says.  The
refined estimator (:mod:`~dcmotor_id.identification.estimators.refined`) runs the passes.
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import derived_stderr, derived_values
from dcmotor_id.identification.error_model.criterion import whiten
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.estimators.jacobian import record_sparse_jacobian
from dcmotor_id.identification.estimators.normal_equations import NormalEquations
from dcmotor_id.identification.estimators.uncertainty import block_scores, JACKKNIFE_MAX_RECORDS


MISFIT = ('the motor model does not reproduce the data. Check that the columns are what their '
          'names say (units, signs: current and speed positive for a positive voltage), and '
          'that the input changes between at least two levels (a single constant input '
          'cannot separate all parameters: record a step between two non-zero levels)')


def diverged(error: BaseException) -> str:
    """Describe a failure of the simulation during the fit (its message may be empty)."""
    text = str(error)
    if text:
        return text
    return (f'{type(error).__name__} in the simulation: a parameter ran to zero or infinity '
            'on the way')


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


class FitProblem:
    """
    One output-error fit: the model, the coordinates ``z`` it is solved in, and their passes.

    Base parameters are fitted as logarithms (positive, relative steps); term coefficients
    and the free initial states as multiples of their typical magnitude (``scales``).  Pinned
    initial states (``initial_state='measured'``) stay at the records' first samples.

    Parameters
    ----------
    model : OutputErrorModel
        The model and its records
        (:class:`~dcmotor_id.identification.estimators.refined.OutputErrorModel`).
    start_base : dict
        Start of the base parameters (the refined estimator's start search).
    initial_state : str
        ``estimate`` or ``measured`` (:func:`free_states`).
    warm_states : sequence, optional
        Start of every record's initial state (used when there is one per record).
    progress : callable, optional
        Called with ``cost=`` at every evaluation.
    analytic : bool
        The compiled kernel gives the model's sensitivities (else numeric ones).

    """

    def __init__(self, model: Any, start_base: Mapping[str, float],
                 initial_state: str, warm_states: Sequence[Sequence[float]] | None,
                 progress: Callable[..., None] | None, analytic: bool) -> None:
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
        self.analytic = analytic
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
        except (ZeroDivisionError, OverflowError, FloatingPointError, ValueError):
            # A parameter ran to zero or infinity on the way (the simulation kernels raise
            # on a division by zero): an infinite cost, which the search rejects as a step
            # (as scipy's trust-region solvers do with a non-finite trial) and
            # :func:`levenberg_marquardt` refuses at the start.
            return _Pass(np.inf)

    def estimate(self, method: str, z: np.ndarray, final: Any,
                 noise: list[dict[str, float]], nfev: int) -> Estimate:
        """Return the :class:`Estimate` at the optimum ``z`` (``final``: its pass)."""
        model, names, n_base = self.model, self.names, self.n_base
        values, states, theta = self.unpack(z)
        n_residuals = sum(len(rec) for rec in self.records) * len(model.outputs)
        dof = max(n_residuals - z.shape[0], 1)
        s2 = float(final.cost) / dof
        try:
            if not np.all(np.isfinite(final.hessian)):
                raise np.linalg.LinAlgError('non-finite sensitivities')
            cov_z = s2 * np.linalg.pinv(final.hessian)
        except np.linalg.LinAlgError as error:  # LAPACK's SVD on overflowed sensitivities
            raise FitError(f'the output-error fit diverged ({error} at its optimum): '
                           + MISFIT) from None
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
        """Return the estimate's ``info`` (of the refined estimator)."""
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


def nonnegative_lstsq(matrix: np.ndarray, rhs: np.ndarray,
                      signed: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """
    Least squares with the ``signed`` coefficients at least zero (physical admissibility).

    Returns ``(solution, held)``: the unconstrained solution where it is admissible (``held``
    all False), else scipy's bounded ``lsq_linear`` on unit-norm columns with ``held`` marking
    the coefficients it holds at zero.  An equation-error regression of a single step (one
    speed level, a spin-up the filtered derivative smears) can put J or b below zero, which
    taking magnitudes would turn into a start far from the data.
    """
    solution = np.linalg.lstsq(matrix, rhs, rcond=None)[0]
    sign_bound = np.asarray(signed, dtype=bool)
    if np.all(solution[sign_bound] >= 0.0):
        return solution, np.zeros(solution.shape[0], dtype=bool)
    from scipy.optimize import lsq_linear  # lazily: most records never need the bounds
    norms = np.sqrt(np.einsum('ij,ij->j', matrix, matrix))
    norms = np.where(norms > 0.0, norms, 1.0)
    lower = np.where(sign_bound, 0.0, -np.inf)
    bounded = lsq_linear(matrix / norms, rhs, bounds=(lower, np.inf))
    return bounded.x / norms, bounded.active_mask != 0


def levenberg_marquardt(evaluate, z, max_evaluations, xtol=1e-8, ftol=1e-8, gtol=1e-8,
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
    column of the Jacobian below ``gtol``.  Every trial is simulated without sensitivities
    (a tenth of the cost: the same states and cost) and only an accepted one with them
    (:func:`_accept`).

    Returns ``(z, pass, evaluations, converged, damping)``; ``current`` (the pass at ``z``)
    and ``damping`` continue an earlier run (a reweighted pass starts from its optimum).
    ``max_evaluations`` bounds the evaluations counted as :func:`_accept` says.
    """
    nfev = 0
    if current is None:
        current = evaluate(z, True)
        nfev += 1
    if not np.isfinite(current.cost):
        raise FitError('the output-error fit diverged (non-finite residuals at the start): '
                       + MISFIT)
    scale = np.maximum(np.diag(current.hessian), 0.0)
    mu = 1e-3 if damping is None else damping
    after_rejection = False
    while nfev < max(int(max_evaluations), 2):
        cost = current.cost
        scale = np.maximum(scale, np.diag(current.hessian))
        if _stationary(current, gtol):
            return z, current, nfev, True, mu
        step, predicted, small = _damped_step(current, z, mu, scale, xtol)
        trial = evaluate(z + step, False)
        nfev += 1
        actual = cost - trial.cost if np.isfinite(trial.cost) else -np.inf
        ratio = actual / predicted if predicted > 0.0 else -1.0
        accepted = None
        if ratio > 1e-4:
            accepted, counted = _accept(evaluate, z + step, after_rejection)
            nfev += counted
        if accepted is not None:
            z, current, after_rejection = z + step, accepted, False
            mu *= max(1.0 / 3.0, 1.0 - (2.0 * ratio - 1.0) ** 3)
            if (abs(actual) <= ftol * cost and predicted <= ftol * cost) or small:
                return z, current, nfev, True, mu
        else:
            after_rejection = True
            mu *= 10.0
            if small or mu > 1e16:
                return z, current, nfev, True, mu
    return z, current, nfev, False, mu


def _accept(evaluate, point, after_rejection):
    """
    Return the pass with sensitivities at an accepted trial ``point`` (or None) and its count.

    The count keeps the evaluation budget of the search that simulated a trial with its
    sensitivities unless the step before it was rejected: the sensitivities of a point
    reached after a rejected step count one evaluation, those of any other accepted point
    none (its trial counted).  So a budget stops a search at the same step as before the
    trials were simulated without sensitivities.  The sensitivities can fail where the
    states alone did not (a division by zero on an event): then, unless a rejected step came
    before, the step is rejected, as it was when its trial carried them; after one, the
    non-finite pass is returned as it was.
    """
    accepted = evaluate(point, True)
    if after_rejection:
        return accepted, 1
    return (accepted if np.isfinite(accepted.cost) else None), 0


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
