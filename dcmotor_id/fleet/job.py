"""
The fleet job: every window of every recording identified as one task on a Dask cluster.

Dask does the scheduling, the retries and the data movement; this module only says what to
run. Per recording, one task reads it into windows (the samples stay on the worker that read
them), one small task returns the list of windows to the client, and one task per window
identifies it (Dask moves the recording's windows to whichever worker runs it). Results are
taken as they complete (``distributed.as_completed``); when all windows of a recording are in,
its rows are appended to the history, so an interrupted run loses at most the recordings in
flight. At most a few recordings per worker are read ahead, so worker memory stays bounded
on any fleet size. A task that raises a machine error is retried (``retries``); a task whose
worker dies is rescheduled by the scheduler (and reported as ``KilledWorker`` after
``distributed.scheduler.allowed-failures`` deaths); either way a failure ends as an error
row, never as the end of the batch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import logging
import os
import time
from typing import Any, Iterable, Optional
import uuid

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.fleet import history
from dcmotor_id.fleet.progress import Progress
from dcmotor_id.fleet.sources import check_motor_from, find_sources, Source
from dcmotor_id.fleet.tasks import (bag_plan, BagPlan, error_message, FleetOptions,
                                    identify_window, read_windows, window_columns)

#: Recordings read ahead per worker thread (bounds the samples held on the cluster).
READ_AHEAD_PER_THREAD = 2
#: Retries of a task that raised (a machine error) before it becomes an error row.
RETRIES = 2


@dataclass
class FleetSummary:
    """
    What a fleet run did.

    Attributes
    ----------
    found, skipped, done : int
        Recordings found, skipped (already in the history) and identified now.
    windows, failures : int
        Rows written for windows, and error rows (windows or whole recordings).
    files : list of str
        Parquet files appended to the history.
    elapsed_s : float
        Wall time of the run [s].
    workers : int
        Worker threads of the cluster.

    """

    found: int = 0
    skipped: int = 0
    done: int = 0
    windows: int = 0
    failures: int = 0
    files: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    workers: int = 0

    def text(self) -> str:
        """One line for the command's output."""
        return (f'{self.found} recordings found, {self.skipped} already in the history, '
                f'{self.done} identified: {self.windows} windows, {self.failures} failures, '
                f'{self.elapsed_s:.1f} s on {self.workers} workers')


@dataclass
class _Bag:
    """The client's book-keeping of one recording in flight."""

    source: Source
    read: Any
    plan: Any = None
    windows: dict[Any, tuple[str, int, int, int]] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)


def start_client(scheduler: Optional[str] = None, workers: Optional[int] = None) -> Any:
    """
    Connect to a Dask scheduler, or start a local cluster of worker processes.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler (``tcp://host:8786``); default a
        ``distributed.LocalCluster`` on this machine (127.0.0.1 only; its HTTP port is a free one).
    workers : int, optional
        Worker processes of the local cluster, 1 or more (one thread each; default one per
        core).

    Raises
    ------
    InputDataError
        For fewer than 1 worker (a cluster without workers waits forever).

    """
    from distributed import Client, LocalCluster
    if workers is not None and workers < 1:
        raise InputDataError(f'workers = {workers}: a local cluster needs 1 or more workers '
                             '(or none given: one per core)')
    if scheduler:
        return Client(scheduler)
    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                           processes=True, host='127.0.0.1', dashboard_address='127.0.0.1:0',
                           silence_logs=logging.ERROR)
    return Client(cluster)


def _threads(client: Any) -> int:
    info = client.scheduler_info()
    return max(1, sum(int(worker.get('nthreads', 1))
                      for worker in info.get('workers', {}).values()))


def run_fleet(paths: Iterable[str], history_dir: str, options: Optional[FleetOptions] = None,
              *, scheduler: Optional[str] = None, workers: Optional[int] = None,
              force: bool = False, client: Any = None, progress: Optional[Progress] = None,
              retries: int = RETRIES, flush_s: float = 30.0,
              flush_rows: int = 2000, retry_errors: bool = True) -> FleetSummary:
    """
    Identify every window of every recording under ``paths``; append the rows to the history.

    Parameters
    ----------
    paths : iterable of str
        Bags, files of the other formats (CSV, .mat, .parquet), or directories searched
        recursively for them.
    history_dir : str
        The Parquet dataset (created if needed).
    options : FleetOptions, optional
        Grouping by motor, torque constant, discovery, window length.
    scheduler : str, optional
        A running Dask scheduler's address; default a local cluster.
    workers : int, optional
        Worker processes of the local cluster (default one per core).
    force : bool
        Identify recordings already in the history again.
    client : distributed.Client, optional
        Use this client (its cluster is left running).
    progress : Progress, optional
        Where to show progress (default none).
    retries : int
        Retries of a task that raised.
    flush_s, flush_rows : float, int
        Append finished recordings to the history at least this often, or once this many
        rows wait.
    retry_errors : bool
        Identify again the recordings whose newest rows hold an error (default); False skips
        every recording already in the history.

    Raises
    ------
    InputDataError
        When a path does not exist, nothing is found, or ``--motor-from`` is not valid.

    """
    options = options or FleetOptions()
    check_motor_from(options.motor_from)
    paths = list(paths)
    began = time.monotonic()
    sources = find_sources(paths)
    if not sources:
        raise InputDataError(f'no bags, .mcap, .db3 or CSV files under {", ".join(paths)}')
    known = set() if force else history.known_sources(history_dir, retry_errors)
    todo = [source for source in sources if source.path not in known]
    summary = FleetSummary(found=len(sources), skipped=len(sources) - len(todo))
    if todo:
        own_client = client is None
        run = _FleetRun(start_client(scheduler, workers) if own_client else client,
                        history_dir, options, todo, summary, retries, (flush_s, flush_rows))
        run.run(progress, own_client)
    summary.elapsed_s = time.monotonic() - began
    return summary


class _FleetRun:
    """One run of the fleet on a client: recordings read ahead, windows identified, rows kept."""

    def __init__(self, client: Any, history_dir: str, options: FleetOptions,
                 todo: list[Source], summary: FleetSummary, retries: int,
                 flush_every: tuple[float, int]) -> None:
        from distributed import as_completed

        self.client, self.history_dir, self.options = client, history_dir, options
        self.todo, self.summary, self.retries = todo, summary, retries
        self.flush_s, self.flush_rows = flush_every
        self.run_id = uuid.uuid4().hex[:12]
        self.version = history.package_version()
        self.counts = {'windows': 0, 'known': 0, 'failures': 0}
        self.pending: list[dict[str, Any]] = []
        self.last_flush = time.monotonic()
        self.queue = list(reversed(todo))
        self.bags: dict[str, _Bag] = {}
        self.owner: dict[str, tuple[str, _Bag]] = {}
        self.completed = as_completed()

    def run(self, progress: Optional[Progress], own_client: bool) -> None:
        """Identify every recording; flush the rows and close an own client at the end."""
        try:
            self.summary.workers = _threads(self.client)
            read_ahead = READ_AHEAD_PER_THREAD * self.summary.workers + 1
            while self.queue and len(self.bags) < read_ahead:
                self.submit_bag()
            for future in self.completed:
                self.take(future, progress)
        finally:
            self.flush(final=True)
            if own_client:
                cluster = getattr(self.client, 'cluster', None)
                self.client.close()
                if cluster is not None:
                    cluster.close()
        self.summary.windows = self.counts['windows']
        self.summary.failures = self.counts['failures']
        if progress is not None:
            progress.update(self.summary.done, len(self.todo), self.counts['windows'],
                            self.counts['known'], self.counts['failures'], final=True)

    def submit_bag(self) -> None:
        """Submit the next recording's reading and planning."""
        source = self.queue.pop()
        number = len(self.todo) - len(self.queue)
        read = self.client.submit(read_windows, source, self.options, retries=self.retries,
                                  key=f'fleet-read-{self.run_id}-{number}')
        plan = self.client.submit(bag_plan, read, retries=self.retries, priority=1,
                                  key=f'fleet-plan-{self.run_id}-{number}')
        bag = _Bag(source, read, plan)
        self.bags[source.path] = bag
        self.owner[plan.key] = ('plan', bag)
        self.completed.add(plan)

    def take(self, future: Any, progress: Optional[Progress]) -> None:
        """Take a finished plan or window; finish its recording when nothing is left of it."""
        owner, counts = self.owner, self.counts
        kind, bag = owner.pop(future.key)
        if kind == 'plan':
            _planned(self.client, future, bag, self.options, self.retries, owner,
                     self.completed, counts)
        else:
            _identified(future, bag, counts)
        if kind == 'plan' and not bag.windows or kind == 'window' and not any(
                key in owner for key in bag.windows):
            self.finish(self.bags.pop(bag.source.path))
            bag.read = bag.plan = None  # release the samples on the cluster
            if self.queue:
                self.submit_bag()
        if progress is not None:
            planning = bool(self.queue) or any(kind == 'plan' for kind, _ in owner.values())
            progress.update(self.summary.done, len(self.todo), counts['windows'],
                            counts['known'], counts['failures'], planning=planning)

    def finish(self, bag: _Bag) -> None:
        """Stamp a finished recording's rows and queue them for the history."""
        stamp = _now()
        for row in bag.rows:
            row.update({'package_version': self.version, 'run_id': self.run_id,
                        'processed_at': stamp})
            self.counts['failures'] += row['status'] != 'ok'
        self.pending.extend(bag.rows)
        self.summary.done += 1
        self.flush()

    def flush(self, final: bool = False) -> None:
        """Append the waiting rows when it is time (or at the end)."""
        if self.pending and (final or len(self.pending) >= self.flush_rows or
                             time.monotonic() - self.last_flush >= self.flush_s):
            self.summary.files.append(history.write_rows(self.history_dir, self.pending,
                                                         self.run_id))
            self.pending = []
            self.last_flush = time.monotonic()


def _now() -> Any:
    import datetime
    return datetime.datetime.now(datetime.timezone.utc)


def _planned(client: Any, future: Any, bag: _Bag, options: FleetOptions, retries: int,
             owner: dict[str, tuple[str, _Bag]], completed: Any,
             counts: dict[str, int]) -> None:
    """Take a recording's plan: error rows for what could not be read, a task per window."""
    try:
        plan: BagPlan = future.result()
    except Exception as error:  # noqa: BLE001  (after Dask's retries: the recording's row)
        plan = BagPlan([], [('', f'{bag.source.path}: {error_message(error)}')])
    for motor, message in plan.errors:
        row = history.error_row(message)
        row.update(window_columns(bag.source, motor, -1, None, None))
        bag.rows.append(row)
    for position, (motor, index, start_ns, end_ns) in enumerate(plan.windows):
        window = client.submit(identify_window, bag.read, position, options, retries=retries,
                               priority=2, key=f'{future.key}-window-{position}'.replace(
                                   'fleet-plan', 'fleet-identify'))
        bag.windows[window.key] = (motor, index, start_ns, end_ns)
        owner[window.key] = ('window', bag)
        completed.add(window)
    counts['known'] += len(plan.windows)


def _identified(future: Any, bag: _Bag, counts: dict[str, int]) -> None:
    """Take a window's row, or make an error row of the task's failure."""
    try:
        row = future.result()
    except Exception as error:  # noqa: BLE001  (after Dask's retries: the window's row)
        motor, index, start_ns, end_ns = bag.windows[future.key]
        row = history.error_row(error_message(error))
        row.update(window_columns(bag.source, motor, index, start_ns, end_ns))
    bag.rows.append(row)
    counts['windows'] += 1
