"""
The fleet history: one Parquet row per identified window, appended as files of a dataset.

Each run appends ``part-<UTC time>-<run>.parquet`` files under the history directory, written
under a hidden temporary name and renamed when complete (a reader never sees half a file; the
dataset readers skip hidden names). A bag's rows are always written together, so a bag is
either wholly in the history or not at all; :func:`known_sources` is what makes re-runs skip
it. With ``--force`` a bag is identified again and its new rows are appended;
:func:`read_history` keeps only the newest run of every bag.

Columns (:data:`SCHEMA`): the motor, the bag, the window (index, start and end [ns], sample
period, samples), the status (``ok`` or ``error`` with its message), every parameter and its
standard error, the effects (name and parameters as JSON), the held-out simulation errors
before and after discovery, ``unexplained``, the method and mode, ``warnings``, the package
version, the run, the worker and the task's time. Keys of the identification JSON that this
module does not know yet are appended as text columns (JSON for non-text values), so new
fields of ``dcmotor-id identify`` reach the history without a change here.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import sys
from typing import Any, Iterable, Mapping, Optional, Sequence
import uuid

import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq

from dcmotor_id.core.model import DERIVED_NAMES, PARAMETER_NAMES

#: Parameters with a value and a standard-error column each.
PARAMETERS = PARAMETER_NAMES + DERIVED_NAMES
#: Channels of the simulation-error columns.
ERROR_CHANNELS = ('current_nrmse_pct', 'speed_nrmse_pct')
#: Identification JSON keys not stored (bulky or repeated elsewhere).
IGNORED_KEYS = frozenset({'initial_states', 'noise_std', 'records', 'units', 'discovery',
                          'discover', 'n_samples', 'sample_period_s', 'parameters', 'stderr',
                          'effects', 'error_before', 'error_after', 'unexplained', 'method',
                          'mode', 'torque_constant', 'warnings'})
#: Type of the ``effects`` column.
EFFECT_TYPE = pa.list_(pa.struct([('name', pa.string()), ('parameters', pa.string())]))

SCHEMA = pa.schema(
    [('motor_id', pa.string()), ('source_bag', pa.string()), ('window_index', pa.int32()),
     ('window_start_ns', pa.int64()), ('window_end_ns', pa.int64()),
     ('sample_period_s', pa.float64()), ('n_samples', pa.int64()),
     ('status', pa.string()), ('error', pa.string()),
     ('method', pa.string()), ('mode', pa.string()), ('torque_constant', pa.float64())]
    + [(name, pa.float64()) for name in PARAMETERS]
    + [(f'{name}_stderr', pa.float64()) for name in PARAMETERS]
    + [('effects', EFFECT_TYPE), ('effect_names', pa.list_(pa.string()))]
    + [(f'error_{when}_{channel}', pa.float64()) for when in ('before', 'after')
       for channel in ERROR_CHANNELS]
    + [('unexplained', pa.bool_()), ('warnings', pa.list_(pa.string())),
       ('package_version', pa.string()), ('run_id', pa.string()),
       ('processed_at', pa.timestamp('us', tz='UTC')), ('worker', pa.string()),
       ('elapsed_s', pa.float64())])
#: Prefix of the files of the dataset.
PART_PREFIX = 'part-'


def package_version() -> str:
    """Return the installed version of dcmotor_id (``unknown`` when not installed)."""
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version('dcmotor_id')
    except PackageNotFoundError:
        return 'unknown'


def _number(value: Any) -> Optional[float]:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _text(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value, default=str, sort_keys=True)


def result_row(result: Mapping[str, Any]) -> dict[str, Any]:
    """
    Turn the identification JSON (``IdentificationResult.as_dict()``) into history columns.

    Known keys go to their columns; ``warnings`` (a list) to the list column; every other key
    not in :data:`IGNORED_KEYS` to a text column of its own name.
    """
    parameters = result.get('parameters') or {}
    stderr = result.get('stderr') or {}
    row: dict[str, Any] = {'status': 'ok', 'error': None,
                           'method': result.get('method'), 'mode': result.get('mode'),
                           'torque_constant': _number(result.get('torque_constant'))}
    for name in PARAMETERS:
        row[name] = _number(parameters.get(name))
        row[f'{name}_stderr'] = _number(stderr.get(name))
    effects = list(result.get('effects') or [])
    row['effects'] = [{'name': str(effect.get('name')),
                       'parameters': _text(effect.get('parameters', {}))} for effect in effects]
    row['effect_names'] = [str(effect.get('name')) for effect in effects]
    for when in ('before', 'after'):
        errors = result.get(f'error_{when}') or {}
        for channel in ERROR_CHANNELS:
            row[f'error_{when}_{channel}'] = _number(errors.get(channel))
    row['unexplained'] = bool(result.get('unexplained', False))
    warnings = result.get('warnings') or []
    row['warnings'] = [_text(item) for item in
                       (warnings if isinstance(warnings, (list, tuple)) else [warnings])]
    for key, value in result.items():
        if key not in IGNORED_KEYS and key not in SCHEMA.names and value is not None:
            row[key] = _text(value)
    return row


def error_row(message: str) -> dict[str, Any]:
    """Return the columns of a window or bag that could not be identified."""
    return {'status': 'error', 'error': message, 'effects': [], 'effect_names': [],
            'warnings': []}


def rows_table(rows: Sequence[Mapping[str, Any]]) -> pa.Table:
    """Build a table of rows in :data:`SCHEMA`, plus text columns for unknown keys."""
    extra = sorted({key for row in rows for key in row} - set(SCHEMA.names))
    schema = pa.schema(list(SCHEMA) + [(key, pa.string()) for key in extra])
    columns = {name: [row.get(name) for row in rows] for name in schema.names}
    return pa.Table.from_pydict(columns, schema=schema)


def write_rows(history_dir: str, rows: Sequence[Mapping[str, Any]], run_id: str) -> str:
    """
    Append rows to the history as one new Parquet file; return its path.

    The file is written under a hidden name and renamed, so readers never see it half done.
    """
    os.makedirs(history_dir, exist_ok=True)
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y%m%dT%H%M%S%fZ')
    name = f'{PART_PREFIX}{stamp}-{run_id}-{uuid.uuid4().hex[:8]}.parquet'
    temporary = os.path.join(history_dir, f'.{name}.tmp')
    pq.write_table(rows_table(rows), temporary)
    path = os.path.join(history_dir, name)
    os.replace(temporary, path)
    return path


def part_files(history_dir: str) -> list[str]:
    """Return the dataset's files, oldest first."""
    if not os.path.isdir(history_dir):
        return []
    return sorted(os.path.join(history_dir, name) for name in os.listdir(history_dir)
                  if name.startswith(PART_PREFIX) and name.endswith('.parquet'))


#: Unreadable part files already reported (each is named once per process).
_REPORTED: set[str] = set()


def readable_parts(history_dir: str) -> tuple[list[str], list[pa.Schema]]:
    """
    Return the part files that are Parquet files of a compatible schema, and their schemas.

    A damaged or foreign ``part-*.parquet`` (a truncated copy, another program's file) is
    skipped and named once on stderr: one bad file never hides the rest of the history.
    """
    files, schemas = [], []
    for path in part_files(history_dir):
        try:
            schema = pq.read_schema(path)
            pa.unify_schemas([SCHEMA, schema])
            if 'source_bag' not in schema.names or 'status' not in schema.names:
                raise ValueError('no source_bag or status column: not a fleet history file')
        except (OSError, ValueError, pa.ArrowException) as error:
            if path not in _REPORTED:
                _REPORTED.add(path)
                print(f'dcmotor-id: warning: {path}: not a readable fleet history file '
                      f'({str(error).splitlines()[0] if str(error) else type(error).__name__}); '
                      'skipped: move it out of the history directory or delete it',
                      file=sys.stderr)
            continue
        files.append(path)
        schemas.append(schema)
    return files, schemas


def read_history(history_dir: str, latest: bool = True,
                 columns: Optional[Iterable[str]] = None) -> pa.Table:
    """
    Read the history as one table.

    The schemas of all files are unified: columns that newer files added are null in older
    rows.

    Parameters
    ----------
    history_dir : str
        The history directory.
    latest : bool
        Keep only the newest run of every bag (what ``--force`` redid replaces the old rows).
    columns : iterable of str, optional
        Read only these columns (``source_bag``, ``run_id`` and ``processed_at`` are added
        when ``latest`` needs them).

    """
    files, schemas = readable_parts(history_dir)
    if not files:
        return SCHEMA.empty_table()
    schema = pa.unify_schemas(schemas)
    wanted = None
    if columns is not None:
        wanted = list(dict.fromkeys(list(columns) + (['source_bag', 'run_id', 'processed_at']
                                                     if latest else [])))
        wanted = [name for name in wanted if name in schema.names]
    table = pads.dataset(files, schema=schema, format='parquet').to_table(columns=wanted)
    if latest and table.num_rows:
        table = _newest_runs(table)
    return table


def _newest_runs(table: pa.Table) -> pa.Table:
    bags = table.column('source_bag').to_pylist()
    runs = table.column('run_id').to_pylist()
    times = table.column('processed_at').to_pylist()
    newest: dict[str, tuple[tuple[bool, Any], str]] = {}
    for bag, run, when in zip(bags, runs, times):
        order = (when is not None, when)  # a row without a time is the oldest
        if bag not in newest or (order[0] and (not newest[bag][0][0] or
                                               when > newest[bag][0][1])):
            newest[bag] = (order, run)
    keep = [newest[bag][1] == run for bag, run in zip(bags, runs)]
    return table.filter(pa.array(keep))


def known_sources(history_dir: str, retry_errors: bool = True) -> set[str]:
    """
    Return the bags (absolute paths) the history holds rows of.

    With ``retry_errors`` (the default), a bag whose newest run has an error row is not
    known: it is identified again on the next run (it may have been repaired, or have
    vanished mid-run), instead of being skipped forever.
    """
    table = read_history(history_dir, latest=retry_errors,
                         columns=['source_bag', 'status'])
    if not table.num_rows:
        return set()
    bags = table.column('source_bag').to_pylist()
    if not retry_errors:
        return set(bags)
    failed = {bag for bag, status in zip(bags, table.column('status').to_pylist())
              if status != 'ok'}
    return set(bags) - failed
