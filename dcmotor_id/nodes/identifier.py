"""
``identifier``: aligns a drive's streams, records windows as bags, identifies on request.

Inputs (relative names, remappable), by ``input``:

* ``float64`` (default): ``voltage``, ``current``, ``speed`` (``std_msgs/msg/Float64``). With
  ``align_by: sequence`` the n-th message published on each topic is sample n (the DDS
  publication sequence number says which, so lost, late, duplicated and reordered messages
  land on the right sample); with ``align_by: timestamp`` the DDS source timestamp is rounded
  to the sample grid.
* ``batch``: ``samples`` (``std_msgs/msg/Float64MultiArray``, layout
  :data:`dcmotor_id.io.BATCH_LABEL`): many samples a message, for 10 kHz and more.
* ``joint_state``: ``joint_states`` (``sensor_msgs/msg/JointState``; speed from
  ``velocity``, current from ``effort`` times ``effort_scale``, both at ``header.stamp``) plus
  ``voltage`` by its source timestamp, or no voltage when ``torque_constant`` > 0
  (mechanical-only identification of J, b, Mc).

Outputs: ``~/parameters`` (``diagnostic_msgs/msg/DiagnosticStatus``, TRANSIENT_LOCAL depth 1:
keys Ra, La, CPhi, J, b, Mc, Ka, Ta, ``<key>_stderr`` and ``effect.<name>.<parameter>``),
``/diagnostics``, the parameters ``identified.<key>``, and ``~/online_parameters`` (the
recursive estimate with ``converged`` and the innovation RMS) at ``online_rate_hz``.
Service ``~/identify`` (``std_srvs/srv/Trigger``): closes the current window and identifies
the most recent windows (at least ``window_s`` of data). The callback is a coroutine: a worker
thread waits for the bags to be written and runs the fit (the default method, and the paper's
for comparison) in a separate process (``identify_in_subprocess``), so the executor keeps
taking samples; a second call meanwhile is refused.

The sample messages are taken in bulk by the processing timer (``process_rate_hz``) from
subscriptions on a hidden helper node, about ten times cheaper than one executor callback per
message; remap the sample topics globally (``-r voltage:=...``), which applies to both nodes.
"""

from collections import deque
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
import math
from multiprocessing import get_context
import os
import queue
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from dcmotor_id.errors import DcMotorIdError
from dcmotor_id.formats.batch import decode_batch
from dcmotor_id.identify import METHODS
from dcmotor_id.model import DERIVED_NAMES, PARAMETER_NAMES, UNITS
from dcmotor_id.nodes.common import declare, run, sample_qos
from dcmotor_id.nodes.worker import identify_windows, warm_up, watch_parent
from dcmotor_id.online import OnlineEstimator
from dcmotor_id.recording import WindowBagWriter
from dcmotor_id.records import MIN_SAMPLES, record_from_stamps
from dcmotor_id.streams import contiguous_runs, StreamAligner

#: Keys of the result, in order.
RESULT_KEYS = PARAMETER_NAMES + DERIVED_NAMES
INPUTS = ('float64', 'batch', 'joint_state')
LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _guarded(callback):
    """Log an unexpected error of a timer callback instead of letting it stop the executor."""
    def run(self, *args):
        try:
            return callback(self, *args)
        except Exception as error:  # noqa: BLE001  (the node must outlive any bad input)
            self.get_logger().error(f'{callback.__name__}: {type(error).__name__}: {error}',
                                    throttle_duration_sec=5.0)
            return None
    run.__name__ = callback.__name__
    run.__doc__ = callback.__doc__
    return run


def _fmt(value):
    """Full-precision text of a number (``nan`` for None; other values as they print)."""
    if value is None:
        return 'nan'
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return repr(float(value))
    return str(value)


class Window:
    """A contiguous run of aligned samples: grid stamps [ns] and channel arrays."""

    _counter = 0

    def __init__(self, stamps_ns, channels):
        Window._counter += 1
        self.number = Window._counter
        self.stamps_ns = stamps_ns
        self.channels = channels
        self.path = None
        self.error = None
        self.written = threading.Event()

    @property
    def duration_s(self):
        """Span covered by the samples [s] (samples times the period)."""
        if self.stamps_ns.size < 2:
            return 0.0
        step = (self.stamps_ns[-1] - self.stamps_ns[0]) / (self.stamps_ns.size - 1)
        return float(self.stamps_ns.size * step * 1e-9)

    def record(self):
        """Return the window as a record, built as :func:`dcmotor_id.io.read_bag` builds it."""
        return record_from_stamps(self.stamps_ns, self.channels,
                                  source=self.path or f'window {self.number}')


class Identifier(Node):
    """Online identification node (see the module docstring)."""

    def __init__(self, **kwargs):
        super().__init__('identifier', **kwargs)
        self.input = declare(self, 'input', 'float64', 'float64, batch or joint_state',
                             choices=INPUTS)
        self.sample_rate_hz = declare(self, 'sample_rate_hz', 1000.0,
                                      'sample rate of the drive [Hz]', low=1.0, high=1e6)
        self.align_by = declare(self, 'align_by', 'sequence',
                                'float64 input: sequence (DDS publication sequence number) '
                                'or timestamp (DDS source timestamp)',
                                choices=('sequence', 'timestamp'))
        max_delay_s = declare(self, 'max_delay_s', 0.5,
                              'how long a sample waits for a late channel before it is '
                              'counted as lost [s]', low=0.0)
        depth = declare(self, 'qos_depth', 5000, 'history depth of the sample topics', low=1)
        reliability = declare(self, 'qos_reliability', 'reliable', 'reliable or best_effort',
                              choices=('reliable', 'best_effort'))
        self.joint_name = declare(self, 'joint_name', '',
                                  'joint_state input: joint to use ("" = the first)')
        self.effort_scale = declare(self, 'effort_scale', 1.0,
                                    'joint_state input: current = effort_scale * effort [A]')
        self.torque_constant = declare(self, 'torque_constant', 0.0,
                                       '> 0: mechanical-only mode, torque = K current [N m/A]'
                                       '; identifies J, b, Mc without voltage', low=0.0)
        self.window_s = declare(self, 'window_s', 10.0,
                                'length of a recorded window and of the data identified [s]',
                                low=0.01)
        self.min_window_s = declare(self, 'min_window_s', 0.5,
                                    'runs of samples shorter than this (cut by lost samples) '
                                    'are dropped, neither recorded nor identified [s]',
                                    low=0.0)
        self.record = declare(self, 'record', True, 'write every window as an MCAP bag')
        self.record_dir = declare(self, 'record_dir', '~/.ros/dcmotor_id/windows',
                                  'directory of the window bags')
        self.disk_budget_mb = declare(self, 'disk_budget_mb', 200.0,
                                      'oldest windows are deleted beyond this [MiB]', low=0.0)
        self.min_free_mb = declare(self, 'min_free_mb', 16.0,
                                   'keep this much of the file system free [MiB]', low=0.0)
        self.record_format = declare(self, 'record_format', 'auto',
                                     'float64 (three topics), batch (samples) or auto (as '
                                     'the input)', choices=('auto', 'float64', 'batch'))
        self.method = declare(self, 'method', 'refined', 'identification method',
                              choices=tuple(METHODS))
        self.compare_paper = declare(self, 'compare_paper', True,
                                     'also run the paper method and report it')
        self.discover = declare(self, 'discover', True,
                                'run the residual analysis / effect discovery')
        self.identify_in_subprocess = declare(
            self, 'identify_in_subprocess', True,
            'fit in a separate process (keeps the executor at full rate during a fit)')
        self.online = declare(self, 'online', True, 'run the recursive online estimator')
        self.online_rate_hz = declare(self, 'online_rate_hz', 2.0,
                                      'rate of ~/online_parameters [Hz]', low=0.01, high=1e3)
        online_memory_s = declare(self, 'online_memory_s', 10.0,
                                  'forgetting time constant of the online estimate [s]',
                                  low=1e-3)
        converged_rel = declare(self, 'online_converged_rel_stderr', 0.05,
                                'relative standard error below which the online estimate '
                                'counts as converged', low=0.0)
        self.stream_timeout_s = declare(self, 'stream_timeout_s', 1.0,
                                        'a topic silent this long counts as stopped [s]',
                                        low=0.01)
        process_rate_hz = declare(self, 'process_rate_hz', 50.0,
                                  'rate at which received samples are aligned [Hz]', low=1.0)
        for key in RESULT_KEYS:
            self.declare_parameter(f'identified.{key}', float('nan'))
        self.declare_parameter('identified.method', '')
        self.declare_parameter('identified.bags', [''])
        self._setting_results = False
        self.add_on_set_parameters_callback(self._guard_results)

        self.mechanical = self.torque_constant > 0
        self.channels = ('current', 'speed') if self.mechanical else \
            ('voltage', 'current', 'speed')
        self.sample_period_s = 1.0 / self.sample_rate_hz
        self._period_ns = 1e9 / self.sample_rate_hz
        self.aligner = StreamAligner(self.channels,
                                     max(1, int(round(max_delay_s * self.sample_rate_hz))))
        self.estimator = OnlineEstimator(self.sample_period_s, online_memory_s,
                                         converged_rel) if self.online else None
        self._lock = threading.Lock()             # windows, current window, aligner output
        self._inbox = {channel: ([], []) for channel in self.channels}
        self._inbox_lock = threading.Lock()
        self._origin_ns = {}
        self._last_index = None
        self._anchor_ns = None
        self._current = []                        # list of (indices, values) of this window
        self._current_count = 0
        self._windows = deque()
        self._min_window_samples = max(int(self.min_window_s * self.sample_rate_hz),
                                       MIN_SAMPLES)
        self.discarded_samples = 0
        self._last_seen = {}
        self._stalled = set()
        self._identify_busy = threading.Lock()
        self._identify_started = 0.0
        self.last_result = None
        self.last_error = None
        self.record_error = None

        self._pool = None  # the fitting process starts with the first ~/identify
        self.writer = None
        self._write_queue = queue.Queue()
        if self.record:
            self._open_writer()
        self._writer_thread = threading.Thread(target=self._write_loop, name='window_writer',
                                               daemon=True)
        self._writer_thread.start()

        qos = sample_qos(depth, reliability)
        # The sample subscriptions live on a hidden helper node that no executor spins: the
        # processing timer takes every queued message in one go (a few microseconds each)
        # instead of paying a full executor cycle per message (about ten times more).
        self._input_node = rclpy.create_node(
            f'_{self.get_name()}_input', namespace=self.get_namespace(), context=self.context,
            start_parameter_services=False)
        self._inputs = []
        if self.input == 'float64':
            for channel in self.channels:
                self._add_input(Float64, channel, qos, lambda message, info, channel=channel:
                                self._on_float64(channel, message, info))
        elif self.input == 'batch':
            self._add_input(Float64MultiArray, 'samples', qos,
                            lambda message, info: self._on_batch(message))
        else:
            self._add_input(JointState, 'joint_states', qos,
                            lambda message, info: self._on_joint_state(message))
            if not self.mechanical:
                self._add_input(Float64, 'voltage', qos, lambda message, info: self._on_float64(
                    'voltage', message, info, by_timestamp=True))
        self.parameters_pub = self.create_publisher(DiagnosticStatus, '~/parameters', LATCHED)
        self.online_pub = self.create_publisher(DiagnosticStatus, '~/online_parameters', 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # reentrant: a second request is taken (and refused) while the first one is running
        self.create_service(Trigger, '~/identify', self._on_identify,
                            callback_group=ReentrantCallbackGroup())
        # housekeeping runs on the steady clock: under use_sim_time a /clock that stops (end
        # of a replay) must not stop the node from taking and aligning what has arrived
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0 / process_rate_hz, self._process, clock=steady)
        if self.online:
            self.create_timer(1.0 / self.online_rate_hz, self._publish_online, clock=steady)
        self.create_timer(1.0, self._health, clock=steady)
        where = f'to {self.writer.record_dir}' if self.writer else 'off'
        self.get_logger().info(
            f'identifier: {self.input} input at {self.sample_rate_hz:g} Hz, window '
            f'{self.window_s:g} s, recording {where}')

    # ------------------------------------------------------------------ parameters
    def _guard_results(self, parameters):
        if self._setting_results:
            return SetParametersResult(successful=True)
        for parameter in parameters:
            if parameter.name.startswith('identified.'):
                return SetParametersResult(
                    successful=False,
                    reason=f'{parameter.name} is a result of ~/identify, not a setting')
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ input
    def _add_input(self, message_type, topic, qos, handler):
        subscription = self._input_node.create_subscription(message_type, topic,
                                                            lambda _: None, qos)
        self._inputs.append((subscription, handler))

    def _drain(self, limit=200_000):
        """Take every queued sample message (at most ``limit``) and hand it to its handler."""
        taken = 0
        for subscription, handler in self._inputs:
            with subscription.handle:
                while taken < limit:
                    item = subscription.handle.take_message(subscription.msg_type, False)
                    if item is None:
                        break
                    taken += 1
                    handler(*item)
        return taken

    def _on_float64(self, channel, message, info, by_timestamp=False):
        stamp = info.get('source_timestamp') or info.get('received_timestamp')
        self._last_seen[channel] = time.monotonic()
        sequence = info.get('publication_sequence_number')
        if self.align_by == 'sequence' and not by_timestamp and sequence:
            index = int(sequence) - 1
        else:
            index = self._index_from_stamp(channel, stamp)
        with self._inbox_lock:
            indices, values = self._inbox[channel]
            indices.append(index)
            values.append(message.data)

    def _index_from_stamp(self, channel, stamp_ns):
        origin = self._origin_ns.setdefault('stamp', int(stamp_ns))
        return int(round((int(stamp_ns) - origin) / self._period_ns))

    def _on_batch(self, message):
        now = time.monotonic()
        try:
            block = decode_batch([dim.label for dim in message.layout.dim],
                                 [dim.size for dim in message.layout.dim],
                                 np.frombuffer(message.data, dtype=float))
        except DcMotorIdError as error:
            self.get_logger().error(f'samples: {error}', throttle_duration_sec=5.0)
            return
        with np.errstate(invalid='ignore'):
            indices = np.rint(block[0] / self.sample_period_s)
        good = np.isfinite(indices)
        indices = indices[good].astype(np.int64)
        with self._inbox_lock:
            for row, channel in enumerate(('voltage', 'current', 'speed'), start=1):
                if channel in self._inbox:
                    self._last_seen[channel] = now
                    store_indices, store_values = self._inbox[channel]
                    store_indices.append(indices)
                    store_values.append(block[row][good])

    def _on_joint_state(self, message):
        now = time.monotonic()
        names = list(message.name)
        if self.joint_name:
            if self.joint_name not in names:
                self.get_logger().error(f'joint_states has no joint {self.joint_name!r} '
                                        f'(has {names})', throttle_duration_sec=5.0)
                return
            position = names.index(self.joint_name)
        else:
            position = 0
        if len(message.velocity) <= position or len(message.effort) <= position:
            self.get_logger().error('joint_states lacks velocity or effort for the joint',
                                    throttle_duration_sec=5.0)
            return
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        index = self._index_from_stamp('joint', stamp)
        with self._inbox_lock:
            for channel, value in (('current', self.effort_scale * message.effort[position]),
                                   ('speed', message.velocity[position])):
                self._last_seen[channel] = now
                self._inbox[channel][0].append(index)
                self._inbox[channel][1].append(value)

    # ------------------------------------------------------------------ processing
    @_guarded
    def _process(self):
        self._drain()
        with self._inbox_lock:
            inbox = self._inbox
            self._inbox = {channel: ([], []) for channel in self.channels}
        for channel, (indices, values) in inbox.items():
            if not indices:
                continue
            if isinstance(indices[0], np.ndarray):
                indices, values = np.concatenate(indices), np.concatenate(values)
            self.aligner.add_block(channel, indices, values)
        self._consume(*self.aligner.pop_ready())

    def _consume(self, indices, values):
        if indices.size == 0:
            return
        if self._anchor_ns is None:
            self._anchor_ns = self.get_clock().now().nanoseconds - \
                int(round(int(indices[0]) * self._period_ns))
        for run_slice in contiguous_runs(indices):
            run_indices, run_values = indices[run_slice], values[run_slice]
            if self._last_index is not None and run_indices[0] != self._last_index + 1:
                self._close_window('gap')
                if self.estimator is not None:
                    self.estimator.break_continuity()
            self._last_index = int(run_indices[-1])
            if self.estimator is not None:
                columns = {name: run_values[:, k] for k, name in enumerate(self.channels)}
                voltage = columns.get('voltage')
                if voltage is not None:
                    self.estimator.update(voltage, columns['current'], columns['speed'])
            start = 0
            while start < run_indices.size:
                room = int(math.ceil(self.window_s * self.sample_rate_hz)) - \
                    self._current_count
                part = slice(start, start + max(room, 1))
                with self._lock:
                    self._current.append((run_indices[part], run_values[part]))
                    self._current_count += run_indices[part].size
                start = part.stop
                if self._current_count >= self.window_s * self.sample_rate_hz - 0.5:
                    self._close_window('full')

    def _close_window(self, reason):
        """Turn the current samples into a window (kept in memory, queued for writing)."""
        with self._lock:
            if not self._current:
                return None
            if self._current_count < self._min_window_samples:
                if reason == 'identify':  # too short to stand alone: keep collecting
                    return None
                self.discarded_samples += self._current_count
                self._current = []
                self._current_count = 0
                return None
            indices = np.concatenate([part[0] for part in self._current])
            values = np.vstack([part[1] for part in self._current])
            self._current = []
            self._current_count = 0
            stamps = self._anchor_ns + np.rint(indices * self._period_ns).astype(np.int64)
            window = Window(stamps, {name: values[:, k].copy()
                                     for k, name in enumerate(self.channels)})
            self._windows.append(window)
            keep_s = 3.0 * self.window_s
            while sum(w.duration_s for w in self._windows) - self._windows[0].duration_s \
                    >= keep_s:
                self._windows.popleft()
        if self.record:
            self._write_queue.put(window)
        else:
            window.written.set()
        return window

    # ------------------------------------------------------------------ recording
    def _open_writer(self):
        record_dir = os.path.expanduser(self.record_dir)
        try:
            self.writer = WindowBagWriter(
                record_dir, int(self.disk_budget_mb * 2 ** 20),
                batch_samples=self._record_batch(),
                min_free_bytes=int(self.min_free_mb * 2 ** 20))
            for path in self.writer.removed_partials:
                self.get_logger().warning(f'removed an unfinished window left by a killed '
                                          f'run: {path}')
            self.record_error = None
        except OSError as error:
            self.writer = None
            self.record_error = (f'cannot record to {record_dir}: {error.strerror or error}; '
                                 'set record_dir to a writable directory')
            self.get_logger().error(self.record_error)

    def _record_batch(self):
        fmt = self.record_format
        if fmt == 'auto':
            fmt = 'batch' if self.input == 'batch' else 'float64'
        return 0 if fmt == 'float64' else max(1, int(round(0.1 * self.sample_rate_hz)))

    def _write_loop(self):
        while True:
            window = self._write_queue.get()
            if window is None:
                return
            try:
                if self.writer is None:
                    self._open_writer()
                if self.writer is None:
                    window.error = self.record_error
                    continue
                window.path = self.writer.write(window.stamps_ns, window.channels)
                for path in self.writer.deleted:
                    self.get_logger().info(f'disk budget: deleted the oldest window {path}')
                self.writer.deleted.clear()
                self.record_error = None
            except Exception as error:  # noqa: BLE001  (a full disk must not stop the node)
                window.error = f'window {window.number} not recorded: {error}'
                self.record_error = window.error
                self.get_logger().error(window.error, throttle_duration_sec=5.0)
            finally:
                window.written.set()

    # ------------------------------------------------------------------ identification
    async def _on_identify(self, request, response):
        if not self._identify_busy.acquire(blocking=False):
            response.success = False
            response.message = (f'an identification is already running (started '
                                f'{time.monotonic() - self._identify_started:.1f} s ago); '
                                'call again when it has finished')
            return response
        try:
            self._identify_started = time.monotonic()
            self._close_window('identify')
            windows = self._select_windows()
            if not windows:
                have = sum(w.stamps_ns.size for w in self._windows) + self._current_count
                response.success = False
                response.message = (
                    f'not enough data: {have} aligned samples so far, a run of at least '
                    f'{self._min_window_samples} samples without loss is needed; check that '
                    f'the drive publishes {", ".join(self.channels)}, then call again')
                self._publish_failure(response.message)
                return response
            future = Future(executor=self.executor)
            future.add_done_callback(lambda _: None)  # wakes the executor when done
            threading.Thread(target=self._identify_worker, args=(windows, future),
                             name='identify', daemon=True).start()
            outcome = await future
            if isinstance(outcome, str):
                response.success = False
                response.message = outcome
                self._publish_failure(outcome)
                return response
            self._publish_result(outcome)
            response.success = True
            response.message = outcome['summary']
            return response
        finally:
            self._identify_busy.release()

    def _select_windows(self):
        """Most recent windows, newest last, until they hold ``window_s`` of data."""
        minimum = self._min_window_samples
        chosen = []
        total = 0.0
        with self._lock:
            for window in reversed(self._windows):
                if window.stamps_ns.size < minimum:
                    continue
                chosen.append(window)
                total += window.duration_s
                if total >= self.window_s - 0.5 * self.sample_period_s:
                    break
        return list(reversed(chosen))

    def _identify_worker(self, windows, future):
        try:
            for window in windows:
                window.written.wait(timeout=30.0)
            payload = [(window.stamps_ns, window.channels, window.path or
                        f'window {window.number}') for window in windows]
            arguments = (payload, self.method,
                         self.torque_constant if self.mechanical else None, self.discover,
                         self.compare_paper)
            if self._pool is None and self.identify_in_subprocess:
                self._pool = self._make_pool()
            if self._pool is not None:
                try:
                    status, result = self._pool.submit(identify_windows, *arguments).result()
                except BrokenProcessPool:
                    self._pool = self._make_pool()
                    raise RuntimeError('the identification process died; it was restarted, '
                                       'call again') from None
            else:
                status, result = identify_windows(*arguments)
            if status != 'ok':
                future.set_result(f'identification failed: {result}')
                return
            result['bags'] = [window.path for window in windows if window.path]
            result['record_errors'] = [window.error for window in windows if window.error]
            result['summary'] = self._summary(result)
            future.set_result(result)
        except Exception as error:  # noqa: BLE001  (report, never kill the node)
            future.set_result(f'identification failed unexpectedly: {type(error).__name__}: '
                              f'{error}')

    def _make_pool(self):
        if not self.identify_in_subprocess:
            return None
        pool = ProcessPoolExecutor(max_workers=1, mp_context=get_context('spawn'),
                                   initializer=watch_parent, initargs=(os.getpid(),))
        pool.submit(warm_up)
        return pool

    def _summary(self, result):
        values = result['parameters']
        text = f"{result['method']}: " + ', '.join(
            f'{key}={values[key]:.5g} {UNITS[key]}' for key in RESULT_KEYS if key in values)
        errors = result['error_after']
        text += ' (' + ', '.join(f"{key.split('_')[0]} {value:.3g} %" for key, value in
                                 errors.items() if value is not None) + \
            f"; {result['n_samples']} samples in {len(result['records'])} window(s))"
        effects = result.get('effects') or []
        if effects:
            text += '; effects: ' + '; '.join(
                effect['name'] + ' ' + ', '.join(
                    f'{k}={v:.4g}' if isinstance(v, (int, float)) else f'{k}={v}'
                    for k, v in effect['parameters'].items())
                for effect in effects)
        paper = result.get('paper')
        if isinstance(paper, dict):
            text += '; paper: ' + ', '.join(
                f"{key}={paper['parameters'][key]:.5g}" for key in RESULT_KEYS
                if key in paper['parameters'])
        elif paper:
            text += f'; paper failed: {paper}'
        if result['bags']:
            text += '; bags: ' + ', '.join(result['bags'])
        if result['record_errors']:
            text += '; not recorded: ' + '; '.join(result['record_errors'])
        return text

    def _result_status(self, result):
        status = DiagnosticStatus(level=DiagnosticStatus.OK,
                                  name=f'{self.get_name()}: identified parameters',
                                  hardware_id=self.get_fully_qualified_name(),
                                  message=result['summary'])
        values, errors = result['parameters'], result['stderr']
        status.values = [KeyValue(key=key, value=_fmt(values.get(key, math.nan)))
                         for key in RESULT_KEYS]
        status.values += [KeyValue(key=f'{key}_stderr', value=_fmt(errors.get(key, math.nan)))
                          for key in RESULT_KEYS]
        for effect in result.get('effects') or []:
            status.values += [KeyValue(key=f"effect.{effect['name']}.{name}", value=_fmt(value))
                              for name, value in effect['parameters'].items()]
        return status

    def _publish_result(self, result):
        self.last_result = result
        self.last_error = None
        status = self._result_status(result)
        self.parameters_pub.publish(status)
        statuses = [status]
        paper = result.get('paper')
        if paper is not None:
            paper_status = DiagnosticStatus(name=f'{self.get_name()}: paper method',
                                            hardware_id=self.get_fully_qualified_name())
            if isinstance(paper, dict):
                paper_status.level = DiagnosticStatus.OK
                paper_status.message = 'paper method on the same windows (comparison)'
                paper_status.values = [
                    KeyValue(key=key, value=_fmt(paper['parameters'].get(key, math.nan)))
                    for key in RESULT_KEYS]
            else:
                paper_status.level = DiagnosticStatus.WARN
                paper_status.message = f'paper method failed: {paper}'
            statuses.append(paper_status)
        self._publish_diagnostics(statuses)
        self._setting_results = True
        try:
            self.set_parameters(
                [Parameter(f'identified.{key}', value=float(result['parameters'].get(
                    key, math.nan))) for key in RESULT_KEYS]
                + [Parameter('identified.method', value=result['method']),
                   Parameter('identified.bags', value=list(result['bags']) or [''])])
        finally:
            self._setting_results = False

    def _publish_failure(self, message):
        self.last_error = message
        self.get_logger().warning(message)
        self._publish_diagnostics([DiagnosticStatus(
            level=DiagnosticStatus.ERROR, name=f'{self.get_name()}: identify',
            hardware_id=self.get_fully_qualified_name(), message=message)])

    def _publish_diagnostics(self, statuses):
        array = DiagnosticArray(status=statuses)
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(array)

    # ------------------------------------------------------------------ online and health
    def online_status(self):
        """Return the online estimate as a DiagnosticStatus (``converged``, innovation RMS)."""
        estimate = self.estimator.estimate()
        status = DiagnosticStatus(
            name=f'{self.get_name()}: online estimate',
            hardware_id=self.get_fully_qualified_name(),
            level=DiagnosticStatus.OK if estimate.converged else DiagnosticStatus.WARN,
            message=('converged' if estimate.converged else 'not converged') +
            f' after {estimate.n_updates} sample pairs')
        status.values = [KeyValue(key=key, value=_fmt(estimate.parameters[key]))
                         for key in RESULT_KEYS]
        status.values += [KeyValue(key=f'{key}_stderr', value=_fmt(estimate.stderr[key]))
                          for key in RESULT_KEYS]
        status.values += [
            KeyValue(key='converged', value=str(estimate.converged).lower()),
            KeyValue(key='innovation_rms_current_A',
                     value=_fmt(estimate.innovation_rms['current'])),
            KeyValue(key='innovation_rms_speed_rad_s',
                     value=_fmt(estimate.innovation_rms['speed'])),
            KeyValue(key='n_updates', value=str(estimate.n_updates))]
        return status

    @_guarded
    def _publish_online(self):
        self.online_pub.publish(self.online_status())

    @_guarded
    def _health(self):
        now = time.monotonic()
        stopped = sorted(channel for channel in self.channels
                         if now - self._last_seen.get(channel, now) > self.stream_timeout_s
                         and channel in self._last_seen)
        newly = set(stopped) - self._stalled
        if newly:
            self.get_logger().warning(f'topic(s) {", ".join(sorted(newly))} stopped (nothing '
                                      f'for {self.stream_timeout_s:g} s); the current window '
                                      'is closed and kept')
            self.aligner.flush()
            self._consume(*self.aligner.pop_ready())
            self._close_window('stopped')
        self._stalled = set(stopped)
        stats = self.aligner.stats
        level = DiagnosticStatus.OK
        message = 'receiving'
        if not self._last_seen:
            level, message = DiagnosticStatus.WARN, 'no samples received yet'
        elif stopped:
            level, message = DiagnosticStatus.WARN, f'stopped: {", ".join(stopped)}'
        if self.record_error:
            level, message = DiagnosticStatus.ERROR, self.record_error
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: streams',
                                  hardware_id=self.get_fully_qualified_name(),
                                  message=message)
        status.values = [KeyValue(key=key, value=str(value))
                         for key, value in stats.as_dict().items()]
        status.values += [KeyValue(key='first_sample', value=str(self.aligner.first_index)),
                          KeyValue(key='next_sample', value=str(self.aligner.next_index))]
        status.values.append(KeyValue(key='windows_in_memory', value=str(len(self._windows))))
        status.values.append(KeyValue(key='discarded_samples',
                                      value=str(self.discarded_samples)))
        if self.writer is not None:
            status.values.append(KeyValue(key='record_dir', value=self.writer.record_dir))
        self._publish_diagnostics([status])

    # ------------------------------------------------------------------ shutdown
    def close(self):
        """Flush: align what arrived, write the current window, stop the writer."""
        try:
            self._process()
            self.aligner.flush()
            self._consume(*self.aligner.pop_ready())
            self._close_window('shutdown')
        finally:
            self._write_queue.put(None)
            self._writer_thread.join(timeout=30.0)
            self._input_node.destroy_node()
            if self._pool is not None:
                self._pool.shutdown(wait=False, cancel_futures=True)


def main(args=None):
    """Run the ``identifier`` node."""
    return run(Identifier, args)


if __name__ == '__main__':
    raise SystemExit(main())
