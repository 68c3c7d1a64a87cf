"""
Experiment design: the PRBS or multisine band and amplitude that tell the most, within limits.

Given prior parameters (a datasheet, a paper motor or the last result JSON), the sensor noise
and the drive's limits, :func:`design_experiment` tries PRBS clocks and multisine bands
scaled to the prior's mechanical and electrical corner frequencies.  For each band it takes
the largest amplitude (a descending grid below the voltage limit) whose simulated response
(:func:`dcmotor_id.simulation.simulate_motor`, the exact model with Coulomb friction, the
command profile of :func:`dcmotor_id.design.routines.command_profile` with its ramp-in held at the
drive's sample period) keeps the current and speed within ``margin`` times their limits,
and scores it by the D-criterion: the log-determinant of the Fisher information
(:func:`dcmotor_id.identification.estimators.fisher.fisher_information`) of the parameters asked
for, the
initial states and the other parameters marginalised out (Schur complement), in relative
units.  The best candidate is the plan; its Cramer-Rao bounds are the expected standard
errors of an efficient estimator (the refined method reaches them, bench/experiment_results.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import (derived_stderr, MotorParameters, PAPER_MOTORS, PARAMETER_NAMES,
                                   UNITS)
from dcmotor_id.core.records import Record
from dcmotor_id.design.routines import command_profile, hold, Limits, Routine
from dcmotor_id.formats.json_file import load_json
from dcmotor_id.identification.estimators.fisher import fisher_information
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.simulation import simulate_motor

#: Routine kinds the design chooses between.
DESIGN_KINDS = ('prbs', 'multisine')
#: Sensor noise of ``sim_motor``'s defaults (config/sim_motor.yaml) [A, rad/s].
DEFAULT_NOISE = {'current': 0.01, 'speed': 0.02}
#: Amplitudes tried per band, as fractions of the voltage limit (largest first).
AMPLITUDE_FRACTIONS = tuple(float(value) for value in np.geomspace(1.0, 0.05, 14))


@dataclass
class Plan:
    """
    An experiment plan: the routine, the expected standard errors and how it was chosen.

    Attributes
    ----------
    routine : Routine
        The routine to drive.
    expected_stderr : dict
        Cramer-Rao bound per parameter (Ra, La, CPhi, J, b, Mc, Ka, Ta) [SI units].
    criterion : float
        D-criterion of the routine (log-determinant of the relative information of the
        parameters asked for; larger is better).
    peak_current_a, peak_speed_rad_s : float
        Peaks of the simulated response [A, rad/s].
    prior : dict
        The prior parameters.
    noise_std : dict
        Sensor noise assumed, per channel.
    limits : Limits
        The drive's limits.
    parameters : list of str
        The parameters the design maximises the information of.
    rate_hz, ramp_in_s, sample_period_s : float
        Command rate, ramp-in and drive sample period assumed.
    candidates : list of dict
        Every band tried: routine, amplitude, peaks, criterion or why rejected.

    """

    routine: Routine
    expected_stderr: dict[str, float]
    criterion: float
    peak_current_a: float
    peak_speed_rad_s: float
    prior: dict[str, float]
    noise_std: dict[str, float]
    limits: Limits
    parameters: list[str]
    rate_hz: float
    ramp_in_s: float
    sample_period_s: float
    candidates: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """Return the plan as JSON-ready data (the exciter reads ``routine`` from it)."""
        return {
            'routine': self.routine.as_dict(),
            'expected_stderr': self.expected_stderr,
            'expected_rel_stderr_pct': {
                name: 100.0 * value / abs(self.prior[name])
                for name, value in self.expected_stderr.items() if self.prior.get(name)},
            'criterion': self.criterion,
            'peak_current_a': self.peak_current_a,
            'peak_speed_rad_s': self.peak_speed_rad_s,
            'prior': self.prior,
            'noise_std': self.noise_std,
            'limits': {'voltage_v': self.limits.voltage_v, 'current_a': self.limits.current_a,
                       'speed_rad_s': self.limits.speed_rad_s},
            'parameters': self.parameters,
            'rate_hz': self.rate_hz,
            'ramp_in_s': self.ramp_in_s,
            'sample_period_s': self.sample_period_s,
            'candidates': self.candidates,
        }

    def describe(self) -> str:
        """Return the plan and its expected standard errors as text."""
        lines = [f'plan: {self.routine.describe()} (ramp-in {self.ramp_in_s:g} s, commands at '
                 f'{self.rate_hz:g} Hz)',
                 f'simulated peaks: current {self.peak_current_a:.4g} A (limit '
                 f'{self.limits.current_a:g}), speed {self.peak_speed_rad_s:.4g} rad/s (limit '
                 f'{self.limits.speed_rad_s:g}); voltage limit {self.limits.voltage_v:g} V',
                 f'noise assumed: current {self.noise_std["current"]:g} A, speed '
                 f'{self.noise_std["speed"]:g} rad/s; D-optimal for '
                 f'{", ".join(self.parameters)}',
                 f'{"":<6}{"prior":>12}{"expected stderr":>17}{"rel %":>9}']
        for name, value in self.expected_stderr.items():
            prior = self.prior.get(name, float('nan'))
            rel = 100.0 * value / abs(prior) if prior else float('nan')
            lines.append(f'{name:<6}{prior:>12.5g}{value:>17.3g}{rel:>9.3g}  {UNITS[name]}')
        lines.append('candidates:')
        for item in self.candidates:
            verdict = f'D = {item["criterion"]:.2f}' if item.get('criterion') is not None \
                else item.get('rejected', '')
            lines.append(f'  {item["description"]:<52} {verdict}')
        return '\n'.join(lines)


def load_prior(source: str) -> tuple[MotorParameters, Optional[dict[str, float]]]:
    """
    Read prior parameters and, when present, the noise: a paper motor, a result or datasheet.

    Parameters
    ----------
    source : str
        ``paper1`` / ``paper2``, or a JSON or YAML file holding ``Ra, La, CPhi, J, b, Mc``
        at the top level (a datasheet) or under ``parameters`` (a ``dcmotor-id identify``
        result, whose ``noise_std`` is used too).

    Returns
    -------
    prior : MotorParameters
        The parameters.
    noise_std : dict or None
        ``{'current', 'speed'}`` noise of a result file, else None.

    """
    if source in PAPER_MOTORS:
        return PAPER_MOTORS[source], None
    if not os.path.isfile(source):
        raise InputDataError(f'prior {source!r}: neither a file nor one of '
                             f'{", ".join(PAPER_MOTORS)}')
    import yaml
    try:
        with open(source, encoding='utf-8') as stream:
            data = yaml.safe_load(stream) if source.endswith(('.yaml', '.yml')) else \
                load_json(stream)
    except yaml.constructor.ConstructorError as error:
        raise InputDataError(f'prior {source}: not plain YAML ({error.problem}); give plain '
                             'values, without !! tags') from None
    except (ValueError, UnicodeDecodeError, yaml.YAMLError, RecursionError) as error:
        raise InputDataError(f'prior {source}: cannot be read: {error}') from None
    if not isinstance(data, dict):
        raise InputDataError(f'prior {source}: expected a mapping of parameters')
    values = data.get('parameters', data)
    try:
        prior = MotorParameters.from_dict(values)
    except (KeyError, TypeError, ValueError) as error:
        raise InputDataError(f'prior {source}: {error}') from None
    if min(prior.Ra, prior.La, prior.CPhi, prior.J) <= 0 or min(prior.b, prior.Mc) < 0:
        raise InputDataError(f'prior {source}: parameters are not physical ({prior})')
    noise = data.get('noise_std') if 'parameters' in data else None
    if isinstance(noise, dict) and all(isinstance(noise.get(key), (int, float)) and
                                       noise[key] > 0 for key in ('current', 'speed')):
        return prior, {key: float(noise[key]) for key in ('current', 'speed')}
    return prior, None


def planned_record(routine: Routine, prior: MotorParameters, rate_hz: float, ramp_in_s: float,
                   sample_period_s: float) -> Record:
    """Simulate the routine's command profile, held at the drive's sample period, noise-free."""
    _, profile = command_profile(routine, rate_hz, ramp_in_s)
    voltage = hold(profile, rate_hz, sample_period_s)
    current, speed = simulate_motor(prior, voltage, sample_period_s)
    t = np.arange(len(voltage)) * sample_period_s
    return Record(t, current=current, voltage=voltage, speed=speed, source=routine.describe())


def expected_stderr(record: Record, prior: MotorParameters, noise_std: Mapping[str, float],
                    parameters: Sequence[str] = PARAMETER_NAMES) -> tuple[dict[str, float],
                                                                          float]:
    """
    Return the Cramer-Rao bounds of a noise-free record and its D-criterion.

    Parameters
    ----------
    record : Record
        The planned experiment, simulated at the prior without noise.
    prior : MotorParameters
        The parameters the bound is evaluated at.
    noise_std : dict
        White-noise standard deviation per channel (``current`` [A], ``speed`` [rad/s]).
    parameters : sequence of str
        Parameters of interest of the D-criterion.

    Returns
    -------
    stderr : dict
        Bound per parameter and for Ka, Ta (initial states are nuisance parameters).
    criterion : float
        ``-log det`` of the relative covariance of ``parameters`` (larger is better).

    """
    values = prior.as_dict(derived=False)
    model = OutputErrorModel([record])
    names, information = fisher_information(model, values, [np.zeros(2)], dict(noise_std))
    diagonal = np.sqrt(np.diag(information))
    if np.any(diagonal <= 0) or not np.all(np.isfinite(diagonal)):
        raise ValueError('the Fisher information is singular for this routine')
    scaled = information / np.outer(diagonal, diagonal)
    covariance = np.linalg.pinv(scaled) / np.outer(diagonal, diagonal)
    base = list(PARAMETER_NAMES)
    stderr = {name: float(np.sqrt(max(covariance[i, i], 0.0))) for i, name in enumerate(base)}
    stderr.update(derived_stderr(values, covariance[:len(base), :len(base)], base))
    index = [names.index(name) for name in parameters]
    theta = np.array([values[name] for name in parameters])
    relative = covariance[np.ix_(index, index)] / np.outer(theta, theta)
    sign, logdet = np.linalg.slogdet(relative)
    criterion = -float(logdet) if sign > 0 else float('-inf')
    return stderr, criterion


def corner_frequencies(prior: MotorParameters) -> tuple[float, float]:
    """Return the mechanical and electrical corner frequencies of the prior [Hz]."""
    mechanical = (prior.b + prior.CPhi ** 2 / prior.Ra) / prior.J / (2 * np.pi)
    electrical = prior.Ra / prior.La / (2 * np.pi)
    return float(mechanical), float(electrical)


def candidate_bands(prior: MotorParameters, rate_hz: float,
                    kinds: Sequence[str] = DESIGN_KINDS) -> list[tuple[str, float, float]]:
    """Return ``(kind, frequency_hz, max_frequency_hz)`` candidates around the prior's corners."""
    corners = corner_frequencies(prior)
    bottom = 0.5 * min(corners)
    top = max(min(4.0 * max(corners), 0.4 * rate_hz), 4.0 * bottom)
    bands: list[tuple[str, float, float]] = []
    if 'prbs' in kinds:
        for clock in np.geomspace(bottom, top, 7):
            # a PRBS holds each bit at least one command: round the clock to the command grid
            hold_commands = max(1, int(round(rate_hz / clock)))
            bands.append(('prbs', float(rate_hz / hold_commands), 0.0))
    if 'multisine' in kinds:
        for low in (0.1 * bottom, 0.5 * bottom):
            for high in np.geomspace(4.0 * bottom, top, 3):
                bands.append(('multisine', float(low), float(high)))
    unique = []
    for band in bands:
        if band not in unique:
            unique.append(band)
    return unique


def design_experiment(prior: MotorParameters, limits: Limits,
                      noise_std: Optional[Mapping[str, float]] = None,
                      duration_s: float = 10.0, kinds: Sequence[str] = DESIGN_KINDS,
                      parameters: Sequence[str] = PARAMETER_NAMES, rate_hz: float = 200.0,
                      ramp_in_s: float = 1.0, sample_period_s: float = 1e-3,
                      margin: float = 0.9, seed: int = 0) -> Plan:
    """
    Choose the PRBS / multisine band and amplitude of largest information within the limits.

    Parameters
    ----------
    prior : MotorParameters
        Prior parameters (datasheet, last result).
    limits : Limits
        The drive's voltage, current and speed limits.
    noise_std : dict, optional
        Sensor noise per channel; default :data:`DEFAULT_NOISE` (sim_motor's).
    duration_s : float
        Length of the routine, ramp-in included [s].
    kinds : sequence of str
        Routine kinds to choose between (``prbs``, ``multisine``).
    parameters : sequence of str
        Parameters whose joint information is maximised (D-optimal).
    rate_hz : float
        Command rate of the exciter [Hz].
    ramp_in_s : float
        Ramp-in of the exciter [s].
    sample_period_s : float
        Sample period of the drive's measurements [s].
    margin : float
        Fraction of the current and speed limits the simulated response may reach.
    seed : int
        PRBS seed.

    Returns
    -------
    Plan
        The best routine and its expected standard errors.

    Raises
    ------
    ValueError
        When no candidate stays within the limits, or an argument is out of range.

    """
    _check_request(kinds, parameters, margin)
    noise = dict(DEFAULT_NOISE if noise_std is None else noise_std)
    trials = _Trials(prior, limits, duration_s, rate_hz, ramp_in_s, sample_period_s, margin, seed)
    best, candidates = _best_band(trials, candidate_bands(prior, rate_hz, kinds), noise,
                                  parameters)
    if best is None:
        raise ValueError('no PRBS or multisine keeps the current and speed within '
                         f'{margin:g} of their limits: raise the limits or check the prior')
    criterion, routine, stderr, peak_i, peak_w = best
    return Plan(routine=routine, expected_stderr=stderr, criterion=criterion,
                peak_current_a=peak_i, peak_speed_rad_s=peak_w,
                prior=prior.as_dict(), noise_std=noise, limits=limits,
                parameters=list(parameters), rate_hz=rate_hz, ramp_in_s=ramp_in_s,
                sample_period_s=sample_period_s, candidates=candidates)


def _check_request(kinds: Sequence[str], parameters: Sequence[str], margin: float) -> None:
    """Raise ValueError for unknown kinds or parameters, or a margin outside (0, 1]."""
    unknown = [kind for kind in kinds if kind not in DESIGN_KINDS]
    if unknown or not kinds:
        raise ValueError(f'design kinds must be among {", ".join(DESIGN_KINDS)}')
    bad = [name for name in parameters if name not in PARAMETER_NAMES]
    if bad or not parameters:
        raise ValueError(f'parameters must be among {", ".join(PARAMETER_NAMES)}')
    if not 0 < margin <= 1:
        raise ValueError('margin must be in (0, 1]')


#: A band's best routine: (criterion, routine, expected stderr, peak current, peak speed).
_Scored = tuple[float, Routine, dict[str, float], float, float]
#: One simulated trial: (within the limits, routine, record, peaks).
_Trial = tuple[bool, Routine, Record, dict[str, Any]]


@dataclass(frozen=True)
class _Trials:
    """What every trial of a band shares: the prior, the limits and the exciter's settings."""

    prior: MotorParameters
    limits: Limits
    duration_s: float
    rate_hz: float
    ramp_in_s: float
    sample_period_s: float
    margin: float
    seed: int

    def run(self, kind: str, low: float, high: float, amplitude: float) -> _Trial:
        """Simulate a routine of the band at ``amplitude``; say whether it stays in limits."""
        routine = Routine(kind=kind, amplitude_v=amplitude, duration_s=self.duration_s,
                          frequency_hz=low, max_frequency_hz=high, seed=self.seed)
        record = planned_record(routine, self.prior, self.rate_hz, self.ramp_in_s,
                                self.sample_period_s)
        assert record.current is not None and record.speed is not None
        peak_i = float(np.max(np.abs(record.current)))
        peak_w = float(np.max(np.abs(record.speed)))
        ok = (peak_i <= self.margin * self.limits.current_a
              and peak_w <= self.margin * self.limits.speed_rad_s)
        return ok, routine, record, {'peak_current_a': peak_i, 'peak_speed_rad_s': peak_w}

    def largest(self, kind: str, low: float, high: float) -> _Trial:
        """Return the trial of the largest amplitude within the limits (grid, bisection)."""
        voltage = self.limits.voltage_v
        above = None
        for fraction in AMPLITUDE_FRACTIONS:
            ok, routine, record, peaks = self.run(kind, low, high, fraction * voltage)
            if ok:
                break
            above = fraction * voltage
        if ok and above is not None:
            below = routine.amplitude_v
            for _ in range(6):
                middle = 0.5 * (below + above)
                good = self.run(kind, low, high, middle)
                if good[0]:
                    below, (ok, routine, record, peaks) = middle, good
                else:
                    above = middle
        return ok, routine, record, peaks


def _best_band(trials: _Trials, bands: Sequence[tuple[str, float, float]],
               noise: Mapping[str, float],
               parameters: Sequence[str]) -> tuple[Optional[_Scored], list[dict[str, Any]]]:
    """Return the most informative band's routine (None: none fits) and every candidate."""
    best: Optional[_Scored] = None
    candidates = []
    for kind, low, high in bands:
        ok, routine, record, peaks = trials.largest(kind, low, high)
        entry: dict[str, Any] = {'description': routine.describe(),
                                 'routine': routine.as_dict(), **peaks}
        if not ok:
            entry['rejected'] = 'beyond the limits at every amplitude'
        if 'rejected' in entry:
            candidates.append(entry)
            continue
        try:
            stderr, criterion = expected_stderr(record, trials.prior, noise, parameters)
        except (ValueError, np.linalg.LinAlgError) as error:
            entry['rejected'] = f'not informative: {error}'
            candidates.append(entry)
            continue
        entry['criterion'] = criterion
        entry['expected_stderr'] = stderr
        candidates.append(entry)
        if best is None or criterion > best[0]:
            best = (criterion, routine, stderr, peaks['peak_current_a'],
                    peaks['peak_speed_rad_s'])
    return best, candidates


def read_plan(path: str) -> dict[str, Any]:
    """Read a plan JSON written by ``dcmotor-id plan --json``; check it holds a routine."""
    with open(path, encoding='utf-8') as stream:
        data = load_json(stream)
    if not isinstance(data, dict) or not isinstance(data.get('routine'), dict):
        raise InputDataError(f'{path}: not a plan (no "routine")')
    Routine.from_dict(data['routine'])
    return data
