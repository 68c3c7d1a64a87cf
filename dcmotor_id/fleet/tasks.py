"""
The work done on the cluster's workers: reading a recording into windows, identifying one.

These are plain functions of picklable arguments (Dask ships them to the workers). A problem
with the data (a bag that cannot be read, a window that does not identify the motor) is
returned as an error, so that it becomes a row of the history and the batch goes on; only
failures of the machine (out of memory, lost files) are raised, for Dask to retry.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import os
import socket
import time
from typing import Any, Optional
import warnings

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.fleet.sources import describe_topics, file_motor_id, motor_streams, Source
from dcmotor_id.fleet.windows import cut_windows, FleetWindow

#: Exceptions that are the machine's, not the data's: raised so that Dask retries the task.
MACHINE_ERRORS = (MemoryError, OSError)


@dataclass(frozen=True)
class FleetOptions:
    """
    How the fleet is identified (the same for every task).

    Attributes
    ----------
    motor_from : str
        ``namespace``, ``path`` or a regular expression (see
        :func:`dcmotor_id.fleet.sources.motor_streams`).
    torque_constant : float or None
        Mechanical-only mode with this torque constant [N m/A].
    discover : bool
        Run the effect discovery loop on every window.
    window_s : float
        Window length [s] (the identifier node's default).
    min_window_s : float, optional
        Shortest last window kept [s]; default half a window.

    """

    motor_from: str = 'namespace'
    torque_constant: Optional[float] = None
    discover: bool = True
    window_s: float = 10.0
    min_window_s: Optional[float] = None

    @property
    def shortest_s(self) -> float:
        """Return the shortest window kept [s]."""
        return self.min_window_s if self.min_window_s is not None else 0.5 * self.window_s


@dataclass
class BagWindows:
    """
    What reading one recording gave: its windows and what could not be read.

    Attributes
    ----------
    source : Source
        The recording.
    windows : list of FleetWindow
        Every window of every motor, in order.
    errors : list of tuple
        ``(motor_id or '', message)`` of what could not be read.
    warnings : list of str
        Warnings while reading (a truncated MCAP file recovered), copied to every row.
    data_loss : list of str
        What of them says data were lost (a truncated or damaged bag): every row of the
        recording gets it in its ``data_loss`` column, so the history marks the rows.

    """

    source: Source
    windows: list[FleetWindow] = field(default_factory=list)
    errors: list[tuple[str, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    data_loss: list[str] = field(default_factory=list)

    def plan(self) -> 'BagPlan':
        """Return the small summary the client schedules from (no samples)."""
        return BagPlan([(window.motor_id, window.index, window.start_ns, window.end_ns)
                        for window in self.windows], list(self.errors))


@dataclass(frozen=True)
class BagPlan:
    """The windows of a recording as ``(motor, index, start_ns, end_ns)`` and its errors."""

    windows: list[tuple[str, int, int, int]]
    errors: list[tuple[str, str]]


def error_message(error: BaseException) -> str:
    """Return an error's message; one that is not the package's own is led by its type."""
    text = str(error) or type(error).__name__
    return text if isinstance(error, DcMotorIdError) else f'{type(error).__name__}: {text}'


def worker_name() -> str:
    """Return ``host:pid`` of this process (the worker a row was computed on)."""
    return f'{socket.gethostname()}:{os.getpid()}'


def _first_stamps(path: str, motors: dict[str, dict[str, str]]) -> dict[str, int]:
    """Return the first message time [ns] of each motor's topics (the bag's own clock)."""
    from dcmotor_id.formats.bag import open_bag
    first = {}
    with open_bag(path) as source:
        for motor, channels in motors.items():
            stamps = []
            for topic in channels.values():
                if topic in source.topics:
                    message = next(iter(source.messages((topic,))), None)
                    if message is not None:
                        stamps.append(message[1])
            first[motor] = min(stamps) if stamps else 0
    return first


def read_windows(source: Source, options: FleetOptions) -> BagWindows:
    """
    Read one recording, group its streams by motor and cut every motor's record into windows.

    A file that is not a bag (CSV, MATLAB, Parquet, ...) is one motor whose windows start at
    its first time stamp (seconds from 0 if the file's time starts there). Errors of the data
    are returned in :attr:`BagWindows.errors`.
    """
    from dcmotor_id.formats import read_record
    from dcmotor_id.formats.bag import DamagedBagWarning, open_bag, read_bag, TruncatedBagWarning

    result = BagWindows(source)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            if source.kind != 'bag':
                motor = file_motor_id(source, options.motor_from)
                record = read_record(source.path,
                                     mechanical_only=options.torque_constant is not None)
                start_ns = int(round(float(record.time_s[0]) * 1e9)) if len(record) else 0
                record = record.replace(time_s=record.time_s - record.time_s[0])
                result.windows.extend(cut_windows(record, start_ns, motor, options.window_s,
                                                  options.shortest_s))
            else:
                with open_bag(source.path) as bag:
                    topics = dict(bag.topics)
                motors = motor_streams(source, topics, options.motor_from)
                if not motors:
                    result.errors.append(('', f'{source.path}: no motor streams (topics '
                                              'ending in voltage, current, speed, or samples); '
                                              f'it has {describe_topics(topics)}'))
                starts = _first_stamps(source.path, motors) if motors else {}
                for motor, channels in motors.items():
                    try:
                        record = read_bag(source.path, topics=channels)
                        result.windows.extend(cut_windows(record, starts[motor], motor,
                                                          options.window_s,
                                                          options.shortest_s))
                    except MACHINE_ERRORS:
                        raise
                    except Exception as error:  # noqa: BLE001  (a motor's data: its row)
                        result.errors.append((motor, error_message(error)))
        except MACHINE_ERRORS:
            raise
        except Exception as error:  # noqa: BLE001  (any problem of the data: an error row)
            result.errors.append(('', error_message(error)))
    result.warnings.extend(str(item.message) for item in caught)
    result.data_loss.extend(str(item.message) for item in caught
                            if issubclass(item.category, (DamagedBagWarning,
                                                          TruncatedBagWarning)))
    if not result.windows and not result.errors:
        result.errors.append(('', f'{source.path}: no window of at least '
                                  f'{options.shortest_s:g} s'))
    return result


def bag_plan(bag: BagWindows) -> BagPlan:
    """Return the plan of a read recording (a task of its own: only this goes to the client)."""
    return bag.plan()


def identify_window(bag: BagWindows, index: int, options: FleetOptions) -> dict[str, Any]:
    """
    Identify window ``index`` of a read recording; return its history row.

    The row holds the identification JSON's values (see
    :func:`dcmotor_id.fleet.history.result_row`) or the error message, plus where and how
    long it ran.
    """
    from dcmotor_id.fleet.history import error_row, result_row
    from dcmotor_id.identification.checks.dropouts import repair_all
    from dcmotor_id.identification.identify import identify, prepare_records

    window = bag.windows[index]
    began = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            records, repairs = repair_all(prepare_records([window.record],
                                                          options.torque_constant))
            for note in repairs:
                warnings.warn(note)
            result = identify(records, torque_constant=options.torque_constant,
                              discover=options.discover)
            row = result_row(result.as_dict())
        except MACHINE_ERRORS:
            raise
        except Exception as error:  # noqa: BLE001  (the window's data: an error row)
            row = error_row(error_message(error))
    record = window.record
    row.update(window_columns(bag.source, window.motor_id, window.index, window.start_ns,
                              window.end_ns))
    row['sample_period_s'] = record.sample_period_s if len(record) > 1 else None
    row['n_samples'] = len(record)
    row['warnings'] = list(bag.warnings) + list(row.get('warnings') or []) + \
        [str(item.message) for item in caught]
    if bag.data_loss:
        row['data_loss'] = '; '.join(dict.fromkeys(bag.data_loss))
    row['worker'] = worker_name()
    row['elapsed_s'] = time.perf_counter() - began
    return row


def window_columns(source: Source, motor_id: str, index: int, start_ns: Optional[int],
                   end_ns: Optional[int]) -> dict[str, Any]:
    """Return the columns that say which window of which motor and recording a row is."""
    return {'motor_id': motor_id, 'source_bag': source.path, 'window_index': index,
            'window_start_ns': start_ns, 'window_end_ns': end_ns}
