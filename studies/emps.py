"""
The EMPS measured data: loading, the published IDIM-LS cross-check, the discovery study.

EMPS (Electro-Mechanical Positioning System) is a real DC-motor drive turning a ball screw
that moves a carriage, published with reference models by A. Janot, M. Gautier and
M. Brunot, "Data Set and Reference Models of EMPS", Nonlinear System Identification
Benchmarks workshop, Eindhoven, 2019 (records: ``python bench/fetch_emps.py DIR``).  The drive is
current-controlled and the motor force is ``gtau * vir``, so only the mechanical part is
identifiable: this module maps it onto the mechanical-only mode of the package (``current``
= ``vir``, torque constant ``gtau``, position ``qm``, speed from the differentiating filter)
with M, Fv, Fc of the benchmark in the roles of J, b, Mc (units N, m, kg for the linear axis).

A study of one data set, kept beside the package rather than in it: run
``python -m studies.emps [DATA_DIR] [--report DIR]`` from the repository root (or
``python studies/emps.py ...``) for the study the README reports.  The data are looked for in
``DATA_DIR``, then ``$EMPS_DATA_DIR``, then ``../shared/data/emps`` beside the repository.
"""

from __future__ import annotations

from dataclasses import dataclass
import os
import sys
from typing import Any, Mapping, Sequence

import numpy as np
from scipy import signal
from scipy.io import loadmat

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import Record
from dcmotor_id.identification.effects import EXTENDED_VOCABULARY, LoadTorque, VOCABULARY
from dcmotor_id.identification.estimators.refined import RefinedEstimator
from dcmotor_id.signals.filters import central_differences, speed_from_position
from dcmotor_id.simulation import MotorEffects, simulate_mechanical_effects

#: Files of the benchmark.
ESTIMATION_FILE = 'DATA_EMPS.mat'
VALIDATION_FILE = 'DATA_EMPS_PULSES.mat'
#: Published IDIM-LS estimates on the estimation record (the data README).
PUBLISHED_IDIM_LS = {'M': 95.1089, 'Fv': 203.5034, 'Fc': 20.3935, 'offset': -3.1648}
#: Published relative error of the IDIM-LS force fit [%].
PUBLISHED_RELATIVE_ERROR_PCT = 4.08
#: Processing of the reference: 4th-order Butterworth at 100 Hz, forward and backward.
FILTER_ORDER = 4
FILTER_CUTOFF_HZ = 100.0
#: Decimation of the reference: round(0.8 * Nyquist / (2 * 20 Hz)) = 10 at 1 kHz.
DECIMATION = 10
#: Samples dropped at the start for the differentiation's edge effect (the reference's 50).
BORDER_SAMPLES = 49
#: The repository's root (this file is ``studies/emps.py``).
REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: Where the data sit relative to the repository: ``../shared/data/emps`` beside it.
DEFAULT_DATA_DIR = os.path.join(REPO_ROOT, '..', 'shared', 'data', 'emps')


def find_data_dir(data_dir: str | None = None) -> str:
    """Return the EMPS data directory (argument, ``EMPS_DATA_DIR``, or beside the repository)."""
    candidates = [data_dir, os.environ.get('EMPS_DATA_DIR'), DEFAULT_DATA_DIR]
    for candidate in candidates:
        if candidate and os.path.isfile(os.path.join(candidate, ESTIMATION_FILE)):
            return os.path.abspath(candidate)
    raise InputDataError(f'EMPS data not found: put {ESTIMATION_FILE} and {VALIDATION_FILE} '
                         'in a directory and pass it (or set EMPS_DATA_DIR)')


def load_emps(path: str) -> tuple[Record, float]:
    """
    Load one EMPS ``.mat`` file as a record for the mechanical-only mode.

    Parameters
    ----------
    path : str
        ``DATA_EMPS.mat`` or ``DATA_EMPS_PULSES.mat``.

    Returns
    -------
    record : Record
        ``time_s`` = t [s], ``current`` = vir (the drive command [V], the force is
        ``gtau * vir``), ``position`` = qm [m], ``speed`` derived from qm with the reference's
        zero-phase 4th-order 100 Hz Butterworth and central differences [m/s].
    gtau : float
        Drive gain [N/V], the torque (force) constant of the mechanical-only mode.

    """
    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file')
    data = loadmat(path)
    missing = [name for name in ('t', 'qm', 'vir', 'gtau') if name not in data]
    if missing:
        raise InputDataError(f'{path}: not an EMPS file (missing {", ".join(missing)})')
    time_s = np.ravel(data['t']).astype(float)
    position = np.ravel(data['qm']).astype(float)
    record = Record(time_s=time_s, current=np.ravel(data['vir']).astype(float),
                    position=position, source=os.path.basename(path))
    speed = speed_from_position(position, record.sample_period_s, FILTER_CUTOFF_HZ,
                                FILTER_ORDER)
    return record.replace(speed=speed), float(np.ravel(data['gtau'])[0])


def _decimate(values, factor):
    """
    Decimate as MATLAB's ``decimate`` does.

    Order-8 Chebyshev I low-pass at 0.8 of the new Nyquist frequency, zero phase; the samples
    are taken so that the last one is kept.
    """
    b, a = signal.cheby1(8, 0.05, 0.8 / factor)
    filtered = signal.filtfilt(b, a, values)
    n = values.shape[0]
    first = factor - (factor * int(np.ceil(n / factor)) - n) - 1
    return filtered[first::factor]


def idim_ls(record: Record, gtau: float, decimation: int = DECIMATION) -> dict[str, Any]:
    """
    Estimate by the benchmark's IDIM-LS: ``gtau vir = M qdd + Fv qd + Fc sgn(qd) + offset``.

    The processing documented with the data: 4th-order Butterworth at 100 Hz forward and
    backward on the position, central differences for speed and acceleration, the first 49
    samples dropped, every column decimated by 10 (Chebyshev anti-alias, zero phase), ordinary
    least squares.

    Returns
    -------
    dict
        ``M`` [kg], ``Fv`` [N s/m], ``Fc`` [N], ``offset`` [N], their ``stderr`` (dict) and
        the ``relative_error_pct`` of the force fit.

    """
    speed, acceleration, keep = _idim_kinematics(record)
    columns = np.column_stack([acceleration, speed, np.sign(speed),
                               np.ones_like(speed)])[keep]
    force = (gtau * record.current)[keep]
    matrix = np.column_stack([_decimate(columns[:, j], decimation) for j in range(4)])
    target = _decimate(force, decimation)
    theta, *_ = np.linalg.lstsq(matrix, target, rcond=None)
    error = target - matrix @ theta
    stderr = np.std(error) * np.sqrt(np.diag(np.linalg.inv(matrix.T @ matrix)))
    names = ('M', 'Fv', 'Fc', 'offset')
    out = {name: float(value) for name, value in zip(names, theta)}
    out['stderr'] = {name: float(value) for name, value in zip(names, stderr)}
    out['relative_error_pct'] = float(100.0 * np.linalg.norm(error) / np.linalg.norm(target))
    return out


def _idim_kinematics(record):
    """
    Return the IDIM speed and acceleration of the carriage and the samples kept.

    The reference processing: Butterworth low-pass applied forward and backward to the
    position, then central differences twice; the first samples are dropped.
    """
    dt = record.sample_period_s
    b, a = signal.butter(FILTER_ORDER, FILTER_CUTOFF_HZ / (0.5 / dt))
    position = signal.filtfilt(b, a, record.position)
    speed = central_differences(position, dt)
    acceleration = central_differences(speed, dt)
    return speed, acceleration, slice(BORDER_SAMPLES, None)


def idim_force_error_pct(parameters: Mapping[str, float], record: Record, gtau: float,
                         decimation: int = DECIMATION) -> float:
    """Relative error [%] of the IDIM force fit for given (M, Fv, Fc, offset)."""
    speed, acceleration, keep = _idim_kinematics(record)
    model = (parameters['M'] * acceleration + parameters['Fv'] * speed
             + parameters['Fc'] * np.sign(speed) + parameters['offset'])[keep]
    force = (gtau * record.current)[keep]
    model, force = _decimate(model, decimation), _decimate(force, decimation)
    return float(100.0 * np.linalg.norm(force - model) / np.linalg.norm(force))


def as_idim(parameters: Mapping[str, float]) -> dict[str, float]:
    """Map a mechanical-only result (J, b, Mc, load torque) onto the names M, Fv, Fc, offset."""
    return {'M': float(parameters['J']), 'Fv': float(parameters['b']),
            'Fc': float(parameters['Mc']),
            'offset': float(parameters.get('load_torque.torque_Nm', 0.0))}


def simulation_error_pct(parameters: Mapping[str, float], record: Record,
                         gtau: float) -> float:
    """
    Speed simulation error [% of std] of (M, Fv, Fc, offset) on a record, from its start.

    The carriage is simulated exactly (stick-slip included) from the force ``gtau * vir``
    (held as the trapezoidal mean over each sample, as the fit does) and the measured initial
    speed.
    """
    force = gtau * np.append(0.5 * (record.current[:-1] + record.current[1:]),
                             record.current[-1])
    effects = MotorEffects(load_torque_Nm=parameters['offset'])
    speed, _ = simulate_mechanical_effects(parameters['M'], parameters['Fv'], parameters['Fc'],
                                           force, record.sample_period_s, effects,
                                           float(record.speed[0]), oversample=1)
    return float(np.sqrt(np.mean((speed - record.speed) ** 2)) / np.std(record.speed) * 100.0)


def output_error_idim_structure(record: Record, gtau: float) -> Any:
    """Output-error fit of the IDIM-LS structure (base model + load_torque) on all the data."""
    terms = LoadTorque.terms([record], {}, {'Mc': 20.0}, gtau)
    estimate = RefinedEstimator().fit([record], torque_constant=gtau, terms=terms)
    return estimate


def emps_study(data_dir: str | None = None) -> dict[str, Any]:
    """
    Identify EMPS with the discovery loop and compare with IDIM-LS; return a dict.

    Returns
    -------
    dict
        ``published`` and ``idim_ls`` (this package's replication of the reference
        processing); ``oe_idim_structure``: the output-error estimate of the same structure
        (base + load_torque) with, for both parameter sets, the force-equation error and the
        speed simulation error on the estimation and validation records (each method wins on
        its own criterion); ``loop`` and ``loop_extended``: the identify results with the
        issue's vocabulary and with the extended one, each with ``estimation`` and
        ``validation`` simulation errors of the base and the final model.

    """
    from dcmotor_id.identification.discovery import errors_by_step
    from dcmotor_id.identification.identify import identify
    directory = find_data_dir(data_dir)
    estimation, gtau = load_emps(os.path.join(directory, ESTIMATION_FILE))
    validation, _ = load_emps(os.path.join(directory, VALIDATION_FILE))
    replication = idim_ls(estimation, gtau)
    estimate = output_error_idim_structure(estimation, gtau)
    oe = as_idim(estimate.parameters)
    idim = {name: replication[name] for name in ('M', 'Fv', 'Fc', 'offset')}
    comparison = {}
    for label, values in (('idim_ls', idim), ('output_error', oe)):
        comparison[label] = {
            'parameters': values,
            'force_error_pct': idim_force_error_pct(values, estimation, gtau),
            'speed_error_estimation_pct': simulation_error_pct(values, estimation, gtau),
            'speed_error_validation_pct': simulation_error_pct(values, validation, gtau),
        }
    comparison['output_error']['stderr'] = as_idim(estimate.stderr)
    out = {'published': dict(PUBLISHED_IDIM_LS), 'idim_ls': replication,
           'criteria': comparison, 'gtau': gtau}
    for key, vocabulary in (('loop', VOCABULARY), ('loop_extended', EXTENDED_VOCABULARY)):
        identified = identify([estimation], torque_constant=gtau, vocabulary=vocabulary,
                              criterion='speed')
        found = identified.discovery_result
        out[key] = {'result': identified.as_dict(), 'found': found,
                    'estimation': found.errors_on([estimation]),
                    'validation': found.errors_on([validation]),
                    'validation_by_step': errors_by_step(found, [validation])}
    return out


def format_study(study: Mapping[str, Any]) -> str:
    """Markdown tables of the study (the README's EMPS section)."""
    published, replication = study['published'], study['idim_ls']
    oe = study['criteria']['output_error']
    lines = ['| parameter | published IDIM-LS | this IDIM-LS | diff | output error (base + '
             'load_torque) | diff |', '|---|---|---|---|---|---|']
    for name, unit in (('M', 'kg'), ('Fv', 'N s/m'), ('Fc', 'N'), ('offset', 'N')):
        ref = published[name]
        mine = replication[name]
        value = oe['parameters'][name]
        lines.append(f'| {name} [{unit}] | {ref:.4f} | {mine:.4f} | '
                     f'{(mine - ref) / abs(ref) * 100:+.2f} % | {value:.4f} +/- '
                     f'{oe["stderr"][name]:.2g} | {(value - ref) / abs(ref) * 100:+.2f} % |')
    lines += ['', '| parameters | force-equation error (IDIM criterion) | speed simulation error, '
              'estimation | speed simulation error, PULSES validation |', '|---|---|---|---|']
    for label in ('idim_ls', 'output_error'):
        item = study['criteria'][label]
        lines.append(f'| {"IDIM-LS" if label == "idim_ls" else "output error"} | '
                     f'{item["force_error_pct"]:.2f} % | '
                     f'{item["speed_error_estimation_pct"]:.2f} % | '
                     f'{item["speed_error_validation_pct"]:.2f} % |')
    lines += ['', '| vocabulary | effects found (in order) | held-out error before -> after | '
              'estimation record before -> after | PULSES before -> after | unexplained |',
              '|---|---|---|---|---|---|']
    for key, label in (('loop', 'standard'), ('loop_extended', 'extended')):
        item = study[key]
        result = item['result']
        found = ', '.join(_effect_text(effect) for effect in result['effects']) or 'none'

        def pair(errors):
            return (f"{errors['before']['speed_nrmse_pct']:.2f} % -> "
                    f"{errors['after']['speed_nrmse_pct']:.2f} %")
        held = {'before': result['error_before'], 'after': result['error_after']}
        lines.append(f'| {label} | {found} | {pair(held)} | {pair(item["estimation"])} | '
                     f'{pair(item["validation"])} | {str(result["unexplained"]).lower()} |')
    lines += ['', '| vocabulary | PULSES speed error, effect by effect (all-data refits) |',
              '|---|---|']
    for key, label in (('loop', 'standard'), ('loop_extended', 'extended')):
        steps = study[key]['validation_by_step']
        text = ' -> '.join(f"{'+'.join(step['effects']) or 'base'} "
                           f"{step['speed_nrmse_pct']:.2f} %" for step in steps)
        lines.append(f'| {label} | {text} |')
    lines += ['', '| vocabulary | round | candidates (held-out gain) |', '|---|---|---|']
    for key, label in (('loop', 'standard'), ('loop_extended', 'extended')):
        for number, step in enumerate(study[key]['result']['discovery']['steps'], start=1):
            text = ', '.join(f"{c['name']} {c['heldout_gain_pct']:.1f} %"
                             + (' (rejected)' if c.get('rejected') else '')
                             for c in step['candidates'] if c['heldout_gain_pct'] is not None)
            added = step['added']['name'] if step.get('added') else 'none added'
            lines.append(f'| {label} | {number}: {added} | {text} |')
    return '\n'.join(lines)


def _effect_text(effect):
    values = ', '.join(f'{key} {value:.4g}' if isinstance(value, float) else f'{key} {value}'
                       for key, value in effect['parameters'].items())
    return f'{effect["name"]} ({values})'


#: Samples at the start of the validation record not scored (the benchmark's protocol).
SCORE_SKIP_SAMPLES = 20
#: Effects of the position-output fits: name -> ((model parameter, start value, scale), ...).
POSITION_FIT_TERMS: dict[str, tuple[tuple[str, float, float], ...]] = {
    'load_torque': (('torque_Nm', -3.0, 1.0),),
    'viscous_asymmetry': (('delta_Nm_s', 0.0, 10.0),),
    'coulomb_asymmetry': (('delta_Nm', 0.0, 1.0),),
    'stribeck': (('excess_Nm', 2.0, 1.0), ('velocity_rad_s', 0.005, 0.002)),
    'quadratic_drag': (('coefficient_Nm_s2', 0.0, 50.0),),
    'cogging': (('amplitude_Nm', 0.5, 0.5), ('phase_rad', 0.0, 1.0)),
}
#: Ripple periods of the cogging rows [m]: a slow force along the stroke (0.5 m, twice the
#: 0.25 m stroke) and the 58 mm period the discovery loop finds (108 cycles per 2 pi m).
COGGING_PERIODS_M = (0.5, 2.0 * np.pi / 108.0)


def emps_model(parameters: Mapping[str, float], gtau: float,
               effects: Sequence[Mapping[str, Any]] = ()) -> Any:
    """Return a mechanical-only validation ``Model`` of EMPS (M, Fv, Fc)."""
    from dcmotor_id.identification.validate import Model
    return Model({'J': float(parameters['M']), 'b': float(parameters['Fv']),
                  'Mc': float(parameters['Fc'])}, 'mechanical', gtau, list(effects))


def idim_model(parameters: Mapping[str, float], gtau: float) -> Any:
    """Return the IDIM-LS structure (M, Fv, Fc, offset) as a model (offset = load torque)."""
    return emps_model(parameters, gtau, [{'name': 'load_torque',
                                          'parameters': {'torque_Nm': parameters['offset']}}])


@dataclass(frozen=True)
class PositionFit:
    """
    A position-output fit: the model and the first-order lag of the force it assumes.

    Attributes
    ----------
    model : dcmotor_id.identification.validate.Model
        The rigid model with its effects.
    input_lag_s : float
        Time constant of a first-order lag between ``gtau * vir`` and the force on the
        carriage (the drive's current loop), 0 for none.
    training_rmse_m : float
        Position RMSE of the fit on its training record [m].

    """

    model: Any
    input_lag_s: float = 0.0
    training_rmse_m: float = float('nan')

    def record(self, record: Record) -> Record:
        """Return the record as the model sees it (its input through the lag)."""
        return lagged_input(record, self.input_lag_s)


def lagged_input(record: Record, time_constant_s: float) -> Record:
    """
    Return the record with its input through a first-order lag (exact for a held input).

    ``y[k+1] = a y[k] + (1 - a) u[k]``, ``a = exp(-dt / tau)``, ``y[0] = u[0]``; a time
    constant of 0 returns the record unchanged.
    """
    if time_constant_s <= 0.0:
        return record
    a = float(np.exp(-record.sample_period_s / time_constant_s))
    current = np.asarray(record.current, dtype=float)
    lagged = signal.lfilter([0.0, 1.0 - a], [1.0, -a], current - current[0]) + current[0]
    return record.replace(current=lagged)


def position_output_fit(record: Record, gtau: float,
                        effects: Sequence[str] = ('load_torque',),
                        inner: Mapping[str, Mapping[str, float]] | None = None,
                        input_lag: bool = False) -> PositionFit:
    """
    Fit M, Fv, Fc and the effects' parameters to the measured position (output error).

    The rigid model is simulated open loop from the force ``gtau * vir`` (the package's exact
    simulator, :func:`dcmotor_id.identification.validate.simulate`) and the squared position error
    after the first :data:`SCORE_SKIP_SAMPLES` samples is minimised: the criterion the benchmark
    scores, unlike the speed-output fit of the package, which weights the fast speed changes and
    lets a small force bias integrate into a position drift.

    Parameters
    ----------
    record : Record
        The training record.
    gtau : float
        Drive gain [N/V].
    effects : sequence of str
        Effects of :data:`POSITION_FIT_TERMS` to fit.
    inner : dict, optional
        Fixed parameters by effect (the cogging's ``cycles_per_rev``).
    input_lag : bool
        Also fit a first-order lag of the force (:func:`lagged_input`).

    """
    from scipy.optimize import least_squares

    from dcmotor_id.identification.validate import simulate

    fixed = {name: dict(values) for name, values in (inner or {}).items()}
    specs = [(name, spec) for name in effects for spec in POSITION_FIT_TERMS[name]]
    start = [95.0, 200.0, 20.0] + [spec[1] for _, spec in specs]
    scale = [10.0, 20.0, 2.0] + [spec[2] for _, spec in specs]
    if input_lag:
        start.append(0.003)
        scale.append(0.002)
    measured = np.asarray(record.position, dtype=float)

    def split(values: Sequence[float]) -> tuple[Any, float]:
        parameters = dict(zip(('M', 'Fv', 'Fc'), values[:3]))
        terms: dict[str, dict[str, float]] = {name: dict(fixed.get(name, {}))
                                              for name in effects}
        for (name, spec), value in zip(specs, values[3:]):
            # the Stribeck velocity enters squared: report its magnitude
            terms[name][spec[0]] = abs(float(value)) if spec[0] == 'velocity_rad_s' else float(
                value)
        listing = [{'name': name, 'parameters': terms[name]} for name in effects]
        lag = abs(float(values[-1])) if input_lag else 0.0
        return emps_model(parameters, gtau, listing), lag

    def residual(values: np.ndarray) -> np.ndarray:
        model, lag = split(values)
        simulated = simulate(model, lagged_input(record, lag), [float(record.speed[0])])
        return (simulated['position'] - measured)[SCORE_SKIP_SAMPLES:]
    fitted = least_squares(residual, start, x_scale=scale, max_nfev=200)
    model, lag = split(fitted.x)
    return PositionFit(model, lag, float(np.sqrt(np.mean(fitted.fun ** 2))))


def friction_by_record(record: Record, gtau: float,
                       decimation: int = DECIMATION) -> dict[str, float]:
    """
    Direction-dependent IDIM-LS on one record: M, Fv+, Fv-, Fc+, Fc- (the benchmark's model).

    ``gtau vir = M qdd + Fv+ qd+ + Fv- qd- + Fc+ [qd > 0] - Fc- [qd < 0]`` by the reference
    processing of :func:`idim_ls`; the same model on two records tells how much the friction
    differs between them (the force that drifts an open-loop simulation trained on the other).
    """
    speed, acceleration, keep = _idim_kinematics(record)
    columns = np.column_stack([acceleration, speed * (speed > 0), speed * (speed < 0),
                               (speed > 0).astype(float), -(speed < 0).astype(float)])[keep]
    force = (gtau * record.current)[keep]
    matrix = np.column_stack([_decimate(columns[:, j], decimation) for j in range(5)])
    theta, *_ = np.linalg.lstsq(matrix, _decimate(force, decimation), rcond=None)
    return dict(zip(('M', 'Fv_pos', 'Fv_neg', 'Fc_pos', 'Fc_neg'), map(float, theta)))


def pulse_steps_in_input(estimation: Record, validation: Record, path: str,
                         gtau: float) -> dict[str, Any]:
    """
    Where the force pulses of the validation record are: in the recorded input or not.

    Compares the two records' ``vir`` (the same trajectory) at the onsets of ``pulses_N``:
    a jump equal to the pulse at its onset sample means the recorded input carries it.
    ``settled_force_difference_N``: the mean force ``gtau (vir_PULSES - vir_EMPS)`` away from
    the pulses (pulse off, 200 ms after its last change), moving forward and backward: what
    the two records differ by without a pulse.
    """
    pulses = np.ravel(loadmat(path)['pulses_N']).astype(float)
    onsets = np.flatnonzero(np.diff(pulses) != 0) + 1
    difference = validation.current - estimation.current
    jumps = difference[onsets] - difference[onsets - 1]
    heights = pulses[onsets] - pulses[onsets - 1]
    # away from the pulses: pulse off and no change of the pulse in the last 200 ms
    settled = pulses == 0
    for onset in onsets:
        settled[onset:onset + 200] = False
    force = gtau * difference
    speed = estimation.speed
    return {'pulses': int(onsets.size), 'pulse_height': float(np.max(np.abs(heights))),
            'settled_force_difference_N': {
                'forward': float(np.mean(force[settled & (speed > 0.01)])),
                'backward': float(np.mean(force[settled & (speed < -0.01)]))},
            'median_jump_of_vir_at_onset': float(np.median(np.abs(jumps))),
            'max_position_difference_m': float(np.max(np.abs(validation.position
                                                             - estimation.position)))}


def emps_score(data_dir: str | None = None) -> dict[str, Any]:
    """
    Score models on EMPS as the benchmark community does; return a dict of rows.

    Train on DATA_EMPS, simulate DATA_EMPS_PULSES open loop from ``gtau * vir``, position RMSE in
    mm after the first 20 samples (:func:`dcmotor_id.identification.validate.validate_record`,
    initial speed from those samples). Rows: the published IDIM-LS parameters; the 4-parameter
    rigid model fitted by output error on speed (the package's criterion) and on position; the
    discovery loop's model (``identify`` on DATA_EMPS); position-output fits with the extensions
    tried (asymmetric friction, Stribeck, drag, a force periodic in position, a lag of the force).
    A last row fits the best structure on PULSES itself: a diagnosis of the difference between the
    two records, not a score. ``friction`` holds the direction-dependent IDIM-LS of each record
    (:func:`friction_by_record`).
    """
    from dcmotor_id.identification.identify import identify
    from dcmotor_id.identification.validate import model_from_dict, validate_record

    directory = find_data_dir(data_dir)
    estimation, gtau = load_emps(os.path.join(directory, ESTIMATION_FILE))
    validation, _ = load_emps(os.path.join(directory, VALIDATION_FILE))
    asymmetric = ('load_torque', 'viscous_asymmetry')
    fits: list[tuple[str, PositionFit]] = [
        ('published IDIM-LS (M, Fv, Fc, offset)',
         PositionFit(idim_model(PUBLISHED_IDIM_LS, gtau))),
        ('4-parameter rigid model, output error on speed',
         PositionFit(idim_model(as_idim(output_error_idim_structure(estimation, gtau)
                                        .parameters), gtau))),
        ('4-parameter rigid model, output error on position',
         position_output_fit(estimation, gtau)),
    ]
    loop = identify([estimation], torque_constant=gtau, criterion='speed')
    fits.append(('discovery loop on speed (identify, effects: '
                 + (', '.join(e['name'] for e in loop.effects) or 'none') + ')',
                 PositionFit(model_from_dict(loop.as_dict()))))
    fits.append(('position output error + viscous_asymmetry',
                 position_output_fit(estimation, gtau, asymmetric)))
    fits.append(('position output error + viscous and coulomb asymmetry',
                 position_output_fit(estimation, gtau, asymmetric + ('coulomb_asymmetry',))))
    fits.append(('position output error + viscous_asymmetry + stribeck',
                 position_output_fit(estimation, gtau, asymmetric + ('stribeck',))))
    fits.append(('position output error + viscous_asymmetry + quadratic_drag',
                 position_output_fit(estimation, gtau, asymmetric + ('quadratic_drag',))))
    for period in COGGING_PERIODS_M:
        fits.append((f'position output error + viscous_asymmetry + force periodic in position '
                     f'(cogging, period {period * 1e3:.0f} mm)',
                     position_output_fit(estimation, gtau, asymmetric + ('cogging',),
                                         {'cogging': {'cycles_per_rev': 2 * np.pi / period}})))
    fits.append(('position output error + viscous_asymmetry + first-order lag of the force',
                 position_output_fit(estimation, gtau, asymmetric, input_lag=True)))
    half = len(estimation) // 2
    for label, part in (('first', estimation.slice(0, half)),
                        ('second', estimation.slice(half, len(estimation)))):
        fits.append((f'position output error + viscous_asymmetry, {label} half of DATA_EMPS '
                     'only', position_output_fit(part, gtau, asymmetric)))
    cogging = {'cogging': {'cycles_per_rev': 2 * np.pi / COGGING_PERIODS_M[1]}}
    diagnoses = [
        ('diagnosis, not a score: position output error + viscous_asymmetry fitted on PULSES',
         position_output_fit(validation, gtau, asymmetric)),
        ('diagnosis, not a score: + force periodic in position (58 mm) fitted on PULSES',
         position_output_fit(validation, gtau, asymmetric + ('cogging',), cogging)),
    ]
    rows = []
    for label, fit in fits + diagnoses:
        scores = {}
        for name, record in (('estimation', estimation), ('validation', validation)):
            item = validate_record(fit.model, fit.record(record), SCORE_SKIP_SAMPLES).scores
            scores[name] = {'position_rmse_mm': 1e3 * item['position_rmse'],
                            'speed_nrmse_pct': item['speed_nrmse_pct'],
                            'fit_position_pct': item['fit_pct']['position']}
        rows.append({'model': label, 'parameters': dict(fit.model.parameters),
                     'effects': [dict(effect) for effect in fit.model.effects],
                     'input_lag_s': fit.input_lag_s,
                     'diagnosis': label.startswith('diagnosis'), **scores})
    return {'rows': rows, 'gtau': gtau,
            'friction': {'estimation': friction_by_record(estimation, gtau),
                         'validation': friction_by_record(validation, gtau)},
            'pulses': pulse_steps_in_input(estimation, validation,
                                           os.path.join(directory, VALIDATION_FILE), gtau)}


def format_score(score: Mapping[str, Any]) -> str:
    """Markdown tables of :func:`emps_score` (the scores, then the friction of each record)."""
    lines = ['| model (trained on DATA_EMPS) | M [kg] | Fv [N s/m] | Fc [N] | effects | '
             'PULSES position RMSE [mm] | PULSES fit position | DATA_EMPS position RMSE [mm] |',
             '|---|---|---|---|---|---|---|---|']
    for row in score['rows']:
        p = row['parameters']
        effects = '; '.join(f"{e['name']} " + ', '.join(f'{k} {v:.4g}' for k, v in
                                                        e['parameters'].items()
                                                        if isinstance(v, float))
                            for e in row['effects']) or 'none'
        if row.get('input_lag_s'):
            effects += f"; force lag {row['input_lag_s'] * 1e3:.2f} ms"
        lines.append(f"| {row['model']} | {p['J']:.2f} | {p['b']:.1f} | {p['Mc']:.2f} | "
                     f"{effects} | **{row['validation']['position_rmse_mm']:.2f}** | "
                     f"{row['validation']['fit_position_pct']:.2f} % | "
                     f"{row['estimation']['position_rmse_mm']:.2f} |")
    friction = score.get('friction')
    if friction:
        names = (('M', 'M [kg]'), ('Fv_pos', 'Fv+ [N s/m]'), ('Fv_neg', 'Fv- [N s/m]'),
                 ('Fc_pos', 'Fc+ [N]'), ('Fc_neg', 'Fc- [N]'))
        lines += ['', '| direction-dependent IDIM-LS | ' + ' | '.join(t for _, t in names)
                  + ' |', '|---' * (len(names) + 1) + '|']
        for key, label in (('estimation', 'DATA_EMPS'), ('validation', 'DATA_EMPS_PULSES')):
            lines.append(f'| {label} | ' + ' | '.join(f'{friction[key][n]:.2f}'
                                                      for n, _ in names) + ' |')
    return '\n'.join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Print the EMPS study; ``--report DIR`` also writes the loop's report."""
    import argparse
    parser = argparse.ArgumentParser(prog='python -m studies.emps',
                                     description='EMPS: IDIM-LS cross-check and the discovery '
                                                 'loop on measured data')
    parser.add_argument('data_dir', nargs='?', help='directory with the EMPS .mat files')
    parser.add_argument('--report', metavar='DIR', help='write the HTML report here')
    parser.add_argument('--score', action='store_true',
                        help='the benchmark score instead: position RMSE on PULSES')
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.score:
        print(format_score(emps_score(args.data_dir)))
        return 0
    study = emps_study(args.data_dir)
    print(format_study(study))
    if args.report:
        from dcmotor_id.reports.identification import write_report
        for key, name in (('loop', 'standard'), ('loop_extended', 'extended')):
            item = study[key]
            result = dict(item['result'])
            result['units'] = {'J': 'kg (M)', 'b': 'N s/m (Fv)', 'Mc': 'N (Fc)'}
            page = write_report(os.path.join(args.report, name), result, item['found'],
                                channel_units={'speed': 'm/s', 'current': 'V (vir)'},
                                title=f'EMPS ({name} vocabulary): before / after')
            print(f'report ({key}): {page}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
