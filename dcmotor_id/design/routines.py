"""
Excitation routines for a real drive and the safety state machine that runs them (no ROS).

A :class:`Routine` describes what the ``exciter`` node drives: ``quasistatic`` (a slow voltage
ramp from 0 to the amplitude, WPILib SysId's quasistatic test), ``dynamic`` (a voltage step to
the amplitude, or steps between 0 and the amplitude at ``frequency_hz``), ``prbs``,
``multisine`` and ``chirp`` (the generators of :mod:`dcmotor_id.simulation.excitation`), each
``forward`` or ``backward`` (the voltage negated).  :func:`command_profile` is the voltage
published at the command rate, with the ramp-in applied: the experiment design
(:mod:`dcmotor_id.design.experiment`) simulates exactly this profile.

:class:`ExcitationSession` is the node's logic: it starts a routine only with fresh
measurements and within the limits, commands the ramped-in profile, and drops to 0 V with a
state saying why when a measured current, speed or voltage exceeds its limit, when the
measurements go stale, when it is stopped, or when the routine is done.  Times are seconds of
any monotonic clock.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from dcmotor_id.simulation.excitation import make_excitation

#: Routine kinds.
ROUTINES = ('quasistatic', 'dynamic', 'prbs', 'multisine', 'chirp')
#: Directions: ``backward`` negates the voltage.
DIRECTIONS = ('forward', 'backward')
#: States of a session, as reported on ``/diagnostics``.
STATES = ('idle', 'ramping-in', 'running', 'stopped', 'stopped-by-limit', 'stale', 'done')
#: Measured channels a session can watch.
CHANNELS = ('current', 'speed', 'voltage')
#: States in which the session drives the motor.
ACTIVE_STATES = ('ramping-in', 'running')


@dataclass(frozen=True)
class Limits:
    """
    Hard limits of a drive; beyond any of them the excitation stops at 0 V.

    Attributes
    ----------
    voltage_v : float
        Largest armature voltage commanded or measured [V].
    current_a : float
        Largest measured armature current [A].
    speed_rad_s : float
        Largest measured shaft speed [rad/s].

    """

    voltage_v: float = 48.0
    current_a: float = 10.0
    speed_rad_s: float = 100.0

    def __post_init__(self) -> None:
        """Refuse limits that are not positive numbers."""
        for item in fields(self):
            value = getattr(self, item.name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f'limit {item.name} must be positive, got {value}')


@dataclass(frozen=True)
class Routine:
    """
    One excitation routine.

    Attributes
    ----------
    kind : str
        One of :data:`ROUTINES`.
    amplitude_v : float
        Peak voltage of the routine (ramp end, step height, PRBS level, multisine peak) [V].
    duration_s : float
        Length of the routine, ramp-in included [s].
    direction : str
        ``forward`` or ``backward`` (negated voltage).
    frequency_hz : float
        PRBS clock, lower edge of the multisine / chirp band, step frequency of ``dynamic``
        (0: a single step); 0 takes the generator's default [Hz].
    max_frequency_hz : float
        Upper edge of the multisine / chirp band; 0 takes the generator's default [Hz].
    offset_v : float
        Constant added before the direction is applied [V].
    seed : int
        Seed of the PRBS.

    """

    kind: str = 'prbs'
    amplitude_v: float = 12.0
    duration_s: float = 10.0
    direction: str = 'forward'
    frequency_hz: float = 0.0
    max_frequency_hz: float = 0.0
    offset_v: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        """Check the kind, direction and ranges."""
        if self.kind not in ROUTINES:
            raise ValueError(f'routine {self.kind!r}: choose one of {", ".join(ROUTINES)}')
        if self.direction not in DIRECTIONS:
            raise ValueError(f'direction {self.direction!r}: choose forward or backward')
        if not (np.isfinite(self.duration_s) and self.duration_s > 0):
            raise ValueError(f'duration_s must be positive, got {self.duration_s}')
        if not (np.isfinite(self.amplitude_v) and self.amplitude_v >= 0):
            raise ValueError(f'amplitude_v must be zero or positive, got {self.amplitude_v}')
        if self.frequency_hz < 0 or self.max_frequency_hz < 0:
            raise ValueError('frequencies must be zero (default) or positive')

    def as_dict(self) -> dict[str, Any]:
        """Return the routine as plain data (the plan's JSON layout)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> Routine:
        """Build from a mapping of the fields (others ignored)."""
        names = {item.name for item in fields(cls)}
        return cls(**{key: value for key, value in values.items() if key in names})

    def replace(self, **changes: Any) -> Routine:
        """Return a copy with some fields changed."""
        return replace(self, **changes)

    def describe(self) -> str:
        """Return a one-line description."""
        band = ''
        if self.kind == 'prbs':
            band = f', clock {self.frequency_hz or 20.0:.4g} Hz'
        elif self.kind in ('multisine', 'chirp'):
            band = (f', band {self.frequency_hz or 0.2:.3g}-'
                    f'{self.max_frequency_hz or 20.0:.3g} Hz')
        elif self.kind == 'dynamic' and self.frequency_hz > 0:
            band = f', steps at {self.frequency_hz:g} Hz'
        return (f'{self.kind} {self.direction}, {self.amplitude_v:.4g} V{band}, '
                f'{self.duration_s:g} s')


def routine_voltage(routine: Routine, sample_period_s: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the routine's voltage at ``t_k = k dt`` without the ramp-in.

    Parameters
    ----------
    routine : Routine
        The routine.
    sample_period_s : float
        The command period [s].

    Returns
    -------
    t, voltage : numpy.ndarray
        Times [s] and voltage [V].

    """
    duration = routine.duration_s
    amplitude = routine.amplitude_v
    if routine.kind == 'quasistatic':
        t, _ = make_excitation('sine', duration, sample_period_s, amplitude_v=0.0)
        voltage = amplitude * t / duration
    elif routine.kind == 'dynamic':
        t, _ = make_excitation('sine', duration, sample_period_s, amplitude_v=0.0)
        if routine.frequency_hz > 0:
            voltage = amplitude * (np.floor(2.0 * routine.frequency_hz * t) % 2 == 0)
        else:
            voltage = np.full(t.shape, amplitude)
    else:
        t, voltage = make_excitation(routine.kind, duration, sample_period_s,
                                     amplitude_v=amplitude,
                                     frequency_hz=routine.frequency_hz or None,
                                     seed=routine.seed,
                                     max_frequency_hz=routine.max_frequency_hz or None)
    voltage = voltage + routine.offset_v
    sign = -1.0 if routine.direction == 'backward' else 1.0
    return t, sign * voltage


def ramp_in_gain(t: ArrayLike, ramp_in_s: float) -> np.ndarray:
    """Return the ramp-in factor, rising linearly from 0 at ``t = 0`` to 1 at ``ramp_in_s``."""
    t = np.asarray(t, dtype=float)
    if ramp_in_s <= 0:
        return np.ones_like(t)
    return np.clip(t / ramp_in_s, 0.0, 1.0)


def command_profile(routine: Routine, rate_hz: float,
                    ramp_in_s: float) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the voltage commands of a routine at ``rate_hz``, ramp-in applied.

    Command ``k`` is published at ``k / rate_hz`` after the start and held until the next.
    """
    t, voltage = routine_voltage(routine, 1.0 / rate_hz)
    return t, voltage * ramp_in_gain(t, ramp_in_s)


def hold(profile: ArrayLike, rate_hz: float, sample_period_s: float,
         n_samples: Optional[int] = None) -> np.ndarray:
    """Return the commands held at a drive's sample period (what a drive applies, ZOH)."""
    profile = np.asarray(profile, dtype=float)
    if n_samples is None:
        n_samples = int(round(len(profile) / rate_hz / sample_period_s))
    index = np.floor(np.arange(n_samples) * sample_period_s * rate_hz + 1e-9).astype(int)
    return profile[np.minimum(index, len(profile) - 1)]


class ExcitationSession:
    """
    Run routines safely: the state machine of the ``exciter`` node (see the module docstring).

    Parameters
    ----------
    limits : Limits
        Hard limits on the voltage, the measured current and speed.
    rate_hz : float
        Command rate [Hz].
    ramp_in_s : float
        Ramp-in time at the start of a routine [s].
    stale_timeout_s : float
        Stop when no measurement arrived for this long [s].
    watch : sequence of str
        Channels (of :data:`CHANNELS`) that must each stay fresh and finite: the routine
        stops at 0 V as soon as one of them has no finite sample for ``stale_timeout_s`` or
        its latest sample is NaN or infinite. Empty: any :meth:`observe` call counts.

    """

    def __init__(self, limits: Limits, rate_hz: float = 200.0, ramp_in_s: float = 1.0,
                 stale_timeout_s: float = 0.5, watch: Sequence[str] = ()) -> None:
        if rate_hz <= 0 or stale_timeout_s <= 0 or ramp_in_s < 0:
            raise ValueError('rate_hz and stale_timeout_s must be positive, ramp_in_s >= 0')
        unknown = set(watch) - set(CHANNELS)
        if unknown:
            raise ValueError(f'cannot watch {sorted(unknown)}: choose from {", ".join(CHANNELS)}')
        self.limits = limits
        self.rate_hz = float(rate_hz)
        self.ramp_in_s = float(ramp_in_s)
        self.stale_timeout_s = float(stale_timeout_s)
        self.watch = tuple(watch)
        self.state = 'idle'
        self.reason = ''
        self.routine: Optional[Routine] = None
        self.profile = np.zeros(0)
        self.started_s: Optional[float] = None
        self.last_sample_s: Optional[float] = None
        #: Time of the latest finite sample of each channel [s].
        self.last_seen: dict[str, float] = {}
        #: Channels whose latest sample was NaN or infinite.
        self.not_finite: set[str] = set()
        self.last_command_v = 0.0
        self.progress = 0.0
        self.peaks = {'current': 0.0, 'speed': 0.0, 'voltage': 0.0}

    @property
    def active(self) -> bool:
        """Whether a routine is driving the motor."""
        return self.state in ACTIVE_STATES

    def fresh(self, now_s: float) -> bool:
        """Whether every watched channel has a finite sample within the stale timeout."""
        return self.stale_reason(now_s) is None

    def stale_reason(self, now_s: float) -> Optional[str]:
        """Say which watched channel is stale or not finite, and since when; None if none."""
        timeout = self.stale_timeout_s
        if not self.watch:
            if self.last_sample_s is None:
                return f'no measurement within {timeout:g} s'
            age = now_s - self.last_sample_s
            return f'no measurement for {age:.3g} s (timeout {timeout:g} s)' \
                if age > timeout else None
        for channel in self.watch:
            if channel in self.not_finite:
                return f'{channel} is not finite (NaN or inf)'
            seen = self.last_seen.get(channel)
            if seen is None:
                return f'no measurement on {channel} within {timeout:g} s'
            if now_s - seen > timeout:
                return (f'no measurement on {channel} for {now_s - seen:.3g} s '
                        f'(timeout {timeout:g} s)')
        return None

    def profile_of(self, routine: Routine) -> np.ndarray:
        """
        Return the commands of a routine at the session's rate, ramp-in applied [V].

        It can take a while (the first PRBS imports scipy.signal: seconds on a busy machine):
        a node computes it before it takes the time of :meth:`start` and passes it there.
        """
        return command_profile(routine, self.rate_hz, self.ramp_in_s)[1]

    def start(self, routine: Routine, now_s: float,
              profile: Optional[ArrayLike] = None) -> tuple[bool, str]:
        """
        Start a routine at ``now_s``; return whether it started and a message.

        Refused while a routine runs, without fresh measurements, or when the routine's peak
        voltage exceeds the voltage limit.  ``profile``: the routine's :meth:`profile_of`,
        computed beforehand (else here), so that ``now_s`` is the time the routine starts.
        """
        if self.active:
            running = self.routine.describe() if self.routine else ''
            return False, f'a routine is running ({running})'
        stale = self.stale_reason(now_s)
        if stale is not None:
            return False, (f'{stale}: not driving blind (check the current/speed or samples '
                           'topics)')
        profile = self.profile_of(routine) if profile is None else \
            np.asarray(profile, dtype=float)
        if not np.all(np.isfinite(profile)):
            return False, (f'the routine {routine.describe()} gives NaN or infinite voltages: '
                           'check its offset and frequencies')
        peak = float(np.max(np.abs(profile))) if profile.size else 0.0
        if peak > self.limits.voltage_v:
            return False, (f'the routine peaks at {peak:.4g} V, beyond the voltage limit '
                           f'{self.limits.voltage_v:g} V')
        self.routine = routine
        self.profile = profile
        self.started_s = now_s
        self.progress = 0.0
        self.peaks = dict.fromkeys(self.peaks, 0.0)
        self.state = 'ramping-in' if self.ramp_in_s > 0 else 'running'
        self.reason = ''
        return True, f'started {routine.describe()}'

    def stop(self, reason: str = 'stopped on request', state: str = 'stopped') -> float:
        """Stop (if active) with a state and a reason; return the command, 0 V."""
        if self.active:
            self.state = state
            self.reason = reason
        self.last_command_v = 0.0
        return 0.0

    def observe(self, now_s: float, current: Optional[ArrayLike] = None,
                speed: Optional[ArrayLike] = None, voltage: Optional[ArrayLike] = None) -> bool:
        """
        Take measured samples; return whether the session was stopped by them.

        A channel given (even empty) is fresh now unless a value is NaN or infinite, which
        stops an active routine at once (``stopped-by-limit``, the channel named) and keeps a
        watched channel stale until a finite sample comes. A call without channels counts
        only for a session that watches none.
        """
        self.last_sample_s = now_s
        given = {'current': current, 'speed': speed, 'voltage': voltage}
        arrays = {channel: np.asarray(values, dtype=float).ravel()
                  for channel, values in given.items() if values is not None}
        for channel, values in arrays.items():
            if np.all(np.isfinite(values)):
                self.not_finite.discard(channel)
                self.last_seen[channel] = now_s
            else:
                self.not_finite.add(channel)
        if not self.active:
            return False
        for channel, limit, unit in (('current', self.limits.current_a, 'A'),
                                     ('speed', self.limits.speed_rad_s, 'rad/s'),
                                     ('voltage', self.limits.voltage_v, 'V')):
            measured = arrays.get(channel)
            if measured is None or not measured.size:
                continue
            if channel in self.not_finite:
                self.stop(f'{channel} is not finite (NaN or inf)', 'stopped-by-limit')
                return True
            peak = float(np.max(np.abs(measured)))
            self.peaks[channel] = max(self.peaks[channel], peak)
            # the voltage is measured after the command: tolerate rounding, not more
            tolerance = 1e-6 * limit if channel == 'voltage' else 0.0
            if peak > limit + tolerance:
                self.stop(f'{channel} {peak:.4g} {unit} beyond the limit {limit:g} {unit}',
                          'stopped-by-limit')
                return True
        return False

    def command(self, now_s: float) -> Optional[float]:
        """
        Return the voltage to command now, or ``None`` when idle (nothing to publish).

        Goes ``stale`` (0 V) when the measurements stopped, ``done`` (0 V) at the end.
        """
        if not self.active or self.started_s is None:
            return None
        stale = self.stale_reason(now_s)
        if stale is not None:
            return self.stop(stale, 'stale')
        elapsed = now_s - self.started_s
        index = int(np.floor(elapsed * self.rate_hz + 1e-9))
        if index >= self.profile.size:
            self.progress = 1.0
            return self.stop('routine complete', 'done')
        self.progress = index / self.profile.size
        self.state = 'ramping-in' if elapsed < self.ramp_in_s else 'running'
        value = float(np.clip(self.profile[index], -self.limits.voltage_v,
                              self.limits.voltage_v))
        if not np.isfinite(value):
            return self.stop(f'the routine gave a non-finite command at {elapsed:.3g} s',
                             'stopped-by-limit')
        self.last_command_v = value
        return value

    def status(self) -> dict[str, str]:
        """Return the state as text key-values (for ``/diagnostics``)."""
        routine = self.routine
        return {
            'state': self.state,
            'reason': self.reason,
            'routine': routine.kind if routine else '',
            'direction': routine.direction if routine else '',
            'description': routine.describe() if routine else '',
            'progress': f'{self.progress:.3f}',
            'command_v': f'{self.last_command_v:.6g}',
            'peak_current_a': f'{self.peaks["current"]:.6g}',
            'peak_speed_rad_s': f'{self.peaks["speed"]:.6g}',
            'watched': ', '.join(self.watch),
            'not_finite': ', '.join(sorted(self.not_finite)),
        }
