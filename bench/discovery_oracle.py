"""
The oracle of ``bench/bench_discovery.py``: whether a record carries its effect above noise.

The loop's base fit on the training parts, then the base model plus the *true* effect refitted
on the same parts from the true values (the motor's parameters, the effect's coefficients and
inner parameters: the Stribeck velocity, the cogging period, the delayed channel), and that
refit judged by the loop's own rule against the base (:func:`oracle`).  A record whose oracle
is turned down does not show its effect to this test: not even the right structure started at
the truth gains significantly on the held-out part.  Then a loop that misses it is not at
fault; a loop that misses an effect the oracle shows is (its screen, refit or choice).

The oracle also says *why* it is turned down, with numbers: the held-out t of the innovations
against its threshold (the effect is not above the noise over the effective samples), or the
least gain (the t is there, the gain under the loop's ``min_gain``), what the true structure
changes in the held-out outputs beyond the base in noise levels (:func:`part_beyond_base`),
and the likelihood ratio of the same two fits on the training parts, on effective samples
(:func:`insample_ratio`: what all of the training data say).  And whether the loop judges at
all: it stops before any rule where the base's residual is white (``white``,
:func:`~dcmotor_id.identification.discovery.analysis.stops_before_judging` under the rule: the
held-out part, and since round 11 by default the whole records too; round 10: every
current-speed record the default missed then).  Current-speed mode only (the
loop alone, :func:`~dcmotor_id.identification.discovery.discover`).
"""

import numpy as np
from scipy.stats import chi2

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.model import PARAMETER_NAMES

from dcmotor_id.identification.checks.start import correlation_time
from dcmotor_id.identification.discovery.analysis import analyse, stops_before_judging
from dcmotor_id.identification.discovery.judging import (HELDOUT_ALPHA, heldout_t_threshold,
                                                         innovation_t, least_gain,
                                                         paired_heldout, score, unearned)
from dcmotor_id.identification.discovery.loop import base_fit, DiscoveryLoop
from dcmotor_id.identification.discovery.refitting import fit_structure
from dcmotor_id.identification.discovery.structure import Candidate, Structure


def true_start(motor, effect):
    """Return the effect's inner parameters and its coefficients by term name, at the truth."""
    cls, values = type(effect), effect.parameters
    if cls.TRANSFORM:
        return {'channel': values['channel'], 'samples': int(values['samples'])}, {}
    if effect.name == 'stribeck':
        velocity = float(values['velocity_rad_s'])
        return {'velocity_rad_s': velocity}, {
            cls.term_name('excess_Nm'): float(values['excess_Nm']),
            cls.term_name('velocity_rad_s'): velocity}
    if effect.name == 'cogging':
        amplitude, phase = float(values['amplitude_Nm']), float(values['phase_rad'])
        return {'cycles_per_rev': float(values['cycles_per_rev'])}, {
            cls.term_name('sin_Nm'): amplitude * np.cos(phase),
            cls.term_name('cos_Nm'): amplitude * np.sin(phase)}
    return {}, {cls.term_name(key): float(value) for key, value in values.items()}


def part_beyond_base(loop, base, fitted):
    """
    RMS of what the oracle changes in the held-out outputs beyond the base, in noise levels.

    The oracle's simulation minus the base's on the held-out parts at the same instants
    (:func:`~dcmotor_id.identification.discovery.judging.paired_heldout`), over each channel's
    noise weight; the largest channel.  The base refit absorbs what it can of the effect (a
    drag in the viscous friction): what is left is what a test can see.
    """
    ratio = 0.0
    for channel in loop.outputs:
        before, after = paired_heldout(base, fitted, channel)
        # residuals at the same instants of the same measurement: their difference is the
        # change of the simulation (a delay's shifted channel aside)
        ratio = max(ratio, float(np.sqrt(np.mean((after - before) ** 2)))
                    / loop.fitted_weights[channel])
    return ratio


def insample_ratio(loop, base, fitted):
    """
    Likelihood-ratio statistic of the oracle on the training parts, on effective samples.

    Per channel ``n_eff log(mse_base / mse_oracle)`` with ``n_eff`` the training samples over
    the oracle residual's correlation time; summed over the channels.  Under no effect it
    follows chi-square with the effect's coefficients as degrees of freedom (for a white
    residual): what all the training data say, where the held-out test sees 30 % of the
    excitation.
    """
    total = 0.0
    for channel in loop.outputs:
        before = base.channel_residual(channel, 'train')
        after = fitted.channel_residual(channel, 'train')
        common = min(before.shape[0], after.shape[0])  # a late sensor keeps the start
        before, after = before[:common], after[:common]
        effective = common / correlation_time(after)
        total += effective * float(np.log(np.mean(before ** 2) / np.mean(after ** 2)))
    return total


def oracle(records, motor, effect, rule):
    """
    Judge the true effect at its true values by ``rule`` against the loop's base; a dict.

    Keys: ``detectable`` (the rule accepts it), ``t`` and ``t_needed`` (the innovations' t
    and its threshold), ``gain_pct``, ``bic_delta``, ``part``
    (:func:`part_beyond_base`), ``why`` (the rule's reason, or None), ``lr`` and
    ``lr_needed`` (:func:`insample_ratio` and its chi-square threshold at the held-out
    test's size), ``white`` (the base's residual is white as the rule's loop asks: it stops
    before judging any candidate).  None when the base or the oracle's refit has no fit.
    """
    inner, coefficients = true_start(motor, effect)
    truth = {name: float(getattr(motor, name)) for name in PARAMETER_NAMES}
    try:
        loop, base = base_fit(DiscoveryLoop(records, acceptance=rule), None, Structure())
        with np.errstate(all='ignore'):
            fitted = fit_structure(loop, Structure().plus(type(effect), inner), start=truth,
                                   initial={**truth, **coefficients})
    except (DcMotorIdError, ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None
    if not np.isfinite(fitted.heldout_cost):
        return None
    candidate = score(loop, base, Candidate(type(effect), inner, coefficients, 0.0,
                                            fit=fitted))
    t, effective = innovation_t(loop, base, fitted)
    lr = insample_ratio(loop, base, fitted)
    dof = max(len(coefficients), 1)
    why = None
    if not (candidate.gain >= least_gain(loop) and candidate.bic_delta < 0):
        why = (f'gain {100 * candidate.gain:.3g} % (least {100 * least_gain(loop):g} %), '
               f'BIC change {candidate.bic_delta:.4g}')
    why = why or unearned(loop, base, candidate)
    return {'detectable': why is None, 't': t, 't_needed': heldout_t_threshold(effective),
            'gain_pct': 100.0 * candidate.gain, 'bic_delta': candidate.bic_delta,
            'part': part_beyond_base(loop, base, fitted), 'why': why,
            'lr': lr, 'lr_needed': float(chi2.ppf(1.0 - HELDOUT_ALPHA, dof)),
            'white': stops_before_judging(loop, base, analyse(loop, base))}


def verdict(found, names, accepted):
    """
    Say why the loop missed an effect, from the oracle (``found``) and the effects added.

    ``(a)``: not above the noise (the oracle's held-out t below its threshold; "in all the
    data" too when the training part's likelihood ratio is below its own); ``(c)``: the t is
    there but the rule's least gain or BIC turns the oracle down; ``(b)``/``(d)``: the oracle
    passes and the loop missed it (``(d)``: it added another effect first); ``(e)`` is added
    where the loop added nothing and the base's residual is white (as the rule's loop asks:
    :func:`~dcmotor_id.identification.discovery.analysis.stops_before_judging`): the loop
    stopped before any rule judged.  None when the loop found it.
    """
    if names and names[0] in accepted:
        return None
    if found is None:
        return 'no oracle fit'
    gate = '; (e) the loop stopped: white residual' if (
        not names and found.get('white')) else ''
    return _why(found, names) + gate


def _why(found, names):
    """Return the oracle's part of :func:`verdict`: ``(a)`` to ``(d)``."""
    if found['detectable']:
        return '(d) another effect first' if names else '(b) screen or refit'
    if found['t'] < found['t_needed']:
        if found['lr'] < found['lr_needed']:
            return '(a) below the noise in all the data'
        return '(a) below the noise on the held-out part'
    return '(c) ' + str(found['why']).split(',')[0]
