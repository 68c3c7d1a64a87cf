"""
From the records as read to records ready for an estimator, and the data that cannot identify.

:func:`prepare_records` checks what was read, gives every record a speed (derived from the
position where needed) and puts records of one clock on one sample period
(:func:`common_period`); :func:`check_excitation` refuses data that cannot identify anything
(no motion, steady state).  :func:`single_current_level` and :func:`one_level_reason` say why
a mechanical-only fit of one constant current failed.
"""

from __future__ import annotations

from typing import Sequence, TYPE_CHECKING

import numpy as np

from dcmotor_id.core.checks import Check, register
from dcmotor_id.core.errors import InputDataError, NotIdentifiableError
from dcmotor_id.core.records import check_record
from dcmotor_id.identification.checks.identifiability import assess_excitation, Excitation
from dcmotor_id.signals.filters import noise_std, speed_from_position, unwrap_turns

if TYPE_CHECKING:
    from dcmotor_id.core.records import Record

#: Largest relative difference of the records' sample periods taken as one period: the logged
#: time of one clock differs between records by its jitter and rounding (EMPS: 0.999984 ms and
#: 1.00001 ms, 2.6e-5), far below what changes a fit; larger differences are refused.
PERIOD_RTOL = 1e-4


def prepare_records(records: Sequence[Record], torque_constant: float | None = None,
                    resample: bool = False,
                    speed_cutoff_hz: float | None = None) -> list[Record]:
    """
    Check records and give each a speed; return the list ready for an estimator.

    Records without a current (all of them, no torque constant) are kept for the
    voltage-to-speed model (:func:`is_voltage_speed`).

    Parameters
    ----------
    records : list of Record
        As read from files or bags.
    torque_constant : float, optional
        Torque constant [N m/A]: selects the mechanical-only mode (no voltage needed).
    resample : bool
        Interpolate irregularly sampled records onto a uniform grid instead of refusing them.
    speed_cutoff_hz : float, optional
        Cut-off of the differentiating filter used when only position is given.

    """
    if not records:
        raise InputDataError('no records given')
    if torque_constant is not None and not (np.isfinite(torque_constant) and
                                            torque_constant > 0):
        raise InputDataError(f'--torque-constant must be a positive number in N m/A, got '
                             f'{torque_constant}')
    prepared = []
    voltage_speed = torque_constant is None and all(rec.current is None for rec in records)
    for record in records:
        if torque_constant is None and record.voltage is None:
            name = record.source or 'record'
            raise InputDataError(
                f'{name}: no voltage column. Name it voltage, or identify the mechanical part '
                'only (J, b, Mc) by giving the torque constant: --torque-constant K [N m/A]')
        record = check_record(record, need_voltage=torque_constant is None, resample=resample,
                              need_current=not voltage_speed)
        record = unwrapped(record)
        if record.speed is None:
            nyquist_hz = 0.5 / record.sample_period_s
            if speed_cutoff_hz is not None and not 0 < speed_cutoff_hz < nyquist_hz:
                raise InputDataError(
                    f'{record.source or "record"}: --speed-cutoff {speed_cutoff_hz:g} Hz is not '
                    f'below the Nyquist frequency {nyquist_hz:.6g} Hz of the record; give a '
                    'lower cut-off (the default is a tenth of the sample rate, at most 100 Hz)')
            assert record.position is not None  # checked above: no speed means a position
            record = record.replace(speed=speed_from_position(
                record.position, record.sample_period_s, speed_cutoff_hz), speed_derived=True)
        prepared.append(record)
    return common_period(prepared)


def unwrapped(record: Record) -> Record:
    """Return the record with an angle that wraps at a turn unwrapped, said in its notes."""
    if record.position is None:
        return record
    position, wraps = unwrap_turns(record.position)
    if not wraps:
        return record
    raw = np.asarray(record.position, dtype=float)
    note = (f'{record.source or "record"}: the position jumps by a whole turn {wraps} times '
            f'(it reads from {np.min(raw):.4g} to {np.max(raw):.4g} rad): an angle that wraps '
            "at a turn (an absolute encoder, a continuous joint's angle); it is unwrapped")
    return record.replace(position=position, notes=record.notes + (note,))


def is_voltage_speed(records: Sequence[Record], torque_constant: float | None = None) -> bool:
    """Whether records are identified as the voltage-to-speed model: no current anywhere."""
    return (torque_constant is None and bool(records)
            and all(rec.current is None and rec.voltage is not None for rec in records))


def common_period(records: Sequence[Record]) -> list[Record]:
    """
    Put records sampled at one period within :data:`PERIOD_RTOL` on that common period.

    The common period is the mean sample interval over all the records; each record's time
    becomes a uniform grid of it from its first instant (records already at one period are
    returned as they are).

    Raises
    ------
    InputDataError
        Periods that differ by more than :data:`PERIOD_RTOL` (relative).

    """
    periods = np.array([rec.sample_period_s for rec in records])
    if np.all(periods == periods[0]):
        return list(records)
    if np.max(periods) / np.min(periods) - 1.0 > PERIOD_RTOL:
        raise InputDataError(
            'the records have different sample periods ('
            + ', '.join(f'{p:.6g} s' for p in periods)
            + '); identify them separately or resample them to one period')
    period = (sum(float(rec.time_s[-1] - rec.time_s[0]) for rec in records)
              / sum(len(rec) - 1 for rec in records))
    return [rec.replace(time_s=rec.time_s[0] + period * np.arange(len(rec)))
            for rec in records]


def check_excitation(records: Sequence[Record], mechanical_only: bool) -> Excitation:
    """
    Refuse data that do not excite the motor at all; return how they move.

    Data that turn one way only are not refused (J, b and the direction's total friction
    torque are identified; the caller says so).

    Raises
    ------
    NotIdentifiableError
        A motor that never moves, or a constant voltage (a constant current in the
        mechanical-only mode) with the motor in steady state.

    """
    excitation = assess_excitation(records, mechanical_only)
    if not excitation.moves:
        raise NotIdentifiableError(
            'the motor never moves (speed stays within its noise): CPhi, J, b and Mc are not '
            'identifiable' + ('' if mechanical_only else ' (Ra and La would be, from the '
                              'current alone, but the model needs motion)')
            + '. Record while the motor turns, e.g. with a sine or PRBS voltage.')
    if excitation.constant_voltage_steady and mechanical_only:
        raise NotIdentifiableError(
            'the current is constant and the motor stays in steady state: only the '
            'steady-state balance K i = b w + Mc is seen, so J is not identifiable and b '
            'cannot be separated from Mc. Excite the motor with a changing current (steps '
            'between two non-zero levels, a sine, PRBS).')
    if excitation.constant_voltage_steady:
        raise NotIdentifiableError(
            'the voltage is constant and the motor stays in steady state: only the '
            'steady-state balance u = Ra i + CPhi w is seen, so La, J, b and Mc are not '
            'identifiable and Ra cannot be separated from CPhi. Excite the motor with a '
            'changing voltage (sine, sawtooth, PRBS, chirp; see dcmotor-id simulate).')
    return excitation


#: Samples at the start of a record a current step may take to settle.
SETTLE_SAMPLES = 3


def single_current_level(records: Sequence[Record]) -> float | None:
    """
    Return the level when every record's current is one constant value, else None.

    A current held by a current-controlled drive at one level (a torque step from rest, the
    first samples rising to it) is constant within its noise (or 2 % of the level).
    """
    settled = [np.asarray(rec.current, dtype=float)[SETTLE_SAMPLES:] for rec in records
               if rec.current is not None and len(rec) > 4 * SETTLE_SAMPLES]
    if not settled or len(settled) != len(records):
        return None
    joined = np.concatenate(settled)
    level = float(np.median(joined))
    band = max(6.0 * max(noise_std(values) for values in settled), 0.02 * abs(level))
    smooth = np.concatenate([np.convolve(values, np.ones(9) / 9, mode='valid')
                             for values in settled if len(values) >= 9])
    if level == 0.0 or smooth.size == 0 or np.max(np.abs(smooth - level)) > band:
        return None
    return level


def one_level_reason(level: float, failure: str) -> str:
    """Say why one constant current cannot separate J, b and Mc, and what to record."""
    return (f'the current is one constant level ({level:.4g} A) in every record and the fit '
            f'failed ({failure.split(":")[0]}): with a known torque constant a constant current '
            'shows only two numbers in the speed, the mechanical time constant J/b and the '
            'final speed (K i - Mc)/b; J, b and Mc are then separated only by the '
            "current's small fluctuations, too little here. Record a second current "
            'level (a step between two non-zero levels, or a step in the other '
            'direction) and give the records together')


register(Check('excitation', 'before_fit', 'records', check_excitation,
               'data that do not move the motor, or hold one current level, refused'))
