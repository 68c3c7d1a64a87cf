"""
The vocabulary of effects the base motor model lacks, each a small self-describing class.

Every effect documents its parameters (units, sign convention) and does two jobs:

* **Simulate** (:meth:`Effect.motor_effects`): the true, state-dependent effect for
  :func:`dcmotor_id.simulation.simulate_motor_effects` and the ``effects=`` option of
  :class:`dcmotor_id.simulation.MotorStepper`, to make data with the effect in it.
* **Estimate** (:meth:`Effect.terms`, :meth:`Effect.transform`): what the output-error fit
  needs to model the effect: linear :class:`~dcmotor_id.estimators.base.ExogenousTerm`
  regressors built from the *measured* signals (the sign of the speed, ``w |w|``, the shaft
  angle...), or a data transform (:class:`SensorDelay`).  Nonlinear inner parameters (the
  Stribeck velocity, the cogging period) are found by the small grid of
  :meth:`Effect.inner_grid`; the discovery loop (:mod:`dcmotor_id.discovery`) screens the grid
  and refits all parameters at the best point.

Sign convention throughout: the shaft equation is ``J dw/dt = CPhi i - b w - Mc sgn(w) + ...``
(``K i`` in the mechanical-only mode) and the armature circuit ``La di/dt = u - Ra i - CPhi w
+ ...``; each class says what it adds.  Units are SI (N m, rad/s, V, A, Ohm, s); for a linear
axis such as EMPS read N for N m and m for rad.

Two effects of the vocabulary are the same model in most data: a constant load torque ``T`` on
a shaft with Coulomb friction ``Mc`` behaves exactly like direction-dependent Coulomb friction
``Mc + T`` / ``Mc - T`` (in motion and at rest) as long as ``|T| < Mc``; they differ only when
the load can turn the shaft by itself.  The discovery loop reports such ties (the earlier
effect in :data:`VOCABULARY` wins and the other is listed as equivalent).
"""

import numpy as np

from dcmotor_id.estimators.base import ExogenousTerm
from dcmotor_id.estimators.refined import StateTerm
from dcmotor_id.signals import dead_sign, integrate_trapezoid, smooth


def shaft_angle(record):
    """Shaft angle [rad]: the measured position, else the integral of the measured speed."""
    if record.position is not None:
        return np.asarray(record.position, dtype=float)
    return integrate_trapezoid(record.speed, record.sample_period_s)


def torque_spread(records, base, torque_constant=None):
    """Return the standard deviation of the driving torque (``CPhi i`` or ``K i``) [N m]."""
    constant = torque_constant if torque_constant is not None else base.get('CPhi', 1.0)
    current = np.concatenate([rec.current for rec in records])
    return max(float(constant * np.std(current)), 1e-12)


class Effect:
    """
    One effect: its parameters, its simulation and its estimation.

    Subclasses set :attr:`name`, :attr:`PARAMETERS` and :attr:`MODES` and implement
    :meth:`motor_effects`, :meth:`terms` (or :meth:`transform`) and :meth:`from_fit`.

    Parameters
    ----------
    **parameters : float
        Values of the effect's parameters by name (see :attr:`PARAMETERS`); missing ones take
        their default.

    """

    #: Vocabulary name (as in the JSON result).
    name = ''
    #: One-line description.
    summary = ''
    #: Parameter name -> (unit, default, meaning and sign).
    PARAMETERS = {}
    #: Modes where the effect applies: ``full`` and/or ``mechanical``.
    MODES = ('full', 'mechanical')
    #: Whether the effect acts by transforming the data instead of by terms.
    TRANSFORM = False

    def __init__(self, **parameters):
        unknown = sorted(set(parameters) - set(self.PARAMETERS))
        if unknown:
            raise ValueError(f'{self.name}: unknown parameter(s) {", ".join(unknown)}; it has '
                             f'{", ".join(self.PARAMETERS) or "none"}')
        self.parameters = {key: parameters.get(key, spec[1])
                           for key, spec in self.PARAMETERS.items()}

    def __repr__(self):
        """Return e.g. ``LoadTorque(torque_Nm=0.5)``."""
        listing = ', '.join(f'{key}={value!r}' for key, value in self.parameters.items())
        return f'{type(self).__name__}({listing})'

    @classmethod
    def applies(cls, mechanical_only):
        """Whether the effect can act in this mode."""
        return ('mechanical' if mechanical_only else 'full') in cls.MODES

    def motor_effects(self):
        """Fields of :class:`~dcmotor_id.simulation.MotorEffects` that simulate the effect."""
        raise NotImplementedError

    @classmethod
    def inner_grid(cls, records, base, torque_constant=None):
        """Values of the nonlinear inner parameters to screen (``[{}]`` when there are none)."""
        return [{}]

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """
        Exogenous terms of the effect for these records (regressors from measured signals).

        Parameters
        ----------
        records : list of Record
            The records (the regressors are as long as each).
        inner : dict
            Inner parameters (from :meth:`inner_grid`).
        base : dict
            Current parameter values (for the coefficients' typical magnitude).
        torque_constant : float, optional
            Mechanical-only mode.
        initial : dict, optional
            Start values of the coefficients by term name.

        """
        return ()

    @classmethod
    def transform(cls, records, inner):
        """Return the records as the model should see them (identity but for data effects)."""
        return list(records)

    @classmethod
    def from_fit(cls, values, inner):
        """Build the effect from the parameters fitted in ``values`` (by term name)."""
        raise NotImplementedError

    def problem(self, base, records):
        """
        Why the fitted effect is not physical (a sentence), or None when it is.

        The discovery loop rejects a candidate whose fit is not physical (a drag that drives
        the shaft, a negative brush drop...) instead of reporting a wrong effect.
        """
        return None

    @classmethod
    def term_name(cls, coefficient):
        """Name of a coefficient in the fit: ``<effect>.<parameter>``."""
        return f'{cls.name}.{coefficient}'

    def describe(self, base=None):
        """JSON form ``{"name": ..., "parameters": {...}}``."""
        return {'name': self.name, 'parameters': dict(self.parameters)}

    @classmethod
    def documentation(cls):
        """Markdown-ready description of the effect and its parameters."""
        lines = [f'`{cls.name}`: {cls.summary}']
        for key, (unit, _, meaning) in cls.PARAMETERS.items():
            lines.append(f'  - `{key}` [{unit}]: {meaning}')
        return '\n'.join(lines)

    @staticmethod
    def _term(name, channel, regressors, scale, initial, field=None, fixed=()):
        """Build a linear term, or a :class:`StateTerm` (channel ``state``) if ``field``."""
        start = 0.0 if initial is None else float(initial.get(name, 0.0))
        regressors = tuple(np.asarray(r, dtype=float) for r in regressors)
        if field is not None:
            return StateTerm(name, 'state', regressors, float(scale), start, field,
                             tuple(fixed))
        return ExogenousTerm(name, channel, regressors, float(scale), start)


class LoadTorque(Effect):
    """A constant torque on the shaft (a load, a drive offset)."""

    name = 'load_torque'
    summary = ('constant load torque T_L on the shaft: J dw/dt = ... - T_L (the "offset" of '
               'the EMPS IDIM model).')
    PARAMETERS = {'torque_Nm': ('N m', 0.0, 'T_L, positive when it opposes positive rotation')}

    def motor_effects(self):
        """Simulate as a constant torque."""
        return {'load_torque_Nm': float(self.parameters['torque_Nm'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """One term: torque channel, regressor -1."""
        scale = 0.05 * torque_spread(records, base, torque_constant)
        return (cls._term(cls.term_name('torque_Nm'), 'torque',
                          [-np.ones(len(rec)) for rec in records], scale, initial),)

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``torque_Nm``."""
        return cls(torque_Nm=float(values[cls.term_name('torque_Nm')]))


class CoulombAsymmetry(Effect):
    """Direction-dependent Coulomb friction, fitted exactly in the hybrid simulation."""

    name = 'coulomb_asymmetry'
    summary = ('Coulomb friction Mc + d for w > 0 and Mc - d for w < 0 (also the break-away '
               'levels); the same model as load_torque = d while |d| < Mc.')
    PARAMETERS = {'delta_Nm': ('N m', 0.0, 'd, half the difference Mc+ - Mc-')}

    def motor_effects(self):
        """Simulate with friction levels ``Mc +/- d``."""
        return {'coulomb_delta_Nm': float(self.parameters['delta_Nm'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """One state term: the fit's simulator uses ``Mc +/- d`` (exact, fast path)."""
        scale = max(0.1 * base.get('Mc', 0.0), 0.01 * torque_spread(records, base,
                                                                    torque_constant))
        return (cls._term(cls.term_name('delta_Nm'), 'state',
                          [np.zeros(len(rec)) for rec in records], scale, initial,
                          field='coulomb_delta_Nm'),)

    def problem(self, base, records):
        """Refuse a Coulomb level below zero in one direction."""
        if abs(self.parameters['delta_Nm']) > base.get('Mc', 0.0):
            return 'the Coulomb friction would be negative in one direction'
        return None

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``delta_Nm``."""
        return cls(delta_Nm=float(values[cls.term_name('delta_Nm')]))

    def describe(self, base=None):
        """Add the two friction levels when the base ``Mc`` is known."""
        out = super().describe()
        if base is not None and 'Mc' in base:
            out['parameters']['Mc_pos_Nm'] = float(base['Mc'] + self.parameters['delta_Nm'])
            out['parameters']['Mc_neg_Nm'] = float(base['Mc'] - self.parameters['delta_Nm'])
        return out


class ViscousAsymmetry(Effect):
    """Direction-dependent viscous friction (an addition to the issue's vocabulary)."""

    name = 'viscous_asymmetry'
    summary = ('viscous friction (b + d) w for w > 0 and (b - d) w for w < 0: an extra '
               'torque -d |w|.')
    PARAMETERS = {'delta_Nm_s': ('N m s/rad', 0.0, 'd, half the difference b+ - b-')}

    def motor_effects(self):
        """Simulate as a torque ``-d |w|``."""
        return {'viscous_delta_Nm_s': float(self.parameters['delta_Nm_s'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """One term: torque channel, regressor ``-|w|`` of the smoothed measured speed."""
        peak = max(max(float(np.max(np.abs(rec.speed))) for rec in records), 1e-12)
        scale = 0.05 * torque_spread(records, base, torque_constant) / peak
        return (cls._term(cls.term_name('delta_Nm_s'), 'torque',
                          [-np.abs(smooth(rec.speed, rec.sample_period_s)) for rec in records],
                          scale, initial),)

    def problem(self, base, records):
        """Refuse a viscous coefficient below zero in one direction."""
        if abs(self.parameters['delta_Nm_s']) > base.get('b', 0.0):
            return 'the viscous friction would be negative in one direction'
        return None

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``delta_Nm_s``."""
        return cls(delta_Nm_s=float(values[cls.term_name('delta_Nm_s')]))

    def describe(self, base=None):
        """Add the two viscous coefficients when the base ``b`` is known."""
        out = super().describe()
        if base is not None and 'b' in base:
            out['parameters']['b_pos_Nm_s'] = float(base['b'] + self.parameters['delta_Nm_s'])
            out['parameters']['b_neg_Nm_s'] = float(base['b'] - self.parameters['delta_Nm_s'])
        return out


class Stribeck(Effect):
    """Friction that is higher at low speed (static friction above Coulomb friction)."""

    name = 'stribeck'
    summary = ('friction magnitude Mc + excess exp(-(w/w_s)^2): static friction Mc + excess at '
               'rest, falling to Mc above a few w_s.')
    PARAMETERS = {
        'excess_Nm': ('N m', 0.0, 'static minus Coulomb friction, > 0 for a Stribeck dip'),
        'velocity_rad_s': ('rad/s', 1.0, 'Stribeck velocity w_s (inner, by grid search)'),
    }

    def motor_effects(self):
        """Simulate as a speed-dependent friction level (break-away at ``Mc + excess``)."""
        return {'stribeck_excess_Nm': float(self.parameters['excess_Nm']),
                'stribeck_velocity_rad_s': float(self.parameters['velocity_rad_s'])}

    @classmethod
    def inner_grid(cls, records, base, torque_constant=None):
        """Eight Stribeck velocities, log-spaced from 0.5 % to 30 % of the peak speed."""
        peak = max(float(np.max(np.abs(smooth(rec.speed, rec.sample_period_s))))
                   for rec in records)
        return [{'velocity_rad_s': float(v)} for v in np.geomspace(0.005, 0.3, 8) * peak]

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """
        One state term: the friction level follows the *simulated* speed.

        The regressor ``-exp(-(w/w_s)^2) sgn(w)`` of the measured speed (kept for the
        residual correlations) cannot raise the break-away level and, fitted as a torque,
        gave an excess three times too large on motor 2 at low speed; the fit therefore
        simulates the Stribeck friction itself.
        """
        velocity = inner['velocity_rad_s']
        regressors = []
        for rec in records:
            speed = smooth(rec.speed, rec.sample_period_s)
            regressors.append(-np.exp(-(speed / velocity) ** 2)
                              * dead_sign(rec.speed, rec.sample_period_s))
        scale = max(0.1 * base.get('Mc', 0.0), 0.01 * torque_spread(records, base,
                                                                    torque_constant))
        name = cls.term_name('velocity_rad_s')
        fitted_velocity = (initial or {}).get(name)
        return (cls._term(cls.term_name('excess_Nm'), 'state', regressors, scale, initial,
                          field='stribeck_excess_Nm'),
                cls._term(name, 'state', [np.zeros(len(rec)) for rec in records],
                          0.3 * velocity, {name: fitted_velocity or velocity},
                          field='stribeck_velocity_rad_s'))

    def problem(self, base, records):
        """Require static friction above the Coulomb level and a positive velocity."""
        if self.parameters['excess_Nm'] <= 0.0:
            return 'no Stribeck dip: the static friction came out below the Coulomb friction'
        if self.parameters['velocity_rad_s'] <= 0.0:
            return 'the Stribeck velocity must be positive'
        return None

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``excess_Nm`` and the velocity (started at the grid value, then fitted)."""
        velocity = values.get(cls.term_name('velocity_rad_s'), inner['velocity_rad_s'])
        return cls(excess_Nm=float(values[cls.term_name('excess_Nm')]),
                   velocity_rad_s=abs(float(velocity)))


class QuadraticDrag(Effect):
    """Aerodynamic or fluid drag, a torque in the square of the speed."""

    name = 'quadratic_drag'
    summary = 'drag torque -c w |w| (fan, fluid load).'
    PARAMETERS = {'coefficient_Nm_s2': ('N m s^2/rad^2', 0.0, 'c, > 0 for a drag')}

    def motor_effects(self):
        """Simulate as a torque ``-c w |w|``."""
        return {'drag_Nm_s2': float(self.parameters['coefficient_Nm_s2'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """One term: torque, regressor ``-w |w|`` of the smoothed measured speed."""
        regressors = []
        peak = 1e-12
        for rec in records:
            speed = smooth(rec.speed, rec.sample_period_s)
            regressors.append(-speed * np.abs(speed))
            peak = max(peak, float(np.max(speed ** 2)))
        scale = 0.05 * torque_spread(records, base, torque_constant) / peak
        return (cls._term(cls.term_name('coefficient_Nm_s2'), 'torque', regressors, scale,
                          initial),)

    def problem(self, base, records):
        """Refuse a negative drag (it would drive the shaft)."""
        if self.parameters['coefficient_Nm_s2'] < 0.0:
            return 'negative drag: the torque would drive the shaft'
        return None

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``coefficient_Nm_s2``."""
        return cls(coefficient_Nm_s2=float(values[cls.term_name('coefficient_Nm_s2')]))


class BrushDrop(Effect):
    """The voltage lost across the brushes, nearly constant in magnitude."""

    name = 'brush_drop'
    summary = 'brush voltage drop: La di/dt = u - Ra i - CPhi w - V_b sgn(i).'
    PARAMETERS = {'drop_V': ('V', 0.0, 'V_b, > 0 for a drop (typically 0.5 to 2 V)')}
    MODES = ('full',)

    def motor_effects(self):
        """Simulate as a voltage ``-V_b sgn(i)``."""
        return {'brush_drop_V': float(self.parameters['drop_V'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """
        One state term, simulated exactly (drop against the current, blocking).

        A regressor ``-sgn(i)`` of the measured current cannot express the blocking (no
        current while ``|u - CPhi w| <= V_b``) and biases La by some 15 % for a 2 V drop on the
        paper's motor 2; the regressor is kept for the residual correlations.
        """
        spread = float(np.std(np.concatenate([rec.voltage for rec in records])))
        return (cls._term(cls.term_name('drop_V'), 'state',
                          [-dead_sign(rec.current, rec.sample_period_s) for rec in records],
                          max(0.01 * spread, 1e-9), initial, field='brush_drop_V'),)

    def problem(self, base, records):
        """Refuse a negative drop (it would be a source)."""
        if self.parameters['drop_V'] < 0.0:
            return 'negative brush drop: the brushes would be a voltage source'
        return None

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``drop_V``."""
        return cls(drop_V=float(values[cls.term_name('drop_V')]))


class CurrentOffset(Effect):
    """A constant error of the current sensor."""

    name = 'current_offset'
    summary = 'current sensor offset: measured current = true current + offset.'
    PARAMETERS = {'offset_A': ('A', 0.0, 'added to the true current by the sensor')}
    MODES = ('full',)

    def motor_effects(self):
        """Simulate as an offset of the measured current."""
        return {'current_offset_A': float(self.parameters['offset_A'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """One term: current output, regressor 1."""
        spread = float(np.std(np.concatenate([rec.current for rec in records])))
        return (cls._term(cls.term_name('offset_A'), 'current',
                          [np.ones(len(rec)) for rec in records], max(0.01 * spread, 1e-12),
                          initial),)

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``offset_A``."""
        return cls(offset_A=float(values[cls.term_name('offset_A')]))


class SensorDelay(Effect):
    """A sensor that reports a whole number of samples late (or early) against the others."""

    name = 'sensor_delay'
    summary = ('whole-sample delay of one measured channel against the input: measured '
               'y[k] = y_true[k - samples]; handled by shifting the data.')
    PARAMETERS = {
        'channel': ('', 'speed', 'the delayed channel, current or speed'),
        'samples': ('samples', 0, 'delay, > 0 when that sensor is late (integer)'),
    }
    TRANSFORM = True

    def __init__(self, **parameters):
        super().__init__(**parameters)
        if self.parameters['channel'] not in ('current', 'speed'):
            raise ValueError('sensor_delay: channel must be current or speed, got '
                             f"{self.parameters['channel']!r}")
        self.parameters['samples'] = int(self.parameters['samples'])

    def motor_effects(self):
        """Simulate a late sensor (``samples >= 0``)."""
        samples = self.parameters['samples']
        if samples < 0:
            raise ValueError('sensor_delay: simulate a late sensor (samples >= 0); an early '
                             'one is the other channels being late')
        return {f"{self.parameters['channel']}_delay_samples": samples}

    @classmethod
    def channels(cls, mechanical_only):
        """Channels a delay can be estimated on in this mode."""
        return ('speed',) if mechanical_only else ('current', 'speed')

    @classmethod
    def transform(cls, records, inner):
        """Undo the delay: shift the channel back and trim every record to the overlap."""
        samples = int(inner.get('samples', 0))
        channel = inner.get('channel', 'speed')
        if samples == 0:
            return list(records)
        out = []
        for rec in records:
            n = len(rec)
            if samples > 0:
                shifted = getattr(rec, channel)[samples:]
                trimmed = rec.slice(0, n - samples)
            else:
                shifted = getattr(rec, channel)[:n + samples]
                trimmed = rec.slice(-samples, n)
            out.append(trimmed.replace(**{channel: shifted}))
        return out

    @classmethod
    def from_fit(cls, values, inner):
        """Build the delay from the inner parameter itself."""
        return cls(channel=inner['channel'], samples=int(inner['samples']))


class ResistanceDrift(Effect):
    """Armature resistance changing over the record (winding heating)."""

    name = 'resistance_drift'
    summary = ('armature resistance Ra(t) = Ra + rate (t - t_0), t_0 the record start (the '
               'base Ra is then the value at the start).')
    PARAMETERS = {'rate_ohm_per_s': ('Ohm/s', 0.0, 'rate, > 0 while the winding heats up')}
    MODES = ('full',)

    def motor_effects(self):
        """Simulate with a time-varying ``Ra``."""
        return {'resistance_rate_ohm_per_s': float(self.parameters['rate_ohm_per_s'])}

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """One term: voltage, regressor ``-(t - t_0) i`` with the smoothed measured current."""
        regressors = [-(rec.time_s - rec.time_s[0]) * smooth(rec.current, rec.sample_period_s)
                      for rec in records]
        duration = max(float(rec.time_s[-1] - rec.time_s[0]) for rec in records)
        scale = 0.05 * base.get('Ra', 1.0) / max(duration, 1e-9)
        return (cls._term(cls.term_name('rate_ohm_per_s'), 'voltage', regressors, scale,
                          initial),)

    def problem(self, base, records):
        """Require the resistance to stay positive over the records."""
        duration = max(float(rec.time_s[-1] - rec.time_s[0]) for rec in records)
        if base.get('Ra', 1.0) + min(self.parameters['rate_ohm_per_s'] * duration, 0.0) <= 0:
            return 'the armature resistance would become negative within the record'
        return None

    @classmethod
    def from_fit(cls, values, inner):
        """Read ``rate_ohm_per_s``."""
        return cls(rate_ohm_per_s=float(values[cls.term_name('rate_ohm_per_s')]))


class Cogging(Effect):
    """Torque ripple periodic in the shaft angle (slotting, magnets, a screw's pitch)."""

    name = 'cogging'
    summary = ('torque ripple A sin(N theta + phase), theta the shaft angle (the measured '
               'position, else the integrated measured speed).')
    PARAMETERS = {
        'amplitude_Nm': ('N m', 0.0, 'A, >= 0'),
        'cycles_per_rev': ('1/rev', 1.0, 'N, ripple periods per 2 pi of angle (inner, by grid '
                                         'search)'),
        'phase_rad': ('rad', 0.0, 'phase at theta = 0 (of the angle the data define)'),
    }

    def motor_effects(self):
        """Simulate with the ripple on the true angle."""
        return {'cogging_amplitude_Nm': float(self.parameters['amplitude_Nm']),
                'cogging_cycles_per_rev': float(self.parameters['cycles_per_rev']),
                'cogging_phase_rad': float(self.parameters['phase_rad'])}

    @classmethod
    def inner_grid(cls, records, base, torque_constant=None):
        """
        Screen integer ``N``: three ripples over the angles visited to fs / 4 at median speed.

        The upper end uses the median speed (the ripple shows where the shaft turns slowly);
        at most 48 values, log-spaced when the range is wider.
        """
        span = max(float(np.ptp(shaft_angle(rec))) for rec in records)
        speeds = np.abs(np.concatenate([rec.speed for rec in records]))
        typical = max(float(np.median(speeds)), 1e-12)
        rate = 1.0 / records[0].sample_period_s
        # At least three ripple periods within the range of angles visited: a longer period
        # is a position-dependent load, not a ripple.
        lowest = max(1, int(np.ceil(3.0 * 2.0 * np.pi / max(span, 1e-12))))
        highest = int(min(0.25 * rate * 2.0 * np.pi / typical, 4096))
        if highest < lowest:
            return []
        if highest - lowest < 48:
            grid = np.arange(lowest, highest + 1)
        else:
            grid = np.unique(np.round(np.geomspace(lowest, highest, 48)).astype(int))
        return [{'cycles_per_rev': float(n)} for n in grid]

    @classmethod
    def terms(cls, records, inner, base, torque_constant=None, initial=None):
        """Two terms: torque, regressors ``sin(N theta)`` and ``cos(N theta)``."""
        cycles = inner['cycles_per_rev']
        angles = [cycles * shaft_angle(rec) for rec in records]
        scale = 0.05 * torque_spread(records, base, torque_constant)
        return (cls._term(cls.term_name('sin_Nm'), 'torque', [np.sin(a) for a in angles],
                          scale, initial),
                cls._term(cls.term_name('cos_Nm'), 'torque', [np.cos(a) for a in angles],
                          scale, initial))

    @classmethod
    def from_fit(cls, values, inner):
        """Amplitude and phase from the sine and cosine coefficients."""
        a = float(values[cls.term_name('sin_Nm')])
        b = float(values[cls.term_name('cos_Nm')])
        return cls(amplitude_Nm=float(np.hypot(a, b)), cycles_per_rev=inner['cycles_per_rev'],
                   phase_rad=float(np.arctan2(b, a)))


#: The vocabulary the discovery loop searches by default, in the order ties are broken (the
#: earlier wins).
VOCABULARY = (LoadTorque, CoulombAsymmetry, Stribeck, QuadraticDrag, BrushDrop, CurrentOffset,
              SensorDelay, ResistanceDrift, Cogging)
#: The vocabulary with the additions beyond the issue's list (opt-in for the loop).
EXTENDED_VOCABULARY = VOCABULARY + (ViscousAsymmetry,)
#: Effect classes by name (every effect, for simulation and the CLI).
EFFECTS = {cls.name: cls for cls in EXTENDED_VOCABULARY}


def make_effect(name, **parameters):
    """Build an effect by its name (e.g. ``stribeck`` with ``excess_Nm=0.3``)."""
    if name not in EFFECTS:
        raise ValueError(f'unknown effect {name!r}; the vocabulary is {", ".join(EFFECTS)}')
    return EFFECTS[name](**parameters)


def parse_effect(text):
    """Parse ``NAME[:param=value,...]`` (the CLI's ``--effect``) into an effect."""
    name, _, rest = text.partition(':')
    parameters = {}
    for item in filter(None, (part.strip() for part in rest.split(','))):
        key, sep, value = item.partition('=')
        if not sep:
            raise ValueError(f'--effect {text!r}: write param=value, got {item!r}')
        key = key.strip()
        try:
            parameters[key] = float(value)
        except ValueError:
            parameters[key] = value.strip()
    return make_effect(name.strip(), **parameters)
