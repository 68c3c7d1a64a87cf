"""
The measured current's own noise, integrated by the fitted model: a misfit that is no model error.

A drive's current is often sampled with its switching ripple (a PWM ripple caught at random
phases): the samples scatter widely, white, about a current that is smooth.  The speed does
not follow that scatter, but an output-error fit drives the model with the samples as they
are, so its simulated speed wanders by what the model makes of the scatter: in mechanical
mode (torque ``K i``) white current noise of ``s`` gives, through ``J dw/dt = K i - b w``
sampled at ``dt``, a speed of RMS ``g K s / sqrt(1 - a^2)`` with ``a = exp(-b dt / J)`` and
``g = (1 - a) / b``.  When the residual is no more than :data:`INPUT_NOISE_FACTOR` times that,
the misfit is this noise (an effect smaller than it cannot be told from it): the result says
so, and what a user can do about it, instead of blaming the model
(:func:`input_noise_warning`).  On the HSM150 servo's
torque-step records the current samples scatter by 0.43-0.54 A (39-53 % of the current) and the
residual is 0.7-1.6 times this figure (``bench/bench_hsm150_singles.py``).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from dcmotor_id.core.checks import Check, register
from dcmotor_id.signals.filters import noise_std

#: A residual up to this multiple of the speed RMS the current's noise gives is that noise.
INPUT_NOISE_FACTOR = 2.0


def propagated_speed_rms(parameters: dict[str, float], records: Sequence[Any],
                         torque_constant: float) -> tuple[float, float] | None:
    """
    Return the speed RMS [rad/s] the current's white noise gives through the model, and that noise.

    ``parameters`` are the fitted ones (J, b); the current's noise is
    :func:`~dcmotor_id.signals.filters.noise_std` over all records (RMS), the sample period the
    records' median.  None when a figure is missing or not positive.
    """
    j, b = parameters.get('J'), parameters.get('b')
    currents = [rec.current for rec in records if getattr(rec, 'current', None) is not None]
    if not currents or j is None or b is None or not (j > 0 and b > 0 and torque_constant > 0):
        return None
    sigma = float(np.sqrt(np.mean([noise_std(current) ** 2 for current in currents])))
    dt = float(np.median([rec.sample_period_s for rec in records]))
    if not (sigma > 0 and dt > 0):
        return None
    a = float(np.exp(-b * dt / j))
    g = (1.0 - a) / b
    return g * torque_constant * sigma / float(np.sqrt(1.0 - a * a)), sigma


def input_noise_warning(parameters: dict[str, float], records: Sequence[Any],
                        torque_constant: float | None, residual_rms: float,
                        sensor_ratio: float) -> str | None:
    """
    Return the warning for a speed misfit that the current's noise explains, else None.

    ``residual_rms`` is the speed residual's RMS [rad/s], ``sensor_ratio`` its multiple of the
    speed sensor's noise (the figure of the general misfit warning).
    """
    if torque_constant is None:
        return None
    figures = propagated_speed_rms(parameters, records, torque_constant)
    if figures is None:
        return None
    speed_rms, sigma = figures
    ratio = residual_rms / speed_rms
    if ratio > INPUT_NOISE_FACTOR:
        return None
    return (f'the speed misfit ({sensor_ratio:.3g}x the speed sensor noise) is the measured '
            f"current's own noise run through the model ({ratio:.2g}x the {speed_rms:.3g} "
            f'rad/s it gives): the current samples scatter by {sigma:.3g} A (white, e.g. a '
            'switching ripple sampled at random phases), which the speed does not follow, so '
            'the fit cannot tell it from torque.  This is a limit of the data: an effect smaller '
            'than this noise cannot be told from it, and the values of one record scatter '
            'beyond their standard errors.  Fit '
            'several records together, or record the current averaged over each sample period '
            '(a low-pass filter before the sampling, or sampling in step with the switching)')


register(Check('input_noise', 'after_fit', 'fit', input_noise_warning,
               "a speed misfit that the measured current's own noise explains"))
