"""
The ``identifier`` node's ROS wiring: subscriptions, ``~/identify``, parameters, publishing.

It aligns a drive's streams (:mod:`dcmotor_id.formats.streams`), cuts them into windows
(:mod:`dcmotor_id.streaming.windowing`) recorded as bags, and identifies on request off the
executor (:mod:`dcmotor_id.streaming.worker`); its texts come from
:mod:`dcmotor_id.streaming.summary` and its parameters are
:class:`dcmotor_id.nodes.settings.IdentifierSettings`; what went wrong with the input is counted
and said by :class:`dcmotor_id.streaming.input_health.InputHealth`.

Inputs (relative names; remap them globally, the messages are taken in bulk by the processing
timer through :class:`~dcmotor_id.nodes.common.BulkInput`), by ``input``:

* ``float64`` (default): ``voltage``, ``current``, ``speed`` (``std_msgs/msg/Float64``). With
  ``align_by: sequence`` the n-th message published on each topic is sample n (the DDS
  publication sequence number says which, so lost, late, duplicated and reordered messages
  land on the right sample); with ``align_by: timestamp`` the DDS source timestamp is rounded
  to the sample grid.
* ``batch``: ``samples`` (``std_msgs/msg/Float64MultiArray``, layout
  :data:`dcmotor_id.formats.batch.BATCH_LABEL`): many samples a message, for 10 kHz and more.
* ``joint_state``: ``joint_states`` (``sensor_msgs/msg/JointState``; speed from
  ``velocity``, current from ``effort`` times ``effort_scale``, both at ``header.stamp``) plus
  ``voltage`` by its source timestamp, or no voltage when ``torque_constant`` > 0
  (mechanical-only identification of J, b, Mc).
* ``dynamic_joint_state``: ``dynamic_joint_states`` (``control_msgs/msg/DynamicJointState``,
  as ros2_control's joint_state_broadcaster publishes it): the joint's state interfaces
  ``current_interface``, ``voltage_interface`` and ``speed_interface`` at ``header.stamp``
  (the voltage from the ``voltage`` topic when ``voltage_interface`` is empty; none in the
  mechanical-only mode). Needs control_msgs' Python messages (:func:`dynamic_joint_state_type`).

Outputs: ``~/parameters`` (``diagnostic_msgs/msg/DiagnosticStatus``, TRANSIENT_LOCAL depth 1:
keys Ra, La, CPhi, J, b, Mc, Ka, Ta, ``<key>_stderr`` and ``effect.<name>.<parameter>``),
``/diagnostics``, the parameters ``identified.<key>``, and ``~/online_parameters`` (the
online estimate with ``converged``, the innovation RMS and the change alarms, built by
:mod:`dcmotor_id.streaming.monitoring`; the alarms also as the ``condition`` status on
``/diagnostics``)
at ``online_rate_hz``.
Service ``~/identify`` (``std_srvs/srv/Trigger``): closes the current window and identifies
the most recent windows (at least ``window_s`` of data). The callback is a coroutine: a thread
waits for the bags and runs the fit (the default method, and the paper's for comparison) in a
separate process (``identify_in_subprocess``), with ``structure_bootstrap`` noise resamples
when that parameter is set (it can be changed while the node runs; a bad value is refused and
logged, never taken); a second call meanwhile is answered at once
with success false and a message starting ``busy:``. A burst of calls is queued
(:data:`~dcmotor_id.nodes.common.SERVICE_QOS`), never dropped: every call gets an answer, also
when the fit fails in an unexpected way.
"""

from __future__ import annotations

from functools import partial
import threading
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.records import MIN_SAMPLES
from dcmotor_id.formats.batch import decode_batch
from dcmotor_id.formats.regrid import StampRegridder
from dcmotor_id.formats.streams import SampleInbox, StreamAligner
from dcmotor_id.nodes.common import (BulkInput, declare_settings, guard_parameters, guarded,
                                     own_parameters, ResultParameters, run,
                                     sample_qos, SERVICE_QOS)
from dcmotor_id.nodes.settings import (check_settings, check_structure_bootstrap,
                                       IdentifierSettings)
from dcmotor_id.streaming.input_health import InputHealth
from dcmotor_id.streaming.monitoring import LEVELS, monitor_from_settings
from dcmotor_id.streaming.summary import (online_key_values, online_text, paper_status,
                                          result_key_values, RESULT_KEYS)
from dcmotor_id.streaming.windowing import WindowCutter
from dcmotor_id.streaming.worker import FitProcess, WindowRecorder

__all__ = ['Identifier', 'LATCHED', 'main', 'RESULT_KEYS']

LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Identifier(Node):
    """Online identification node (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('identifier', **kwargs)
        self.settings = settings = declare_settings(self, IdentifierSettings)
        self.structure_bootstrap = self._startup_bootstrap(settings.structure_bootstrap)
        check_settings(settings)
        # a missing control_msgs is said at start-up, before anything is started
        self.joint_state_type = dynamic_joint_state_type() if \
            settings.input == 'dynamic_joint_state' else JointState
        self.add_on_set_parameters_callback(self._on_set_bootstrap)
        guard_parameters(self, [name for name in own_parameters(self)
                                if name != 'structure_bootstrap'])
        self.results = ResultParameters(self, 'identified.', {
            **dict.fromkeys(RESULT_KEYS, float('nan')), 'method': '', 'bags': ['']}, '~/identify')

        self.mechanical = settings.torque_constant > 0
        self.channels = ('current', 'speed') if self.mechanical else \
            ('voltage', 'current', 'speed')
        rate = settings.sample_rate_hz
        self.inbox = SampleInbox(self.channels, 1.0 / rate, settings.align_by)
        self.aligner = StreamAligner(self.channels,
                                     max(1, int(round(settings.max_delay_s * rate))))
        self.cutter = WindowCutter(self.channels, rate, settings.window_s,
                                   settings.min_window_s, min_samples=MIN_SAMPLES,
                                   clock_ns=lambda: self.get_clock().now().nanoseconds,
                                   restart_samples=self.aligner.restart_samples)
        #: The channels the joint-state messages carry (joint_state, dynamic_joint_state).
        self.joint_channels: tuple[str, ...] = ()
        self.regridder = self._make_regridder(settings)
        self.health = InputHealth(self.channels, self.inbox, self.aligner, self.cutter,
                                  self.regridder)
        # online estimate and change alarms (ROS-free: dcmotor_id.streaming.monitoring, .online)
        self.online = monitor_from_settings(settings, rate) if settings.online else None
        self.estimator = self.online.estimator if self.online is not None else None
        self._identify_busy = threading.Lock()
        self._identify_started = 0.0
        self.last_result: Optional[dict] = None
        self.last_error: Optional[str] = None
        self._fits = FitProcess(settings.identify_in_subprocess, settings.identify_timeout_s)
        self.recorder = self._make_recorder(settings, rate) if settings.record else None
        self._subscribe(settings)
        self.parameters_pub = self.create_publisher(DiagnosticStatus, '~/parameters', LATCHED)
        self.online_pub = self.create_publisher(DiagnosticStatus, '~/online_parameters', 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # reentrant: a second request is taken (and refused) while the first one is running
        self.create_service(Trigger, '~/identify', self._on_identify, qos_profile=SERVICE_QOS,
                            callback_group=ReentrantCallbackGroup())
        # housekeeping runs on the steady clock: under use_sim_time a /clock that stops (end
        # of a replay) must not stop the node from taking and aligning what has arrived
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0 / settings.process_rate_hz, self.process, clock=steady)
        if settings.online:
            self.create_timer(1.0 / settings.online_rate_hz, self._publish_online, clock=steady)
        self.create_timer(1.0, self._health, clock=steady)
        writer = self.recorder and self.recorder.writer
        where = f'to {writer.record_dir}' if writer else 'off'
        self.get_logger().info(f'identifier: {settings.input} input at {rate:g} Hz, window '
                               f'{settings.window_s:g} s, recording {where}')

    def _make_recorder(self, settings: IdentifierSettings, rate: float) -> WindowRecorder:
        """Return the recorder of the windows (bags in the input's layout unless asked)."""
        fmt = settings.record_format if settings.record_format != 'auto' else \
            'batch' if settings.input == 'batch' else 'float64'
        return WindowRecorder(
            settings.record_dir, self._log,
            disk_budget_bytes=int(settings.disk_budget_mb * 2 ** 20),
            batch_samples=0 if fmt == 'float64' else max(1, int(round(0.1 * rate))),
            min_free_bytes=int(settings.min_free_mb * 2 ** 20))

    def _make_regridder(self, settings: IdentifierSettings) -> Optional[StampRegridder]:
        """
        Return what places stamped messages on the grid (None: placed by sequence number).

        Joint states, and Float64 topics with ``align_by: timestamp``: each topic is a source
        numbered by its DDS sequence numbers and placed on the grid by its stamps
        (:mod:`dcmotor_id.formats.regrid`).
        """
        if settings.input == 'batch' or (settings.input == 'float64' and
                                         settings.align_by == 'sequence'):
            return None
        regridder = StampRegridder(1.0 / settings.sample_rate_hz, hold_channels=('voltage',))
        if settings.input == 'float64':
            for channel in self.channels:
                regridder.add_source(channel, (channel,))
        else:
            source, channels = self._joint_source(settings)
            self.joint_channels = channels
            regridder.add_source(source, channels)
            if 'voltage' in self.channels and 'voltage' not in channels:
                regridder.add_source('voltage', ('voltage',))
        return regridder

    def _joint_source(self, settings: IdentifierSettings) -> tuple[str, tuple[str, ...]]:
        """Return the joint-state topic and the channels its messages carry."""
        if settings.input == 'joint_state':
            return 'joint_states', ('current', 'speed')
        if settings.voltage_interface and not self.mechanical:
            return 'dynamic_joint_states', ('voltage', 'current', 'speed')
        return 'dynamic_joint_states', ('current', 'speed')

    def _subscribe(self, settings: IdentifierSettings) -> None:
        """Subscribe to the samples of the configured input (Float64, batch, joint states)."""
        qos = sample_qos(settings.qos_depth, settings.qos_reliability)
        self.input_node = inputs = BulkInput(self)
        if settings.input == 'float64':
            for name in self.channels:
                inputs.add(Float64, name, qos, partial(self._on_float64, name))
        elif settings.input == 'batch':
            inputs.add(Float64MultiArray, 'samples', qos, lambda message, _: self._on_batch(
                message))
        else:
            if settings.input == 'joint_state':
                inputs.add(JointState, 'joint_states', qos, self._on_joint_state)
            else:
                inputs.add(self.joint_state_type, 'dynamic_joint_states', qos,
                           self._on_dynamic_joint_state)
            if 'voltage' in self.channels and 'voltage' not in self.joint_channels:
                inputs.add(Float64, 'voltage', qos, partial(self._on_float64, 'voltage'))

    # ------------------------------------------------------------------ input
    def _log(self, level, text):
        """Log; errors (bad input, a full disk) at most every 5 s (one throttle for all)."""
        if level == 'error':
            self.get_logger().error(text, throttle_duration_sec=5.0)
        else:
            getattr(self.get_logger(), level)(text)

    def _on_float64(self, channel, message, info):
        if self.regridder is None:
            self.inbox.put_message(channel, message.data, info)
            return
        stamp = info.get('source_timestamp') or info['received_timestamp']
        self.regridder.put(channel, stamp, info.get('publication_sequence_number'),
                           (message.data,))
        self.inbox.seen((channel,))

    def _on_batch(self, message):
        try:
            block = decode_batch([dim.label for dim in message.layout.dim],
                                 [dim.size for dim in message.layout.dim],
                                 np.frombuffer(message.data, dtype=float))
        except DcMotorIdError as error:
            self.health.refuse_batch(str(error))
            self._log('error', f'samples: {error}')
            return
        self.inbox.put_times(block[0], dict(zip(('voltage', 'current', 'speed'), block[1:])))

    def _on_joint_state(self, message, info):
        names, joint = list(message.name), self.settings.joint_name
        if joint and joint not in names:
            self._refuse_joint_state(f'no joint {joint!r} (has {names})')
            return
        position = names.index(joint) if joint else 0
        if len(message.velocity) <= position or len(message.effort) <= position:
            self._refuse_joint_state(f'{len(message.velocity)} velocities and '
                                     f'{len(message.effort)} efforts for joint {position}')
            return
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        assert self.regridder is not None
        self.regridder.put('joint_states', stamp or info.get('source_timestamp') or
                           info['received_timestamp'], info.get('publication_sequence_number'),
                           (self.settings.effort_scale * message.effort[position],
                            message.velocity[position]))
        self.inbox.seen(('current', 'speed'))

    def _on_dynamic_joint_state(self, message, info):
        names, joint = list(message.joint_names), self.settings.joint_name
        if joint and joint not in names or not names:
            self._refuse_joint_state(f'dynamic_joint_states: no joint {joint!r} (has {names})')
            return
        position = names.index(joint) if joint else 0
        if len(message.interface_values) <= position:
            self._refuse_joint_state(f'dynamic_joint_states: {len(message.interface_values)} '
                                     f'interface value sets for joint {position}')
            return
        found = message.interface_values[position]
        values = dict(zip(found.interface_names, found.values))
        channels, settings = self.joint_channels, self.settings
        wanted = {'voltage': settings.voltage_interface, 'current': settings.current_interface,
                  'speed': settings.speed_interface}
        missing = [wanted[channel] for channel in channels if wanted[channel] not in values]
        if missing:
            self._refuse_joint_state(f'dynamic_joint_states: joint {names[position]!r} has no '
                                     f'interface {", ".join(missing)} (has '
                                     f'{", ".join(values) or "none"})')
            return
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        assert self.regridder is not None
        self.regridder.put('dynamic_joint_states', stamp or info.get('source_timestamp') or
                           info['received_timestamp'], info.get('publication_sequence_number'),
                           tuple(float(values[wanted[channel]]) for channel in channels))
        self.inbox.seen(channels)

    def _refuse_joint_state(self, why):
        self.health.refuse_joint_state(why)
        self._log('error', f'joint_states refused: {why}')

    # ------------------------------------------------------------------ processing
    @guarded
    def process(self) -> None:
        """Align what has arrived, cut it into windows and feed the online estimate."""
        self.input_node.take()
        if self.regridder is not None:
            self.regridder.drain_into(self.inbox)
        self.inbox.drain_into(self.aligner)
        self._consume()

    def _place_all(self):
        """Place the stamped topics with less than a second of stamps too (they stopped)."""
        if self.regridder is not None:
            self.regridder.drain_into(self.inbox, force=True)
            self.inbox.drain_into(self.aligner)

    def _consume(self):
        for run_ in self.cutter.add(*self.aligner.pop_ready()):
            if self.online is not None and self.online.feed(run_, not self.mechanical):
                self._log('error', self.online.error)
        self._dispatch()

    def _close_window(self, keep_short=False):
        window = self.cutter.close(keep_short)
        self._dispatch()
        return window

    def _dispatch(self):
        """Queue the windows just closed for writing."""
        for window in self.cutter.pop_closed():
            if self.recorder is not None:
                self.recorder.put(window)
            else:
                window.written.set()

    # ------------------------------------------------------------------ identification
    def _startup_bootstrap(self, value: Any) -> int:
        """``structure_bootstrap`` as launched; a bad value is logged and the bootstrap off."""
        try:
            return check_structure_bootstrap(value)
        except ValueError as error:
            self.get_logger().error(f'{error}; the structure bootstrap is off (0)')
            return 0

    def _on_set_bootstrap(self, parameters: list[Parameter]) -> SetParametersResult:
        """Take a new ``structure_bootstrap`` for the next ``~/identify``, or refuse it."""
        for parameter in parameters:
            if parameter.name != 'structure_bootstrap':
                continue
            try:
                value = check_structure_bootstrap(parameter.value)
            except ValueError as error:
                self.get_logger().error(f'{error}; it stays {self.structure_bootstrap}')
                return SetParametersResult(successful=False, reason=str(error))
            self.structure_bootstrap = value
        return SetParametersResult(successful=True)

    async def _on_identify(self, request, response):
        if not self._identify_busy.acquire(blocking=False):
            response.success = False
            response.message = (f'busy: an identification is already running (started '
                                f'{time.monotonic() - self._identify_started:.1f} s ago); '
                                'call again when it has finished')
            return response
        try:
            self._identify_started = time.monotonic()
            return await self._identify(response)
        except Exception as error:  # noqa: BLE001  (every call is answered; the node lives on)
            response.success = False
            response.message = (f'identification failed unexpectedly: '
                                f'{type(error).__name__}: {error}')
            self._publish_failure(response.message)
            return response
        finally:
            self._identify_busy.release()

    async def _identify(self, response):
        """Identify from the latest windows; fill ``response``."""
        self._close_window(keep_short=True)
        windows = self.cutter.select()
        if not windows:
            response.success = False
            response.message = self.health.not_enough_data()
            self._publish_failure(response.message)
            return response
        future = Future(executor=self.executor)
        future.add_done_callback(lambda _: None)  # wakes the executor when done
        arguments = (windows, self.settings.method, self.settings.torque_constant if
                     self.mechanical else None, self.settings.discover,
                     self.settings.compare_paper, self.structure_bootstrap)

        def fit():
            try:
                future.set_result(self._fits.identify(*arguments))
            except BaseException as error:  # noqa: BLE001  (answered by _on_identify)
                future.set_exception(error)
        threading.Thread(target=fit, name='identify', daemon=True).start()
        outcome = await future
        response.success = not isinstance(outcome, str)
        if response.success:  # what was refused or lost is said, never a silent success
            outcome['summary'] = self.health.with_problems(outcome['summary'])
            self._publish_result(outcome)
            response.message = outcome['summary']
        else:
            response.message = outcome
            self._publish_failure(outcome)
        return response

    def _status(self, what, level='OK', message='', pairs=()):
        """Build a status of this node; ``level`` is a name of :data:`LEVELS`."""
        return DiagnosticStatus(level=bytes([LEVELS.index(level)]),
                                name=f'{self.get_name()}: {what}',
                                hardware_id=self.get_fully_qualified_name(),
                                message=message,
                                values=[KeyValue(key=k, value=v) for k, v in pairs])

    def result_status(self, result: dict) -> DiagnosticStatus:
        """Return the ``~/parameters`` message of a result (with its ``summary``)."""
        return self._status('identified parameters', message=result['summary'],
                            pairs=result_key_values(result))

    def _publish_result(self, result):
        self.last_result = result
        self.last_error = None
        status = self.result_status(result)
        self.parameters_pub.publish(status)
        statuses = [status]
        paper = paper_status(result)  # the paper method's result on the same windows
        if paper is not None:
            statuses.append(self._status('paper method', *paper))
        self._publish_diagnostics(statuses)
        if self.online is not None:
            self.online.identified(result)  # the change baseline, if monitor_baseline says so
        values = {key: float(result['parameters'].get(key, float('nan'))) for key in RESULT_KEYS}
        self.results.publish({**values, 'method': result['method'],
                              'bags': list(result['bags']) or ['']})

    def _publish_failure(self, message):
        self.last_error = message
        self.get_logger().warning(message)
        self._publish_diagnostics([self._status('identify', 'ERROR', message)])

    def _publish_diagnostics(self, statuses):
        array = DiagnosticArray(status=statuses)
        array.header.stamp = self.get_clock().now().to_msg()
        self.diagnostics_pub.publish(array)

    # ------------------------------------------------------------------ online and health
    def online_status(self) -> DiagnosticStatus:
        """Return the online estimate as a DiagnosticStatus (``converged``, alarms)."""
        return self._online_statuses()[0]

    def _online_statuses(self):
        """Return the ``~/online_parameters`` status and the condition (alarm) status."""
        assert self.online is not None, 'online is false'
        estimate, alarms = self.online.snapshot()
        level, message, pairs = self.online.condition(alarms, time.time())
        worst = LEVELS[max(LEVELS.index(level), 0 if estimate.converged else 1)]
        text = online_text(estimate, message, bool(alarms))
        online = self._status('online estimate', worst, text, online_key_values(estimate, pairs))
        return online, self._status('condition', level, message, pairs)

    @guarded
    def _publish_online(self):
        online, condition = self._online_statuses()
        self.online_pub.publish(online)
        if self.online is not None and self.online.detector is not None:
            self._publish_diagnostics([condition])

    @guarded
    def _health(self):
        """Close the window when a channel stops; publish the ``streams`` status."""
        timeout_s = self.settings.stream_timeout_s
        # what arrived while the node was busy (a loaded machine runs the process timer
        # late) is taken first: a channel is stopped when nothing came, not when nothing
        # was taken
        self.process()
        stopped, newly = self.health.stopped(timeout_s)
        if newly:
            self.get_logger().warning(f'topic(s) {", ".join(newly)} stopped (nothing '
                                      f'for {timeout_s:g} s); the current window '
                                      'is closed and kept')
            self._place_all()
            self.aligner.flush()
            self._consume()
            self._close_window()
        recorder = self.recorder
        writer = recorder.writer if recorder is not None else None
        level, message = self.health.status(stopped, recorder.error if recorder else None)
        pairs = self.health.key_values(self._fits.restarts, writer.record_dir if writer else None)
        self._publish_diagnostics([self._status('streams', level, message, pairs)])

    # ------------------------------------------------------------------ shutdown
    def close(self) -> None:
        """Flush: align what arrived, write the current window, stop the writer."""
        try:
            self.process()
            self._place_all()
            self.aligner.flush()
            self._consume()
            self._close_window()
        finally:
            if self.online is not None:
                self.online.close()
            if self.recorder is not None:
                self.recorder.close()
            self.input_node.destroy()
            self._fits.shutdown()


def dynamic_joint_state_type() -> Any:
    """
    Return ``control_msgs.msg.DynamicJointState``; ValueError saying how to install it.

    On a ROS machine it is the installed control_msgs (``ros-jazzy-control-msgs``, not in
    package.xml: only this input needs it); with the PyPI wheels of ROS, ``make control-msgs``
    generates it (tools/build_control_msgs.sh).
    """
    try:
        from control_msgs.msg import DynamicJointState
    except ImportError as error:
        raise ValueError(f"parameter input = dynamic_joint_state needs control_msgs' Python "
                         f'messages, which cannot be imported ({error}): on a ROS machine '
                         'apt-get install ros-jazzy-control-msgs; with the ROS wheels from '
                         'PyPI run `make control-msgs` (docs/nodes.md); or use input '
                         'joint_state') from None
    return DynamicJointState


def main(args: Optional[list[str]] = None) -> int:
    """Run the ``identifier`` node."""
    return run(Identifier, args)


if __name__ == '__main__':
    raise SystemExit(main())
