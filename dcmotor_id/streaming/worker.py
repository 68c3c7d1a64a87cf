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

from concurrent.futures import Future
import ctypes
from multiprocessing import get_context
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
import os
import queue
import signal
import sys
import threading
import time
from typing import Any, Callable, Optional, Sequence, Union

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.records import record_from_stamps
from dcmotor_id.formats.recording import WindowBagWriter
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.streaming.summary import format_line
from dcmotor_id.streaming.windowing import Window

#: ``prctl`` option: the signal a process gets when its parent dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1


def watch_parent(parent_pid: int, period_s: float = 1.0) -> None:
    """
    Exit this worker process when the node that started it is gone.

    The second line of defence after :func:`die_with_parent` (and the only one off Linux):
    a worker whose node was killed with SIGKILL would otherwise wait forever.
    """
    def watch():
        while True:
            time.sleep(period_s)
            if os.getppid() != parent_pid:
                os._exit(0)
    threading.Thread(target=watch, name='watch_parent', daemon=True).start()


def die_with_parent(parent_pid: int) -> bool:
    """
    Ask the kernel to kill this process with SIGKILL when its parent dies (Linux).

    ``prctl(PR_SET_PDEATHSIG)`` through ctypes: no polling, works even while the worker is
    stuck in a native call. The signal comes when the parent *thread* that started the
    process ends, so :class:`FitProcess` starts its workers from one long-lived thread.
    Returns whether the request was made; exits at once if the parent is already gone.
    """
    done = False
    if sys.platform.startswith('linux'):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            done = libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
        except (OSError, AttributeError):
            done = False
    if os.getppid() != parent_pid:  # died before the request took effect
        os._exit(0)
    return done


def serve(connection: Connection, parent_pid: int) -> None:
    """
    Run the jobs that come over ``connection`` until it closes (the worker process).

    A job is ``(function name, arguments)``; the answer is ``('ok', value)`` or
    ``('raised', 'Type: message')``. SIGINT is ignored (a Ctrl-C in the terminal reaches the
    whole process group; the node decides when its worker ends).
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent_pid)
    watch_parent(parent_pid)
    jobs: dict[str, Callable[..., Any]] = {'identify_windows': identify_windows,
                                           'warm_up': warm_up}
    warm_up()
    while True:
        try:
            job = connection.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        name, arguments = job
        try:
            answer: tuple[str, Any] = ('ok', jobs[name](*arguments))
        except Exception as error:  # noqa: BLE001  (reported to the node, never a dead worker)
            answer = ('raised', f'{type(error).__name__}: {error}')
        try:
            connection.send(answer)
        except (OSError, ValueError):
            return


def warm_up() -> bool:
    """Import the numerical modules (and load the numba cache) ahead of the first job."""
    from dcmotor_id.simulation import motor_system  # noqa: F401
    return True


def identify_windows(windows: Sequence[tuple[Any, dict, str]], method: str,
                     torque_constant: Optional[float], discover: bool,
                     compare_paper: bool, structure_bootstrap: int = 0) -> tuple[str, Any]:
    """
    Identify the motor from windows ``[(stamps_ns, channels, source), ...]``.

    ``structure_bootstrap`` noise resamples rerun the discovery so that the standard errors
    cover the choice of effects (``identify(..., structure_bootstrap=N)``; 0: not run).

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
        identified = identify(records, method=method, torque_constant=torque_constant,
                              discover=discover, structure_bootstrap=structure_bootstrap)
        result = identified.as_dict()
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


class FitTimeout(TimeoutError):
    """A fit took longer than its time limit; its process was killed and replaced."""


class FitProcess:
    """
    Run :func:`identify_windows` in a process of its own, or here with ``in_subprocess`` false.

    One long-lived thread starts the process (at once, so the first job finds the numerical
    modules imported), hands it the jobs and waits for each at most ``timeout_s``: a job
    that takes longer (a solver that does not converge) is ended by killing the process,
    which is replaced at once. A process that dies is replaced too. The process dies with
    the node (:func:`die_with_parent`, :func:`watch_parent`), even on SIGKILL. In-process
    (``in_subprocess`` false) a fit cannot be stopped, and ``timeout_s`` does not apply.
    """

    def __init__(self, in_subprocess: bool = True, timeout_s: Optional[float] = None) -> None:
        self.in_subprocess = in_subprocess
        self.timeout_s = timeout_s if timeout_s and timeout_s > 0 else None
        self.restarts = 0
        self._process: Optional[BaseProcess] = None
        self._connection: Optional[Connection] = None
        self._jobs: queue.Queue = queue.Queue()
        self._lock = threading.Lock()
        self._closing = False
        self._thread: Optional[threading.Thread] = None
        if in_subprocess:
            self._thread = threading.Thread(target=self._loop, name='fit_process', daemon=True)
            self._thread.start()

    @property
    def pid(self) -> Optional[int]:
        """Process id of the current worker (None in-process or before it started)."""
        process = self._process
        return process.pid if process is not None else None

    def _start(self) -> None:
        context = get_context('spawn')
        ours, theirs = context.Pipe()
        process = context.Process(target=serve, args=(theirs, os.getpid()),
                                  name='dcmotor_id_fit', daemon=True)
        process.start()
        theirs.close()
        with self._lock:
            self._process, self._connection = process, ours

    def _stop(self) -> None:
        """Kill the worker (if any) and wait for it."""
        with self._lock:
            process, connection = self._process, self._connection
            self._process = self._connection = None
        if process is not None:
            process.kill()
            process.join(timeout=10.0)
        if connection is not None:
            connection.close()

    def _loop(self) -> None:
        try:
            self._start()
        except Exception:  # noqa: BLE001  (retried with the first job, which reports it)
            self._stop()
        while True:
            item = self._jobs.get()
            if item is None or self._closing:
                self._stop()
                if item is not None:
                    item[1].set_exception(RuntimeError('the node is shutting down'))
                return
            arguments, future = item
            try:
                future.set_result(self._run_one(arguments))
            except BaseException as error:  # noqa: BLE001  (handed to the caller)
                future.set_exception(error)

    def _run_one(self, arguments: tuple) -> tuple[str, Any]:
        if self._process is None or not self._process.is_alive():
            self._stop()
            self._start()
        connection = self._connection
        assert connection is not None
        try:
            connection.send(('identify_windows', arguments))
            ready = connection.poll(self.timeout_s)
        except (OSError, ValueError, EOFError):
            ready = True  # broken pipe: the process died, recv below says so
        if not ready:
            self._stop()
            self.restarts += 1
            if not self._closing:
                self._start()
            raise FitTimeout(
                f'the fit did not finish within identify_timeout_s = {self.timeout_s:g} s; '
                'its process was stopped and a new one started. Call again; if it keeps '
                'happening, identify shorter windows (window_s), set discover false or raise '
                'identify_timeout_s')
        try:
            status, payload = connection.recv()
        except (EOFError, OSError, ValueError):
            self._stop()
            self.restarts += 1
            if not self._closing:
                self._start()
            raise RuntimeError('the identification process died; it was restarted, '
                               'call again') from None
        if status != 'ok':
            raise RuntimeError(payload)
        return payload

    def run(self, *arguments: Any) -> tuple[str, Any]:
        """Return ``identify_windows(*arguments)``; raise :class:`FitTimeout` or RuntimeError."""
        if not self.in_subprocess:
            return identify_windows(*arguments)
        future: Future = Future()
        self._jobs.put((arguments, future))
        return future.result()

    def identify(self, windows: Sequence[Window], method: str,
                 torque_constant: Optional[float], discover: bool,
                 compare_paper: bool, structure_bootstrap: int = 0) -> Union[dict, str]:
        """
        Wait until the windows are written, identify from them; return the result or why not.

        The result is that of :func:`identify_windows` plus ``bags``, ``record_errors`` and
        ``summary`` (:func:`dcmotor_id.streaming.summary.format_line`, followed by the plausibility
        warnings); a failure is a message (a timeout says so).
        """
        try:
            for window in windows:
                window.written.wait(timeout=30.0)
            status, result = self.run(
                [(window.stamps_ns, window.channels, window.source) for window in windows],
                method, torque_constant, discover, compare_paper, structure_bootstrap)
            if status != 'ok':
                return f'identification failed: {result}'
            result['bags'] = [window.path for window in windows if window.path]
            result['record_errors'] = [window.error for window in windows if window.error]
            warnings = result.get('warnings') or []
            result['summary'] = format_line(result) + ''.join(
                f'; warning: {text}' for text in warnings)
            return result
        except FitTimeout as error:
            return f'identification failed: {error}'
        except Exception as error:  # noqa: BLE001  (report, never kill the node)
            return f'identification failed unexpectedly: {type(error).__name__}: {error}'

    def shutdown(self) -> None:
        """Stop the process now, also in the middle of a job (which then fails)."""
        self._closing = True
        if self._thread is not None:
            self._jobs.put(None)
            self._stop()  # ends a running job at once: its recv fails
            self._thread.join(timeout=10.0)


class WindowRecorder:
    """
    Write windows as bags with a ``WindowBagWriter`` on a thread.

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
