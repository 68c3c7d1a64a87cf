"""
The weighted normal equations of the output-error fit, accumulated without the Jacobian.

:class:`NormalEquations` turns an
:class:`~dcmotor_id.identification.estimators.refined.OutputErrorModel`
and a parameter point into the arrays of :func:`~dcmotor_id.simulation.sensitivity.normal_kernel`
(analytic sensitivities, exact through events) and returns, per record, ``J^T J``, ``J^T r``,
the cost, the residual sums of squares and the block score sums in the *physical* coordinates
``theta`` (the parameters, then the record's initial state).  Memory beyond the inputs: the
forcing array (``n`` floats a sample) and the stacked regressors of linear terms.

Model variants the kernel does not cover (effects simulated on sub-steps: Stribeck, drag,
brush drop, ...; a quasi-static armature; any subclass that simulates differently) are
refused by :meth:`NormalEquations.supports`; the estimator then differentiates the simulation
numerically.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast, Mapping, Sequence

import numpy as np

from dcmotor_id.identification.estimators.base import StateTerm
from dcmotor_id.identification.estimators.uncertainty import block_edges
from dcmotor_id.simulation.compiled import kernel

_NO_REGS = np.zeros((0, 1))
_NO_INDEX = np.zeros(0, dtype=np.int64)
_NO_VALUES = np.zeros(0)
_NO_TRAJECTORY = np.zeros((1, 1, 1))


@dataclass
class RecordSums:
    """
    What one pass over one record accumulates (``theta`` coordinates, weighted rows).

    Attributes
    ----------
    by_channel : tuple of numpy.ndarray
        ``J_c^T J_c`` (n x m x m), ``J_c^T r_c`` (n x m) and the block score sums
        (n_blocks x n x m) of every output channel ``c`` (a new weighting rescales them).
    cost : float
        ``sum r^2`` (residuals divided by the channel's noise level).
    sums : numpy.ndarray
        Unweighted ``sum e^2`` per output channel.
    block_edges : numpy.ndarray
        Sample edges of the blocks
    (:func:`dcmotor_id.identification.estimators.uncertainty.block_edges`).
    trajectory : numpy.ndarray or None
        ``[k, channel, 0]`` the simulated state, ``[k, channel, 1 + j]`` its sensitivities
        (when asked for).

    """

    by_channel: tuple
    cost: float
    sums: np.ndarray
    block_edges: np.ndarray
    trajectory: np.ndarray | None = None

    @property
    def hessian(self) -> np.ndarray:
        """``J^T J`` over the record's columns (shared parameters, then its initial state)."""
        return self.by_channel[0].sum(axis=0)

    @property
    def gradient(self) -> np.ndarray:
        """``J^T r``."""
        return self.by_channel[1].sum(axis=0)

    @property
    def blocks(self) -> np.ndarray:
        """``J^T r`` over consecutive blocks of samples (``block_edges``; n_blocks x m)."""
        return self.by_channel[2].sum(axis=1)


class NormalEquations:
    """
    Accumulate the output-error normal equations of a model with analytic sensitivities.

    Parameters
    ----------
    model : OutputErrorModel
        The model; :meth:`supports` must hold.

    """

    def __init__(self, model: Any) -> None:
        self.model = model
        self.names = list(model.base_names) + [term.name for term in model.terms]
        self.n_shared = len(self.names)
        self._column = {name: position for position, name in enumerate(self.names)}
        # Columns of a record's initial state: the ODE's, then the initial position when the
        # position is compared (its sensitivities follow the kernel's, :meth:`_with_position`).
        self.n_state = len(getattr(model, 'states', model.outputs))
        #: Which initial states the fit estimates (set by the fit; None: all of them).
        self.free_states: list[bool] | None = None
        self._regressors = [self._stack_regressors(index) for index in range(len(model.records))]
        self._edges: dict[int, np.ndarray] = {}  # block edges by record length (read only)

    @staticmethod
    def supports(model: Any) -> bool:
        """
        Whether the analytic kernel reproduces the model's terms (else finite differences).

        The caller checks that ``model.simulate`` is the plain output-error simulation (a
        subclass that simulates otherwise has no analytic sensitivities here).
        """
        if getattr(model, 'quasi_static', False):
            return False
        for term in model.terms:
            if isinstance(term, StateTerm):
                if term.field != 'coulomb_delta_Nm' or term.fixed:
                    return False
            elif term.channel not in ('voltage', 'torque', 'current', 'speed') or (
                    model.mechanical_only and term.channel == 'voltage'):
                return False
        return True

    def _stack_regressors(self, index):
        """Return the regressors of the linear terms of record ``index`` (forcing, outputs)."""
        model = self.model
        forcing, outputs = [], []
        for position, term in enumerate(model.terms):
            if isinstance(term, StateTerm):
                continue
            column = len(model.base_names) + position
            target = forcing if term.channel in ('voltage', 'torque') else outputs
            target.append((term, column, np.asarray(term.regressors[index], dtype=float)))
        stack = (lambda items: np.ascontiguousarray(np.vstack([item[2] for item in items]))
                 if items else _NO_REGS)
        return forcing, stack(forcing), outputs, stack(outputs)

    def record(self, values: Mapping[str, float], index: int, initial_state: Sequence[float],
               inverse_sigma: Sequence[float], with_sens: bool = True,
               store: bool = False) -> RecordSums:
        """
        Run the kernel over record ``index``; return its :class:`RecordSums`.

        ``inverse_sigma`` weights the model's compared channels (``model.outputs``, in order);
        ``initial_state`` is the record's (``model.states``).
        """
        if 'position' in self.model.outputs:
            return self._with_position(values, index, initial_state, inverse_sigma, with_sens,
                                       store)
        return self._dynamic(values, index, initial_state, inverse_sigma, with_sens, store)

    def _with_position(self, values, index, initial_state, inverse_sigma, with_sens, store):
        """
        Accumulate the normal equations with the position: the kernel's, then the position's.

        The position is the trapezoidal integral of the simulated speed from the initial
        position (:func:`dcmotor_id.identification.error_model.criterion.integrate_speed`), so its
        sensitivities are the
        running integral of the speed's, which the kernel stores (the trajectory), and 1 for
        the initial position; :func:`~dcmotor_id.simulation.sensitivity.position_kernel`
        accumulates them in one pass.  A channel not compared (the speed derived from the
        position) enters the kernel with weight 0.
        """
        model = self.model
        dynamic, outputs = model.dynamic, model.outputs
        weight = dict(zip(outputs, (float(value) for value in inverse_sigma)))
        n_dynamic = len(dynamic)
        kernel_sums = self._dynamic(values, index, initial_state[:n_dynamic],
                                    [weight.get(channel, 0.0) for channel in dynamic],
                                    with_sens, True)
        trajectory = cast(np.ndarray, kernel_sums.trajectory)
        m = self.n_shared + n_dynamic
        # The position error's AR(1) model (0: white) whitens the error and its sensitivities.
        rho = float(getattr(model, 'position_ar', (0.0,) * (index + 1))[index])
        edges = kernel_sums.block_edges
        position_h, position_g, position_b, position_sum, position_cost = kernel(
            'position_kernel')(trajectory, float(model.sample_periods_s[index]),
                               float(initial_state[n_dynamic]),
                               np.ascontiguousarray(model.records[index].position, dtype=float),
                               rho, float(weight['position']), bool(with_sens), edges)
        kernel_h, kernel_g, kernel_b = kernel_sums.by_channel
        hessian = np.zeros((len(outputs), m + 1, m + 1))
        gradient = np.zeros((len(outputs), m + 1))
        blocks = np.zeros((edges.shape[0] - 1, len(outputs), m + 1))
        sums = np.zeros(len(outputs))
        for out, channel in enumerate(outputs):
            if channel == 'position':
                sums[out] = position_sum
                hessian[out], gradient[out], blocks[:, out] = position_h, position_g, position_b
                continue
            state = dynamic.index(channel)
            sums[out] = kernel_sums.sums[state]
            hessian[out, :m, :m] = kernel_h[state]
            gradient[out, :m] = kernel_g[state]
            blocks[:, out, :m] = kernel_b[:, state]
        return RecordSums((hessian, gradient, blocks), kernel_sums.cost + position_cost, sums,
                          edges, trajectory if store else None)

    def _dynamic(self, values, index, initial_state, inverse_sigma, with_sens, store):
        """Run the kernel (the ODE's states, weighted by ``inverse_sigma``)."""
        model = self.model
        rec = model.records[index]
        dynamic = getattr(model, 'dynamic', model.outputs)
        n = len(dynamic)
        m = self.n_shared + n
        a, da, forcing, gscale = self._system(values, index, n, m)
        s_start = np.zeros((n, m))
        for c in range(n):
            s_start[c, self.n_shared + c] = 1.0
        measured = [np.ascontiguousarray(getattr(rec, channel), dtype=float)
                    for channel in dynamic]
        edges = self._edges.get(len(rec))
        if edges is None:
            edges = self._edges[len(rec)] = block_edges(len(rec))
        trajectory = np.empty((len(rec), n, m + 1)) if store else _NO_TRAJECTORY
        hessian, gradient, cost, sums, blocks = kernel('normal_kernel')(
            np.ascontiguousarray(a), da, forcing, gscale, *self._linear_terms(values, index, n),
            *self._friction(values, m), np.asarray(initial_state, dtype=float), s_start,
            float(model.sample_periods_s[index]), measured[0], measured[-1],
            np.asarray(inverse_sigma, dtype=float), bool(with_sens), edges, trajectory,
            bool(store))
        return RecordSums((hessian, gradient, blocks), float(cost), sums, edges,
                          trajectory if store else None)

    def _system(self, values, index, n, m):
        """
        Return the ODE of record ``index``: ``A``, ``dA / d theta``, forcing, its derivatives.

        ``gscale[j, c]`` is the derivative of the forcing of state ``c`` with respect to
        parameter ``j`` divided by that forcing (a signal divided by La or J).
        """
        model, columns = self.model, self._column
        da = np.zeros((m, n, n))
        gscale = np.zeros((m, n))
        inertia, viscous = values['J'], values['b']
        torque = model._channel(values, 'torque', index)
        if model.mechanical_only:
            a = np.array([[-viscous / inertia]])
            da[columns['b'], 0, 0] = -1.0 / inertia
            da[columns['J'], 0, 0] = viscous / inertia ** 2
            drive = model.torque_constant * model.held_currents[index]
            if torque is not None:
                drive = drive + torque
            forcing = np.ascontiguousarray((drive / inertia)[:, None])
            gscale[columns['J'], 0] = -1.0 / inertia
            return a, da, forcing, gscale
        ra, la, cphi = values['Ra'], values['La'], values['CPhi']
        a = np.array([[-ra / la, -cphi / la], [cphi / inertia, -viscous / inertia]])
        da[columns['Ra'], 0, 0] = -1.0 / la
        da[columns['La'], 0, 0] = ra / la ** 2
        da[columns['La'], 0, 1] = cphi / la ** 2
        da[columns['CPhi'], 0, 1] = -1.0 / la
        da[columns['CPhi'], 1, 0] = 1.0 / inertia
        da[columns['J'], 1, 0] = -cphi / inertia ** 2
        da[columns['J'], 1, 1] = viscous / inertia ** 2
        da[columns['b'], 1, 1] = -1.0 / inertia
        forcing = np.empty((len(model.records[index]), 2))
        voltage = model._channel(values, 'voltage', index)
        np.divide(model.records[index].voltage, la, out=forcing[:, 0])
        if voltage is not None:
            forcing[:, 0] += voltage / la
        if torque is not None:
            np.divide(torque, inertia, out=forcing[:, 1])
        else:
            forcing[:, 1] = 0.0
        gscale[columns['La'], 0] = -1.0 / la
        gscale[columns['J'], 1] = -1.0 / inertia
        return a, da, forcing, gscale

    def _linear_terms(self, values, index, n):
        """Return the kernel's arrays of the linear terms of record ``index`` (in its order)."""
        model = self.model
        forcing_terms, regs, output_terms, oregs = self._regressors[index]
        inertia = values['J']
        reg_col = np.array([column for _, column, _ in forcing_terms], dtype=np.int64)
        reg_row = np.array([0 if term.channel == 'voltage' else n - 1
                            for term, _, _ in forcing_terms], dtype=np.int64)
        reg_factor = np.array([1.0 / values['La'] if term.channel == 'voltage' else 1.0 / inertia
                               for term, _, _ in forcing_terms], dtype=float)
        oreg_col = np.array([column for _, column, _ in output_terms], dtype=np.int64)
        states = getattr(model, 'dynamic', model.outputs)
        oreg_chan = np.array([states.index(term.channel) for term, _, _ in output_terms],
                             dtype=np.int64)
        oreg_value = np.array([values[term.name] for term, _, _ in output_terms], dtype=float)
        return regs, reg_col, reg_row, reg_factor, oregs, oreg_col, oreg_chan, oreg_value

    def _friction(self, values, m):
        """
        Return the Coulomb friction levels over J (positive, negative speed) and derivatives.

        The levels are ``Mc +- delta`` (delta: the state terms' asymmetry), clipped at zero.
        """
        model, columns = self.model, self._column
        inertia, coulomb = values['J'], values['Mc']
        delta = sum(values[term.name] for term in model.terms if isinstance(term, StateTerm))
        raw_pos, raw_neg = coulomb + delta, coulomb - delta
        friction_pos = max(raw_pos, 0.0) / inertia
        friction_neg = max(raw_neg, 0.0) / inertia
        dfric_pos = np.zeros(m)
        dfric_neg = np.zeros(m)
        dfric_pos[columns['J']] = -friction_pos / inertia
        dfric_neg[columns['J']] = -friction_neg / inertia
        if raw_pos > 0.0:
            dfric_pos[columns['Mc']] = 1.0 / inertia
        if raw_neg > 0.0:
            dfric_neg[columns['Mc']] = 1.0 / inertia
        for position, term in enumerate(model.terms):
            if isinstance(term, StateTerm):
                column = len(model.base_names) + position
                dfric_pos[column] = 1.0 / inertia if raw_pos > 0.0 else 0.0
                dfric_neg[column] = -1.0 / inertia if raw_neg > 0.0 else 0.0
        return friction_pos, friction_neg, dfric_pos, dfric_neg

    def columns(self, index: int) -> list[int]:
        """Return the global columns of record ``index``: the shared ones, then its state's."""
        start = self.n_shared + index * self.n_state
        return list(range(self.n_shared)) + list(range(start, start + self.n_state))
