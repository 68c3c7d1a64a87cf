"""
WPILib SysId's JSON data files: the four tests of a characterisation routine, one record.

The SysId tool of WPILib (before 2024) saved its data as a JSON object with the tests
``slow-forward``, ``slow-backward``, ``fast-forward`` and ``fast-backward`` (quasistatic ramps
and dynamic steps), each a list of samples, and ``test`` (the mechanism), ``units`` and
``unitsPerRotation``.  A sample of a mechanism is ``[time s, voltage V, position, velocity]``;
of a ``Drivetrain`` ``[time, left voltage, right voltage, left position, right position, left
velocity, right velocity, gyro angle, gyro rate]`` (``--joint left|right`` chooses the side,
left by default).  Positions and velocities are in ``units``, ``unitsPerRotation`` of them a
revolution of the shaft the encoder measures: they are read as rad and rad/s of that shaft.

There is no current: the tests give the voltage-to-speed model (kS, kV, kA).  The tests are
put one after the other on a uniform grid of their median sample step (their stamps jitter:
a logger stamping on arrival), each marked by its number in the record's segment column
(:attr:`~dcmotor_id.core.records.Record.segment`), so that each is fitted as a record of its
own (:mod:`dcmotor_id.identification.pipeline.segments`).
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.records import PathLike, Record
from dcmotor_id.formats.mapping import DEFAULT_OPTIONS, note, ReadOptions

__all__ = ['is_sysid_json', 'read_sysid_json', 'SYSID_TESTS']

#: The tests of a SysId data file, in the order they are put in the record.
SYSID_TESTS = ('slow-forward', 'slow-backward', 'fast-forward', 'fast-backward')
#: Columns of (voltage, position, velocity) in a sample, by mechanism and drivetrain side.
SAMPLE_COLUMNS = {'mechanism': (1, 2, 3), 'left': (1, 3, 5), 'right': (2, 4, 6)}


def is_sysid_json(path: PathLike) -> bool:
    """Say whether a file is a JSON object (its first character that is not blank is ``{``)."""
    with open(path, 'rb') as stream:
        start = stream.read(256).lstrip(b'\xef\xbb\xbf \t\r\n')
    return start.startswith(b'{')


def _side(data: dict, options: ReadOptions, path: PathLike) -> str:
    """Return which columns to read: a mechanism's, or a drivetrain's left or right side."""
    if str(data.get('test', '')).lower() != 'drivetrain':
        return 'mechanism'
    side = (options.joint or 'left').lower()
    if side not in ('left', 'right'):
        raise InputDataError(f'{path}: a SysId drivetrain file has a left and a right side; '
                             f'give --joint left or --joint right, not {options.joint!r}')
    return side


def _tests(data: Any, path: PathLike) -> list[tuple[str, np.ndarray]]:
    """Return the tests present, each as an array of samples (one row each)."""
    if not isinstance(data, dict) or not any(name in data for name in SYSID_TESTS):
        raise InputDataError(f'{path}: a JSON file, but not a WPILib SysId data file (no '
                             f'{", ".join(SYSID_TESTS)}); give a CSV, .mat, Parquet, bag or '
                             'DataLog of the record')
    tests = []
    for name in SYSID_TESTS:
        if name not in data:
            continue
        try:
            samples = np.asarray(data[name], dtype=float)
        except (TypeError, ValueError):
            raise InputDataError(f'{path}: SysId test {name!r}: the samples are not lists of '
                                 'numbers') from None
        if samples.ndim != 2 or samples.shape[1] < 4 or samples.shape[0] < 2:
            raise InputDataError(f'{path}: SysId test {name!r}: expected rows of [time, '
                                 f'voltage, position, velocity], got shape {samples.shape}')
        tests.append((name, samples))
    return tests


def read_sysid_json(path: PathLike, options: ReadOptions = DEFAULT_OPTIONS) -> Record:
    """
    Read a WPILib SysId JSON data file: its tests one after the other, marked as tests.

    Raises
    ------
    InputDataError
        A JSON file that is not a SysId data file, malformed samples, or a drivetrain side
        that does not exist.

    """
    if not os.path.isfile(path):
        raise InputDataError(f'{path}: no such file')
    try:
        with open(path, encoding='utf-8-sig') as stream:
            data = json.load(stream)
    except (ValueError, UnicodeDecodeError) as error:
        raise InputDataError(f'{path}: not a readable JSON file ({error})') from None
    tests = _tests(data, path)
    side = _side(data, options, path)
    voltage_at, position_at, velocity_at = SAMPLE_COLUMNS[side]
    per_rotation = float(data.get('unitsPerRotation') or 2.0 * math.pi)
    factor = 2.0 * math.pi / per_rotation
    steps = np.concatenate([np.diff(samples[:, 0]) for _, samples in tests])
    period = float(np.median(steps)) if options.sample_period_s is None \
        else options.sample_period_s
    if not period > 0:
        raise InputDataError(f'{path}: the SysId time stamps do not increase; give the sample '
                             'period with --sample-period S')
    rows = np.vstack([samples for _, samples in tests])
    segment = np.concatenate([np.full(samples.shape[0], number, dtype=float)
                              for number, (_, samples) in enumerate(tests, start=1)])
    note(f'{path}: read as a WPILib SysId data file ({data.get("test", "?")}'
         f'{"" if side == "mechanism" else ", " + side + " side"}, {data.get("units", "?")}, '
         f'{per_rotation:.6g} per revolution): its tests {", ".join(n for n, _ in tests)} as '
         f'tests 1-{len(tests)}, one after the other on a grid of {period:.6g} s (their '
         'median step; the stamps are not used)')
    return Record(np.arange(rows.shape[0]) * period, voltage=rows[:, voltage_at],
                  speed=rows[:, velocity_at] * factor, position=rows[:, position_at] * factor,
                  source=str(path), segment=segment)
