"""
Plausibility of an identification result against the scales the data themselves imply.

The sign check (:func:`dcmotor_id.core.model.inadmissible`) refuses negative values; this module
catches the numbers that are positive but wrong: a parameter many orders of magnitude from
what the data imply (Ra against u/i, CPhi against u/w, the time constants against the sample
period and the record length, Mc against the torque), a parameter pinned at the fit's lower
bound, a standard error of exactly zero. :func:`check_plausibility` raises
:class:`~dcmotor_id.core.errors.FitError` for a result that must not be reported and returns
warnings (plain sentences) for one that may be, with a caveat.

The scales are RMS values of the measured signals, so the checks are invariant to the units
(scaling every signal by the same factor scales Mc and nothing else).
"""

from __future__ import annotations

from typing import Collection, Mapping, Optional, Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.model import UNITS
from dcmotor_id.core.records import Record

if TYPE_CHECKING:
    from dcmotor_id.identification.checks.answer import FinalFit

#: A value further than this factor from the scale the data imply is refused.
SCALE_FACTOR = 1e5
#: A non-negative parameter below this fraction of its data scale sits at the fit's lower
#: bound (the refined fit works on logarithms, floored): it is not determined, only "about 0".
BOUND_FRACTION = 1e-6
#: Fitted parameters checked for a standard error of exactly zero.
FITTED_NAMES = ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')


def _rms(records: Sequence[Record], channel: str) -> float:
    """RMS of a channel over all records (0 when absent)."""
    parts = [np.asarray(getattr(rec, channel), dtype=float) for rec in records
             if getattr(rec, channel) is not None]
    if not parts:
        return 0.0
    values = np.concatenate(parts)
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else 0.0


def data_scales(records: Sequence[Record],
                torque_constant: Optional[float] = None) -> dict[str, float]:
    """
    Return the scales the data imply: ``u/i`` [Ohm], ``u/w`` [V s], ``dt``, ``T`` [s].

    ``u/i`` and ``u/w`` are ratios of RMS values (absent without voltage), ``dt`` the sample
    period and ``T`` the longest record.
    """
    current, speed = _rms(records, 'current'), _rms(records, 'speed')
    scales = {'dt': float(records[0].sample_period_s),
              'T': max(float(rec.time_s[-1] - rec.time_s[0]) for rec in records),
              'i': current, 'w': speed}
    if torque_constant is None:
        voltage = _rms(records, 'voltage')
        if current > 0:
            scales['u/i'] = voltage / current
        if speed > 0:
            scales['u/w'] = voltage / speed
    return scales


def _far(value: float, scale: float) -> bool:
    return not (scale / SCALE_FACTOR <= value <= scale * SCALE_FACTOR)


def check_plausibility(parameters: Mapping[str, float], stderr: Mapping[str, float],
                       records: Sequence[Record],
                       torque_constant: Optional[float] = None,
                       said: Collection[str] = ()) -> list[str]:
    """
    Check a result against the data's own scales; return warnings, raise for refusals.

    Parameters
    ----------
    parameters, stderr : dict
        The identified values and standard errors by name (``Ra`` ... ``Mc``).
    records : list of Record
        The records identified.
    torque_constant : float, optional
        The mechanical-only mode's torque constant [N m/A].
    said : collection of str
        Parameters already said not to be identifiable (at a bound, undetermined): a standard
        error of zero is theirs to explain, not a degenerate fit's.

    Returns
    -------
    list of str
        Warnings: a parameter at the fit's lower bound, a standard error of exactly zero.

    Raises
    ------
    FitError
        A value that is not finite, or many orders of magnitude from what the data imply:
        Ra against u/i, CPhi against u/w, the electrical (La/Ra) and mechanical time
        constants against the sample period and the record length, Mc far above the torque.

    """
    values = {name: float(value) for name, value in parameters.items()
              if name in FITTED_NAMES}
    broken = [name for name, value in values.items() if not np.isfinite(value)]
    if broken:
        raise FitError(f'the fit gave non-finite values for {", ".join(broken)}: the data do '
                       'not determine the motor; check the units and signs of the columns')
    scales = data_scales(records, torque_constant)
    constant = torque_constant if torque_constant is not None else values.get('CPhi')
    torque = (constant or 0.0) * scales['i']
    problems = _scale_problems(values, scales, torque)
    if problems:
        raise FitError('the result is implausible, many orders of magnitude from what the '
                       'data imply: ' + '; '.join(problems) + '. The fit did not converge to '
                       'the motor: check the units of the columns (V, A, rad/s; all scaled '
                       'alike is fine up to 1e9) and that the data come from one DC drive')
    return _degenerate_warnings(values, stderr, scales, torque, said)


def _scale_problems(values: Mapping[str, float], scales: Mapping[str, float],
                    torque: float) -> list[str]:
    """Return the values many orders of magnitude from the data's scales, as sentences."""
    problems = []

    def far(name: str, value: float, scale: float, what: str) -> None:
        if scale > 0 and np.isfinite(scale) and _far(value, scale):
            problems.append(f'{name} = {value:.3g} {UNITS.get(name, "s")} against {what} '
                            f'{scale:.3g}')

    dt, span = scales['dt'], scales['T']
    ra, cphi = values.get('Ra'), values.get('CPhi')
    if ra is not None and 'u/i' in scales:
        far('Ra', ra, scales['u/i'], 'the u/i of the data,')
    if cphi is not None and 'u/w' in scales:
        far('CPhi', cphi, scales['u/w'], 'the u/w of the data,')
    if ra and values.get('La') is not None:
        electrical = values['La'] / ra
        if not dt / SCALE_FACTOR <= electrical <= span * SCALE_FACTOR:
            problems.append(f'La/Ra = {electrical:.3g} s against a sample period of {dt:.3g} s '
                            f'and a record of {span:.3g} s')
    if values.get('J') is not None:
        gain = (cphi ** 2 / ra if ra and cphi else 0.0) + values.get('b', 0.0)
        if gain > 0:
            mechanical = values['J'] / gain
            if not dt / SCALE_FACTOR <= mechanical <= span * SCALE_FACTOR:
                problems.append(f'the mechanical time constant {mechanical:.3g} s against a '
                                f'sample period of {dt:.3g} s and a record of {span:.3g} s')
    if values.get('Mc') is not None and torque > 0 and values['Mc'] > SCALE_FACTOR * torque:
        problems.append(f'Mc = {values["Mc"]:.3g} N m against a torque of {torque:.3g} N m')
    return problems


def _degenerate_warnings(values: Mapping[str, float], stderr: Mapping[str, float],
                         scales: Mapping[str, float], torque: float,
                         said: Collection[str] = ()) -> list[str]:
    """Return warnings for Mc or b at the fit's lower bound and standard errors of 0."""
    warnings = []
    reference = {'Mc': torque, 'b': torque / scales['w'] if scales['w'] > 0 else 0.0}
    for name, scale in reference.items():
        value = values.get(name)
        if value is not None and scale > 0 and abs(value) < BOUND_FRACTION * scale:
            warnings.append(f'{name} = {value:.3g} {UNITS[name]} is at the lower bound of the '
                            f'fit (below {BOUND_FRACTION:g} of the scale of the data, '
                            f'{scale:.3g} {UNITS[name]}): not determined, read it as about 0')
    zero = [name for name in FITTED_NAMES if name in values and name not in said and
            np.isfinite(stderr.get(name, np.nan)) and stderr[name] == 0.0]
    if zero:
        warnings.append(f'the standard error of {", ".join(zero)} is exactly 0: not a '
                        'precision but a degenerate fit; do not trust those values')
    return warnings


def plausibility_check(fit: FinalFit) -> list[str]:
    """
    Check the answer (:mod:`~.answer`): :func:`check_plausibility` on the records identified.

    A warning on a parameter already said not to be identifiable is not repeated.
    """
    return [text for text in check_plausibility(fit.estimate.parameters, fit.estimate.stderr,
                                                fit.records, fit.torque_constant, fit.said)
            if not any(text.startswith(f'{name} = ') for name in fit.said)]
