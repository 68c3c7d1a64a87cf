"""
The identifier node's work off the executor: writing windows and fitting them (no ROS here).

:class:`WindowRecorder` writes the closed windows as bags on a thread of its own. The fit job
(:func:`identify_windows`) gets the windows as plain arrays, builds the records exactly as
:func:`dcmotor_id.formats.bag.read_bag` does, runs the chosen method and, for comparison,
the paper's.
In a process of its own (:class:`FitProcess`) the fit neither holds the node's interpreter
lock nor shares its core, so the executor keeps taking samples at full rate while it runs.
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
import os
import queue
import threading
import time
from typing import Any, Callable, Optional, Sequence, Union

from dcmotor_id.errors import DcMotorIdError
from dcmotor_id.identify import identify, prepare_records
from dcmotor_id.recording import WindowBagWriter
from dcmotor_id.records import record_from_stamps
from dcmotor_id.summary import format_line
from dcmotor_id.windowing import Window


def watch_parent(parent_pid: int, period_s: float = 1.0) -> None:
    """
    Exit this worker process when the node that started it is gone.

    Pool workers hold both ends of their job queue, so a node killed with SIGKILL would
    otherwise leave them waiting forever. Runs as the pool's initializer.
    """
    def watch():
        while True:
            time.sleep(period_s)
            if os.getppid() != parent_pid:
                os._exit(0)
    threading.Thread(target=watch, name='watch_parent', daemon=True).start()


def warm_up() -> bool:
    """Import the numerical modules (and load the numba cache) ahead of the first job."""
    from dcmotor_id.simulation import motor_system  # noqa: F401
    return True


def identify_windows(windows: Sequence[tuple[Any, dict, str]], method: str,
                     torque_constant: Optional[float], discover: bool,
                     compare_paper: bool) -> tuple[str, Any]:
    """
    Identify the motor from windows ``[(stamps_ns, channels, source), ...]``.

    Returns
    -------
    tuple
        ``('ok', result)`` with the result dict (``identify(...).as_dict()``) plus
        ``paper`` (the paper method's result, its error message, or None), or
        ``('error', message)`` when the data cannot identify the motor.

    """
    try:
        records = prepare_records([record_from_stamps(stamps, channels, source)
                                   for stamps, channels, source in windows], torque_constant)
        result = identify(records, method=method, torque_constant=torque_constant,
                          discover=discover).as_dict()
    except DcMotorIdError as error:
        return 'error', str(error)
    paper: dict[str, Any] | str | None = None
    if compare_paper and method != 'paper':
        try:
            paper = identify(records, method='paper', torque_constant=torque_constant,
                             discover=False).as_dict()
        except DcMotorIdError as error:
            paper = str(error)
    result['paper'] = paper
    return 'ok', result


class FitProcess:
    """
    Run :func:`identify_windows` in a process of its own, or here with ``in_subprocess`` false.

    The process starts with the first job (and imports the numerical modules at once); when
    it dies, a new one is started and the job fails with a message saying so.
    """

    def __init__(self, in_subprocess: bool = True) -> None:
        self.in_subprocess = in_subprocess
        self._pool: Optional[ProcessPoolExecutor] = None

    def _start(self) -> ProcessPoolExecutor:
        pool = ProcessPoolExecutor(max_workers=1, mp_context=get_context('spawn'),
                                   initializer=watch_parent, initargs=(os.getpid(),))
        pool.submit(warm_up)
        return pool

    def run(self, *arguments: Any) -> tuple[str, Any]:
        """Return ``identify_windows(*arguments)``; raise ``RuntimeError`` if the process died."""
        if not self.in_subprocess:
            return identify_windows(*arguments)
        if self._pool is None:
            self._pool = self._start()
        try:
            return self._pool.submit(identify_windows, *arguments).result()
        except BrokenProcessPool:
            self._pool = self._start()
            raise RuntimeError('the identification process died; it was restarted, '
                               'call again') from None

    def identify(self, windows: Sequence[Window], method: str,
                 torque_constant: Optional[float], discover: bool,
                 compare_paper: bool) -> Union[dict, str]:
        """
        Wait until the windows are written, identify from them; return the result or why not.

        The result is that of :func:`identify_windows` plus ``bags``, ``record_errors`` and
        ``summary`` (:func:`dcmotor_id.summary.format_line`); a failure is a message.
        """
        try:
            for window in windows:
                window.written.wait(timeout=30.0)
            status, result = self.run(
                [(window.stamps_ns, window.channels, window.source) for window in windows],
                method, torque_constant, discover, compare_paper)
            if status != 'ok':
                return f'identification failed: {result}'
            result['bags'] = [window.path for window in windows if window.path]
            result['record_errors'] = [window.error for window in windows if window.error]
            result['summary'] = format_line(result)
            return result
        except Exception as error:  # noqa: BLE001  (report, never kill the node)
            return f'identification failed unexpectedly: {type(error).__name__}: {error}'

    def shutdown(self) -> None:
        """Stop the process without waiting for a job that runs."""
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)


class WindowRecorder:
    """
    Write windows as bags with a :class:`~dcmotor_id.recording.WindowBagWriter` on a thread.

    Parameters
    ----------
    record_dir : str
        Directory of the bags (``~`` is expanded).
    log : callable
        ``log(level, text)`` with level ``'info'``, ``'warning'`` or ``'error'``.
    **options
        ``disk_budget_bytes``, ``batch_samples`` and ``min_free_bytes`` of the writer.

    Attributes
    ----------
    writer : WindowBagWriter or None
        None while the directory cannot be written (retried with every window).
    error : str or None
        Why the latest window was not recorded (None once one is).

    """

    def __init__(self, record_dir: str, log: Callable[[str, str], None],
                 **options: int) -> None:
        self.record_dir = os.path.expanduser(record_dir)
        self.writer: Optional[WindowBagWriter] = None
        self.error: Optional[str] = None
        self._log = log
        self._options = options
        self._queue: queue.Queue = queue.Queue()
        self._open()
        self._thread = threading.Thread(target=self._loop, name='window_writer', daemon=True)
        self._thread.start()

    def _open(self) -> None:
        try:
            self.writer = WindowBagWriter(self.record_dir, self._options['disk_budget_bytes'],
                                          batch_samples=self._options['batch_samples'],
                                          min_free_bytes=self._options['min_free_bytes'])
            for path in self.writer.removed_partials:
                self._log('warning', f'removed an unfinished window left by a killed run: '
                          f'{path}')
            self.error = None
        except OSError as error:
            self.writer = None
            self.error = (f'cannot record to {self.record_dir}: {error.strerror or error}; '
                          'set record_dir to a writable directory')
            self._log('error', self.error)

    def put(self, window: Window) -> None:
        """Queue a window; its ``written`` event is set once it is written (or failed)."""
        self._queue.put(window)

    def _loop(self) -> None:
        while True:
            window = self._queue.get()
            if window is None:
                return
            try:
                if self.writer is None:
                    self._open()
                if self.writer is None:
                    window.error = self.error
                    continue
                window.path = self.writer.write(window.stamps_ns, window.channels)
                for path in self.writer.deleted:
                    self._log('info', f'disk budget: deleted the oldest window {path}')
                self.writer.deleted.clear()
                self.error = None
            except Exception as error:  # noqa: BLE001  (a full disk must not stop the node)
                window.error = f'window {window.number} not recorded: {error}'
                self.error = window.error
                self._log('error', window.error)
            finally:
                window.written.set()

    def close(self, timeout_s: float = 30.0) -> None:
        """Write what is queued, then stop the thread."""
        self._queue.put(None)
        self._thread.join(timeout=timeout_s)
