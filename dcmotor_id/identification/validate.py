"""
Validation of an identified model on records it was not fitted on (``dcmotor-id validate``).

The model is what ``identify --json`` wrote (its ``model`` block, :func:`model_block`). Each
record is simulated open loop with the model and its effects (state-dependent effects driven
by the simulated state), from an initial state estimated on the record's first samples, and
compared with the measurement as MATLAB's ``compare`` does: NRMSE in percent of each record's
own standard deviation, fit percent ``100 (1 - |y - y_sim| / |y - mean(y)|)``, and the
position RMSE when the record has a position (the simulated position is the integral of the
simulated speed from the measured first position). The samples used for the initial state
are not scored.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import json
import os
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import MECHANICAL_NAMES, MotorParameters, PARAMETER_NAMES
from dcmotor_id.core.records import COLUMNS, Record
from dcmotor_id.identification.effects import make_effect
from dcmotor_id.identification.estimators.voltage_speed import (NAMES as VOLTAGE_SPEED_NAMES,
                                                                simulate_speed)
from dcmotor_id.identification.estimators.voltage_speed_effects import simulate_speed_effects
from dcmotor_id.simulation import (combine_effects, held_input, simulate_mechanical_effects,
                                   simulate_motor_effects)

#: Samples at the start of a record used for the initial state (and not scored), by default.
INIT_SAMPLES = 20
#: Version tag of the ``model`` block of the identify JSON.
MODEL_FORMAT = 'dcmotor_id.core.model/1'
#: Sub-steps per sample for state-dependent effects (as the fit's state terms).
OVERSAMPLE = 10
#: The base parameters of each mode.
MODE_NAMES = {'full': PARAMETER_NAMES, 'mechanical': MECHANICAL_NAMES,
              'voltage_speed': VOLTAGE_SPEED_NAMES}


def model_block(result: Mapping[str, Any]) -> dict[str, Any]:
    """
    Return the self-contained ``model`` block of an identify result (its JSON layout).

    Everything :func:`load_model` needs to simulate the model again: ``mode``,
    ``torque_constant``, the base ``parameters`` (Ra, La, CPhi, J, b, Mc, or J, b, Mc in
    mechanical mode, kS, kV, kA in voltage_speed mode) with their ``parameter_units``, the
    ``effects`` with their parameters,
    the ``sample_period_s`` it was identified at and the ``channel_units`` of the records.

    Parameters
    ----------
    result : dict
        The identify JSON layout (``IdentificationResult.as_dict()`` without this block).

    """
    mode = result.get('mode', 'full')
    names = MODE_NAMES.get(mode, PARAMETER_NAMES)
    parameters = result.get('parameters', {})
    if not isinstance(parameters, Mapping):
        raise InputDataError(f'"parameters" is {json.dumps(parameters)[:80]}, not a mapping of '
                             'names to values; give the JSON written by dcmotor-id identify '
                             '--json')
    units = result.get('units', {})
    units = units if isinstance(units, Mapping) else {}
    effects = []
    for effect in result.get('effects', []) or []:
        if not isinstance(effect, Mapping) or not isinstance(effect.get('parameters', {}),
                                                             Mapping):
            raise InputDataError(f'effect {json.dumps(effect)[:80]} is not {{"name": ..., '
                                 '"parameters": {...}}')
        try:
            made = make_effect(effect['name'])
        except (KeyError, ValueError):
            continue
        known = set(made.PARAMETERS) | ({entry[0] for entry in made.VOLTAGE_SPEED_NAMES.values()}
                                        if mode == 'voltage_speed' else set())
        effects.append({'name': effect['name'],
                        'parameters': {key: value for key, value
                                       in effect.get('parameters', {}).items() if key in known}})
    return {
        'format': MODEL_FORMAT,
        'mode': mode,
        'torque_constant': result.get('torque_constant'),
        'parameters': {name: parameters.get(name) for name in names},
        'parameter_units': {name: units.get(name) for name in names},
        'effects': effects,
        'sample_period_s': result.get('sample_period_s'),
        'channel_units': dict(COLUMNS),
        'operating_range': result.get('operating_range'),
        **({'armature_lag': lag_block(result)} if mode == 'voltage_speed' else {}),
    }


def lag_block(result: Mapping[str, Any]) -> Optional[dict[str, float]]:
    """
    Return the armature lag of a voltage-to-speed result for the ``model`` block, or None.

    ``time_constant_s`` (``Ta``) and ``acceleration_gain`` (``kA + Ta Ra b/CPhi``), from
    ``combined``: with ``kS, kV, kA`` they give the exact second-order model the fit chose.
    """
    combined = result.get('combined')
    combined = combined if isinstance(combined, Mapping) else {}
    entries = [combined.get(key) for key in ('armature_time_constant_s', 'acceleration_gain')]
    if not all(isinstance(entry, Mapping) for entry in entries):
        return None
    values = [entry.get('value') for entry in entries if isinstance(entry, Mapping)]
    numbers = [float(value) for value in values if isinstance(value, (int, float))]
    if len(numbers) != 2 or not all(np.isfinite(value) and value > 0 for value in numbers):
        return None
    return {'time_constant_s': numbers[0], 'acceleration_gain': numbers[1]}


#: Share of a record's samples outside the model's operating range that earns a warning.
OUTSIDE_SHARE = 0.05
#: Margin beyond the model's range before a value counts as outside (a share of the range).
RANGE_MARGIN = 0.25
#: Percentiles of a channel that give its range (spikes of noise do not widen it).
RANGE_PERCENTILES = (1.0, 99.0)


def operating_range(records: Sequence[Record]) -> dict[str, Any]:
    """
    Return the range of speed and current the records cover (the model's operating range).

    ``speed_rad_s`` and ``current_A`` are ``[low, high]`` (the 1st and 99th percentiles over
    all records); ``directions`` lists ``positive`` and/or ``negative`` (speeds beyond a fifth
    of the largest).
    """
    out: dict[str, Any] = {}
    for key, channel in (('speed_rad_s', 'speed'), ('current_A', 'current')):
        values = [np.asarray(getattr(rec, channel), dtype=float) for rec in records
                  if getattr(rec, channel, None) is not None]
        if values:
            joined = np.concatenate(values)
            out[key] = [float(value) for value in np.percentile(joined, RANGE_PERCENTILES)]
    speed = out.get('speed_rad_s')
    if speed is not None:
        top = max(abs(speed[0]), abs(speed[1]))
        out['directions'] = [name for name, present in
                             (('positive', speed[1] > 0.2 * top),
                              ('negative', speed[0] < -0.2 * top)) if present]
    return out


def range_warnings(seen: Mapping[str, Any] | None, record: Record) -> list[str]:
    """
    Warnings for a record outside the operating range a model was identified on.

    A direction of rotation the model never saw, or speed or current beyond its range (by
    more than :data:`RANGE_MARGIN` of the range, on more than :data:`OUTSIDE_SHARE` of the
    samples): the model extrapolates there, and its errors say little about its parameters.
    """
    if not seen:
        return []
    name = record.source or 'record'
    out = []
    here = operating_range([record])
    missing = [direction for direction in here.get('directions', [])
               if direction not in seen.get('directions', here.get('directions', []))]
    if missing:
        out.append(f'{name}: turns in the {" and ".join(missing)} direction, which the model '
                   f'never saw (identified on {" and ".join(seen.get("directions", []))} '
                   'rotation only): friction and offsets differ by direction, so the model '
                   'extrapolates; identify on records in both directions')
    for key, channel, unit in (('speed_rad_s', 'speed', 'rad/s'), ('current_A', 'current', 'A')):
        bounds = seen.get(key)
        values = getattr(record, channel, None)
        if not bounds or values is None or missing and channel == 'speed':
            continue
        low, high = bounds
        margin = RANGE_MARGIN * max(high - low, 1e-300)
        values = np.asarray(values, dtype=float)
        outside = float(np.mean((values < low - margin) | (values > high + margin)))
        if outside > OUTSIDE_SHARE:
            out.append(f'{name}: {100 * outside:.0f} % of its {channel} lies beyond the range '
                       f'the model was identified on ({low:.4g} .. {high:.4g} {unit}): the '
                       'model extrapolates there')
    return out


@dataclass(frozen=True)
class Model:
    """
    A model to simulate: base parameters, mode, effects.

    Attributes
    ----------
    parameters : dict
        Base parameters by name (SI).
    mode : str
        ``full``, ``mechanical`` or ``voltage_speed`` (``kS, kV, kA``: the voltage to the
        speed, no current).
    torque_constant : float or None
        Torque constant of the mechanical mode [N m/A].
    effects : list of dict
        ``{"name", "parameters"}`` of every effect.
    sample_period_s : float or None
        Sample period the model was identified at [s].
    description : dict
        The ``model`` block as read (echoed in the validation JSON).

    """

    parameters: Mapping[str, float]
    mode: str = 'full'
    torque_constant: Optional[float] = None
    effects: Sequence[Mapping[str, Any]] = ()
    sample_period_s: Optional[float] = None
    description: Mapping[str, Any] = field(default_factory=dict)

    @property
    def mechanical_only(self) -> bool:
        """Whether the current is the input (mechanical-only mode)."""
        return self.mode == 'mechanical'

    @property
    def outputs(self) -> tuple[str, ...]:
        """Return the measured channels the model simulates (besides the position)."""
        return ('current', 'speed') if self.mode == 'full' else ('speed',)


def model_from_dict(data: Mapping[str, Any], source: str = 'model') -> Model:
    """
    Build a :class:`Model` from an identify JSON (its ``model`` block, or the top level).

    Raises
    ------
    InputDataError
        A parameter missing or not a positive number, an unknown effect.

    """
    if not isinstance(data, Mapping):
        raise InputDataError(f'{source}: not an identify result (a JSON object is expected)')
    given = data.get('model')
    if isinstance(given, Mapping):
        check_one_model(data, source)
    block: Mapping[str, Any] = given if isinstance(given, Mapping) else _top_level(data, source)
    mode = block.get('mode', 'full')
    if mode not in MODE_NAMES:
        raise InputDataError(f'{source}: unknown mode {mode!r} (full, mechanical or '
                             'voltage_speed)')
    parameters = {}
    for name in MODE_NAMES[mode]:
        value = (block.get('parameters') or {}).get(name)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or \
                not np.isfinite(value) or value < 0 or (
                value == 0 and name not in ('b', 'Mc', 'kS')):
            raise InputDataError(f'{source}: parameter {name} is {value!r}; a model written by '
                                 'dcmotor-id identify --json is expected')
        parameters[name] = float(value)
    constant = block.get('torque_constant')
    if mode == 'mechanical' and not (isinstance(constant, (int, float)) and constant > 0):
        raise InputDataError(f'{source}: a mechanical-only model needs its torque_constant')
    effects = list(block.get('effects') or [])
    for effect in effects:
        _check_effect(effect, source, mode)
    if mode == 'voltage_speed':
        _check_lag(block.get('armature_lag'), source)
    return Model(parameters, mode, None if constant is None else float(constant), effects,
                 block.get('sample_period_s'), dict(block))


def _check_lag(lag: Any, source: str) -> None:
    """Refuse an ``armature_lag`` that is not None or two positive finite numbers."""
    if lag is None:
        return
    values = [lag.get(key) for key in ('time_constant_s', 'acceleration_gain')] \
        if isinstance(lag, Mapping) else [None]
    if not all(isinstance(value, (int, float)) and not isinstance(value, bool)
               and np.isfinite(value) and value > 0 for value in values):
        raise InputDataError(
            f'{source}: model.armature_lag is {json.dumps(lag)[:120]}: null or '
            '{"time_constant_s": Ta [s], "acceleration_gain": kA + Ta Ra b/CPhi [V s^2/rad]}, '
            'both positive, is expected (as identify --json writes it)')


def _top_level(data: Mapping[str, Any], source: str) -> dict[str, Any]:
    """Return :func:`model_block` of the top level; a malformed one is named by ``source``."""
    try:
        return model_block(data)
    except InputDataError as error:
        raise InputDataError(f'{source}: {error}') from None


def check_one_model(data: Mapping[str, Any], source: str = 'model') -> None:
    """
    Refuse a result whose ``model`` block and top-level ``parameters`` describe two motors.

    ``validate`` simulates the ``model`` block and ``design`` reads ``parameters``: an edit of
    one of them alone (J x10, a string, an unknown effect) would be scored on the other.  The
    refusal names the first key that differs.

    Raises
    ------
    InputDataError
        Naming the key, both values and what to do.

    """
    given = data.get('model')
    if not isinstance(given, Mapping) or 'parameters' not in data:
        return
    rebuilt = _top_level(data, source)
    names = [_effect_names(data.get('effects')), _effect_names(given.get('effects'))]
    if names[0] != names[1]:
        raise InputDataError(
            f'{source}: "effects" ({", ".join(map(str, names[0])) or "none"}) differ from '
            f'model.effects ({", ".join(map(str, names[1])) or "none"}): a result file holds '
            'one model; edit both, or delete the "model" block (validate then uses the top '
            'level)')
    known = {effect['name'] for effect in rebuilt['effects']}
    given = {**given, 'effects': [
        {'name': effect.get('name'), 'parameters': effect.get('parameters', {})}
        for effect in given.get('effects') or [] if effect.get('name') in known]}
    for key in ('mode', 'parameters', 'effects'):
        mine: Any = rebuilt.get(key)
        theirs: Any = given.get(key)
        if key == 'mode':
            mine, theirs = mine or 'full', theirs or 'full'
        if key == 'parameters' and isinstance(theirs, Mapping):
            differs = [name for name in mine if mine[name] != theirs.get(name)]
            if differs:
                name = differs[0]
                raise InputDataError(
                    f'{source}: parameters.{name} = {json.dumps(mine[name])} but '
                    f'model.parameters.{name} = {json.dumps(theirs.get(name))}: a result '
                    'file holds one model; edit both, or delete the "model" block (validate '
                    'then uses "parameters")')
        elif mine != theirs:
            raise InputDataError(
                f'{source}: "{key}" ({json.dumps(mine)[:120]}) differs from model.{key} '
                f'({json.dumps(theirs)[:120]}): a result file holds one model; edit both, or '
                'delete the "model" block (validate then uses the top level)')


def _effect_names(effects: Any) -> list[Any]:
    """Return the names of a list of effects (an entry that is not a mapping: itself)."""
    return [effect.get('name') if isinstance(effect, Mapping) else effect
            for effect in (effects if isinstance(effects, list) else [])]


def _check_effect(effect: Any, source: str, mode: str = 'full') -> None:
    """Refuse an effect that is unknown, or whose parameters are not of their types."""
    if not isinstance(effect, Mapping) or not isinstance(effect.get('parameters', {}), Mapping):
        raise InputDataError(f'{source}: effect {effect!r} is not {{"name": ..., "parameters": '
                             '{...}}; a model written by dcmotor-id identify --json is expected')
    try:
        made = (_voltage_speed_effect(effect) if mode == 'voltage_speed' else
                make_effect(effect['name'], **effect.get('parameters', {})))
    except (KeyError, TypeError, ValueError) as error:
        raise InputDataError(f'{source}: effect {effect!r}: {error}') from None
    for key, value in effect.get('parameters', {}).items():
        default = made.PARAMETERS.get(key, ('', 0.0, ''))[1]
        if isinstance(default, str):
            continue
        if not isinstance(value, (int, float)) or isinstance(value, bool) or \
                not np.isfinite(value):
            raise InputDataError(f'{source}: effect {effect["name"]}: parameter {key} is '
                                 f'{json.dumps(value)}, not a finite number; fix the model file '
                                 '(as dcmotor-id identify --json writes it)')


def _voltage_speed_effect(effect: Mapping[str, Any]) -> Any:
    """
    Build an effect of a ``voltage_speed`` model (its parameters in volts).

    Raises
    ------
    ValueError
        An effect that does not act in the voltage-to-speed model, or an unknown parameter.

    """
    cls = type(make_effect(effect['name']))
    parameters = dict(effect.get('parameters', {}))
    if not cls.in_voltage_speed():
        raise ValueError(f'{cls.name} does not act in the voltage-to-speed model (no current)')
    allowed = ({entry[0] for entry in cls.VOLTAGE_SPEED_NAMES.values()}
               | (set(cls.PARAMETERS) - set(cls.VOLTAGE_SPEED_NAMES)))
    unknown = sorted(set(parameters) - allowed)
    if unknown:
        raise ValueError(f'unknown parameter(s) {", ".join(unknown)} of a voltage_speed model; '
                         f'it has {", ".join(sorted(allowed)) or "none"}')
    return cls.from_voltage_speed(parameters)


def load_model(path: str) -> Model:
    """Read a model from the JSON ``identify --json`` wrote."""
    from dcmotor_id.formats.json_file import load_json  # not on identify's path (tempfile)

    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file; give the JSON written by identify --json')
    try:
        with open(path, encoding='utf-8') as stream:
            data = load_json(stream)
    except (ValueError, UnicodeDecodeError) as error:
        raise InputDataError(f'{path}: not a JSON file ({error}); give the JSON written by '
                             'dcmotor-id identify --json') from None
    return model_from_dict(data, path)


def _effects_for(model: Model, sample_period_s: float) -> tuple[list[Any], dict[str, int]]:
    """Return the simulation effects and the sensor delays [samples of this record]."""
    effects: list[Any] = []
    delays: dict[str, int] = {}
    for item in model.effects:
        parameters = dict(item.get('parameters', {}))
        if item['name'] == 'sensor_delay':
            samples = float(parameters.get('samples', 0))
            if model.sample_period_s:
                samples *= float(model.sample_period_s) / sample_period_s
            channel = str(parameters.get('channel', 'speed'))
            delays[channel] = delays.get(channel, 0) + int(round(samples))
            continue
        if model.mechanical_only and item['name'] in ('current_offset',):
            continue
        effects.append(_voltage_speed_effect(item) if model.mode == 'voltage_speed' else
                       make_effect(item['name'], **parameters))
    return effects, delays


def _shift(values: np.ndarray, samples: int) -> np.ndarray:
    """
    Return what a sensor ``samples`` late (``< 0``: early) reports of ``values``.

    The result has the length of ``values`` for any delay: the samples a delay reaches
    beyond the series repeat its first (late) or last (early) value.
    """
    n = len(values)
    if samples == 0 or n == 0:
        return values
    k = min(abs(int(samples)), n)
    if samples > 0:
        return np.concatenate([np.full(k, values[0]), values[:n - k]])
    return np.concatenate([values[k:], np.full(k, values[-1])])


def check_delays(model: Model, record: Record, init_samples: int = INIT_SAMPLES) -> None:
    """
    Refuse a ``sensor_delay`` the record cannot be validated with.

    Raises
    ------
    InputDataError
        A negative delay (a sensor ahead of the true signal: not causal, and not proposed by
        identify), or a delay (converted to the record's sample period) that leaves no
        scored sample after the ``init_samples`` initial ones.

    """
    for item in model.effects:
        if item['name'] != 'sensor_delay':
            continue
        samples = float((item.get('parameters') or {}).get('samples', 0))
        if samples < 0:
            raise InputDataError(
                f"{record.source}: the model's effect sensor_delay has samples={samples:g}: a "
                'sensor that reports the signal before it happens is not physical; remove '
                'that effect from the model file, or identify again (identify no longer '
                'proposes a negative delay)')
    _, delays = _effects_for(model, record.sample_period_s)
    for channel, samples in delays.items():
        if samples >= len(record) - init_samples:
            raise InputDataError(
                f"{record.source}: the model's effect sensor_delay delays the {channel} by "
                f'{samples} samples ({samples * record.sample_period_s:.4g} s), not less than '
                f'the {len(record) - init_samples} samples scored of this record of '
                f'{len(record)}; validate on a longer record, or remove or correct that '
                'effect in the model file')


def simulate(model: Model, record: Record,
             initial_state: Sequence[float] | np.ndarray) -> dict[str, np.ndarray]:
    """
    Simulate the model open loop over a record from an initial state.

    Parameters
    ----------
    model : Model
        The model.
    record : Record
        Supplies the input (voltage, or current in mechanical mode), the sample period and
        the first measured position (angle-dependent effects; the simulated position).
    initial_state : sequence of float
        ``(i0, w0)``, or ``(w0,)`` in mechanical mode.

    Returns
    -------
    dict
        ``speed`` (and ``current`` in full mode) as the sensors would report them, and
        ``position`` (integral of the simulated speed from the measured first position, or 0).

    """
    dt = record.sample_period_s
    effects, delays = _effects_for(model, dt)
    start_angle = float(record.position[0]) if record.position is not None else 0.0
    p = model.parameters
    out: dict[str, np.ndarray] = {}
    if model.mode == 'voltage_speed':
        lag = model.description.get('armature_lag')
        lag = None if not lag else (lag['time_constant_s'], lag['acceleration_gain'])
        voltage = np.asarray(record.voltage, dtype=float)
        drop = [float(value) for value in initial_state[1:2]]
        speed = (simulate_speed_effects(p, voltage, dt, float(initial_state[0]), lag,
                                        combine_effects(effects), *drop) if effects else
                 simulate_speed(p, voltage, dt, float(initial_state[0]), lag, *drop))
        speed = _shift(speed, delays.get('speed', 0))
        return {'speed': speed, 'position': start_angle + np.concatenate(
            [[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1])) * dt])}
    if model.mechanical_only:
        current = np.asarray(record.current, dtype=float)
        held = held_input(current)
        speed, angle = simulate_mechanical_effects(
            p['J'], p['b'], p['Mc'], float(model.torque_constant or 0.0) * held, dt, effects,
            float(initial_state[0]), oversample=OVERSAMPLE if effects else 1,
            initial_angle_rad=start_angle)
    else:
        params = MotorParameters.from_dict(dict(p))
        current, speed, angle = simulate_motor_effects(
            params, np.asarray(record.voltage, dtype=float), dt, effects,
            np.asarray(initial_state, dtype=float), oversample=OVERSAMPLE if effects else 1,
            initial_angle_rad=start_angle)
        out['current'] = _shift(current, delays.get('current', 0))
    out['speed'] = _shift(speed, delays.get('speed', 0))
    # the kernels integrate the speed exactly (the angle of angle-dependent effects)
    out['position'] = angle
    return out


def estimate_initial_state(model: Model, record: Record, samples: int = INIT_SAMPLES
                           ) -> np.ndarray:
    """
    Estimate the initial state from the first ``samples`` samples of a record.

    Least squares of the simulated against the measured outputs over those samples (each
    channel scaled by its spread over the record), started from a straight-line fit of each
    channel at the first sample; one sample gives the first measured values.
    """
    channels = list(model.outputs)
    n = int(max(1, min(samples, len(record))))
    measured = {channel: np.asarray(getattr(record, channel), dtype=float) for channel in
                channels}
    start = []
    for channel in channels:
        head = measured[channel][:n]
        if n >= 3:
            slope, intercept = np.polyfit(np.arange(n), head, 1)
            start.append(float(intercept))
        else:
            start.append(float(head[0]))
    if n < 3:
        return np.array(start)
    part = record.slice(0, n)
    scales = [max(float(np.std(measured[channel])), 1e-12) for channel in channels]
    if model.description.get('armature_lag') and model.mode == 'voltage_speed':
        # the lag's state too (its current times Ra [V]): a record may start on a step
        voltage = np.asarray(record.voltage, dtype=float)
        start.append(float(voltage[0]) - model.parameters['kV'] * start[0])
        scales.append(max(float(np.std(voltage)), 1e-12))

    def residual(state: np.ndarray) -> np.ndarray:
        simulated = simulate(model, part, state)
        return np.concatenate([(simulated[channel] - measured[channel][:n]) / scale
                               for channel, scale in zip(channels, scales[:len(channels)])])
    from scipy.optimize import least_squares  # lazily: identify imports this module too
    x_scale = np.array(scales)
    fitted = least_squares(residual, np.array(start), x_scale=x_scale, max_nfev=60)
    return np.asarray(fitted.x, dtype=float)


def _nrmse(measured: np.ndarray, simulated: np.ndarray) -> Optional[float]:
    spread = float(np.std(measured))
    if not np.isfinite(spread) or spread == 0:
        return None
    return float(100.0 * np.sqrt(np.mean((simulated - measured) ** 2)) / spread)


def _fit(measured: np.ndarray, simulated: np.ndarray) -> Optional[float]:
    """Fit percent as MATLAB's ``compare``: ``100 (1 - |y - y_sim| / |y - mean(y)|)``."""
    norm = float(np.linalg.norm(measured - np.mean(measured)))
    if not np.isfinite(norm) or norm == 0:
        return None
    return float(100.0 * (1.0 - np.linalg.norm(measured - simulated) / norm))


@dataclass
class RecordValidation:
    """
    The validation of one record: its scores and the series behind them (for the report).

    Attributes
    ----------
    scores : dict
        The JSON entry (``source``, ``samples``, ``current_nrmse_pct``, ``speed_nrmse_pct``,
        ``fit_pct``, ``position_rmse``).
    record : Record
        The record as validated (SI, motor shaft).
    simulated : dict
        Simulated channels.
    initial_state : numpy.ndarray
        The estimated initial state.
    init_samples : int
        Samples used for it (not scored).

    """

    scores: dict[str, Any]
    record: Record
    simulated: dict[str, np.ndarray]
    initial_state: np.ndarray
    init_samples: int


def time_constants(model: Model) -> dict[str, float]:
    """Return the model's electrical ``La/Ra`` and mechanical time constants [s]."""
    p = model.parameters
    if model.mode == 'voltage_speed':
        lag = model.description.get('armature_lag') or {}
        return {'mechanical': p['kA'] / p['kV'],
                **({'lag': lag['time_constant_s']} if lag else {})}
    if model.mechanical_only:
        return {'mechanical': p['J'] / p['b'] if p['b'] > 0 else float('inf')}
    damping = p['b'] + p['CPhi'] ** 2 / p['Ra']
    return {'electrical': p['La'] / p['Ra'], 'mechanical': p['J'] / damping}


def _simulate_checked(model: Model, record: Record, init_samples: int
                      ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Estimate the initial state and simulate; refuse a simulation that is not finite."""
    failure = ''
    with np.errstate(all='ignore'):
        try:
            state = estimate_initial_state(model, record, init_samples)
            simulated = simulate(model, record, state)
        except (ValueError, FloatingPointError, OverflowError, ZeroDivisionError) as error:
            failure = f' ({error})'
    if not failure and all(np.all(np.isfinite(values)) for values in simulated.values()):
        return state, simulated
    constants = ', '.join(f'{name} {value:.3g} s' for name, value in
                          time_constants(model).items())
    raise InputDataError(
        f'{record.source}: the model cannot be simulated on this record: the simulation is '
        f'not finite{failure}. Its time constants ({constants}) against the sample period '
        f'{record.sample_period_s:.3g} s and the record length '
        f'{float(record.time_s[-1] - record.time_s[0]):.3g} s: '
        'check the model file (parameters as identify --json wrote them, SI units) and the '
        'time column of the record (seconds)')


def _check_channels(model: Model, record: Record) -> None:
    """Refuse a record without the input of the model, or (full model) without its current."""
    if not model.mechanical_only and record.voltage is None:
        raise InputDataError(f'{record.source}: no voltage column: the model ({model.mode}) '
                             'takes the voltage as its input')
    if model.mode == 'full' and record.current is None:
        raise InputDataError(f'{record.source}: no current column: the model (mode full) is '
                             'scored on the current and the speed; validate it on records with '
                             'the current, or identify records of voltage and speed alone for '
                             'the voltage-to-speed model (kS, kV, kA) and validate that')


def validate_record(model: Model, record: Record, init_samples: int = INIT_SAMPLES,
                    position_scale: float = 1.0) -> RecordValidation:
    """
    Simulate a record open loop and score it (see the module's description).

    Parameters
    ----------
    model : Model
        The model.
    record : Record
        A checked record (SI, uniformly sampled, with speed).
    init_samples : int
        Samples at the start used for the initial state and not scored.
    position_scale : float
        Factor from the file's position unit to the record's (``position_rmse`` is reported
        in the file's unit).

    """
    if init_samples < 1:
        raise InputDataError(f'--init-samples must be at least 1, got {init_samples}')
    if len(record) <= init_samples + 1:
        raise InputDataError(f'{record.source}: {len(record)} samples, not more than the '
                             f'{init_samples} initial samples; give a longer record or a '
                             'smaller --init-samples')
    _check_channels(model, record)
    check_delays(model, record, init_samples)
    state, simulated = _simulate_checked(model, record, init_samples)
    scored = slice(init_samples, None)
    channels = [('current', record.current if 'current' in model.outputs else None),
                ('speed', record.speed),
                ('position', record.position)]
    fits: dict[str, Optional[float]] = {}
    nrmse: dict[str, Optional[float]] = {}
    for channel, measured in channels:
        if measured is None:
            fits[channel], nrmse[channel] = None, None
            continue
        values = np.asarray(measured, dtype=float)[scored]
        sim = simulated[channel][scored]
        fits[channel] = _fit(values, sim)
        nrmse[channel] = _nrmse(values, sim)
    position_rmse = None
    if record.position is not None:
        error = simulated['position'][scored] - np.asarray(record.position, dtype=float)[scored]
        position_rmse = float(np.sqrt(np.mean(error ** 2))) / position_scale
    scores = {
        'source': record.source,
        'samples': len(record),
        'current_nrmse_pct': nrmse['current'],
        'speed_nrmse_pct': nrmse['speed'],
        'fit_pct': fits,
        'position_rmse': position_rmse,
    }
    return RecordValidation(scores, record, simulated, state, init_samples)


@dataclass
class Validation:
    """The validation of a model on records: :meth:`as_dict` is the JSON contract."""

    records: list[RecordValidation]
    model: Model
    warnings: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """Return ``{"records": [...], "model": {...}}`` (plus ``warnings`` when any)."""
        out: dict[str, Any] = {'records': [item.scores for item in self.records],
                               'model': dict(self.model.description)}
        if self.warnings:
            out['warnings'] = list(self.warnings)
        return out


def validate(model: Model, records: Sequence[Record], init_samples: int = INIT_SAMPLES,
             position_scale: float = 1.0) -> Validation:
    """Validate a model on every record (each scored on its own); see :func:`validate_record`."""
    notes = []
    for record in records:
        if model.sample_period_s and abs(record.sample_period_s / model.sample_period_s - 1) \
                > 1e-3:
            notes.append(f'{record.source}: sampled every {record.sample_period_s:.6g} s, the '
                         f'model was identified at {model.sample_period_s:.6g} s (the model is '
                         'continuous-time; delays are converted to this period)')
        notes += range_warnings(model.description.get('operating_range'), record)
    validated = [validate_record(model, record, init_samples, position_scale)
                 for record in records]
    for item in validated:
        notes += reversed_warnings(item, model.mechanical_only, model.mode == 'voltage_speed')
    return Validation(validated, model, notes)


#: A channel whose negation fits this much better (NRMSE ratio) looks reversed.
REVERSED_RATIO = 0.5


def reversed_warnings(item: RecordValidation, mechanical_only: bool,
                      voltage_speed: bool = False) -> list[str]:
    """
    Say when a record's outputs match the model with their sign flipped (a reversed channel).

    The model's simulation against the measured channel and against its negation: a channel
    that matches only negated (NRMSE below :data:`REVERSED_RATIO` of the direct one and below
    50 %) was recorded with the other sign (an encoder counting the other way).  Every output
    reversed at once is the input reversed.
    """
    record, scored = item.record, slice(item.init_samples, None)
    flipped = []
    for channel in ('current', 'speed', 'position'):
        measured = None if channel not in item.simulated else getattr(record, channel)
        if measured is None:
            continue
        values = np.asarray(measured, dtype=float)[scored]
        simulated = item.simulated[channel][scored]
        direct, negated = _nrmse(values, simulated), _nrmse(-values, simulated)
        if direct is not None and negated is not None and negated < 50.0 and \
                negated < REVERSED_RATIO * direct:
            flipped.append((channel, direct, negated))
    if not flipped:
        return []
    names = {name for name, _, _ in flipped}
    if mechanical_only or voltage_speed:
        culprit, option = (f'speed (or the {"voltage" if voltage_speed else "current"}, the '
                           'input: they cannot be told apart)'), flipped[0][0]
    elif {'current', 'speed'} <= names:
        culprit, option = 'voltage (the input: every output is reversed)', 'voltage'
    else:
        culprit = option = flipped[0][0]
    seen = '; '.join(f'{name} NRMSE {direct:.3g} % as recorded, {negated:.3g} % negated'
                     for name, direct, negated in flipped)
    return [f'{record.source}: the model matches this record with its sign flipped ({seen}): '
            f'the {culprit} looks reversed (an encoder counting the other way, a sensor '
            f'mounted reversed); give --negate {option}']


def format_validation(result: Mapping[str, Any]) -> str:
    """Return the stdout table of a validation (one row per record)."""
    def pct(value: Optional[float]) -> str:
        return '-' if value is None else f'{value:.2f}'

    def num(value: Optional[float]) -> str:
        return '-' if value is None else f'{value:.4g}'
    header = (f"{'record':<32} {'samples':>8} {'NRMSE i %':>10} {'NRMSE w %':>10} "
              f"{'fit i %':>8} {'fit w %':>8} {'fit pos %':>9} {'pos RMSE':>10}")
    lines = [header, '-' * len(header)]
    for item in result['records']:
        source = os.path.basename(str(item['source'])) or str(item['source'])
        fits = item['fit_pct']
        lines.append(f'{source[-32:]:<32} {item["samples"]:>8} '
                     f'{pct(item["current_nrmse_pct"]):>10} {pct(item["speed_nrmse_pct"]):>10} '
                     f'{pct(fits["current"]):>8} {pct(fits["speed"]):>8} '
                     f'{pct(fits["position"]):>9} {num(item["position_rmse"]):>10}')
    for note in result.get('warnings', []):
        lines.append(f'note: {note}')
    return '\n'.join(lines)
