"""
``exciter``: the node that drives a real (or simulated) motor with an excitation routine, safely.

Publishes ``voltage_command`` (``std_msgs/msg/Float64``, relative name; ``command_topic``) at
``rate_hz`` while a routine runs, or, with ``command_type: forward_command_controller``, a
``std_msgs/msg/Float64MultiArray`` on ``command_topic`` for a ros2_control forward command
controller (the voltage at ``joint_index`` of ``joint_count`` values, the others 0), the same
on every stop (:mod:`dcmotor_id.design.routines`: quasistatic, dynamic, prbs, multisine, chirp,
forward or backward; or the routine of a plan file written by ``dcmotor-id plan --json``).
Services ``~/start`` and ``~/stop`` (``std_srvs/srv/Trigger``); the state (idle, ramping-in,
running, stopped, stopped-by-limit, stale, done), the routine and its progress go to
``/diagnostics``.  It reads the measurements the drive publishes, ``current`` and ``speed``
(``std_msgs/msg/Float64``, ``input: float64``), the batches on ``samples`` (``input:
batch``, :mod:`dcmotor_id.formats.batch`, which carry the voltage too) or the velocity of
``joint_name`` in ``joint_states`` (``sensor_msgs/msg/JointState``, ``input: joint_state``,
as a ros2_control robot publishes it), and commands 0 V and
stops at once when one exceeds its limit or is NaN/inf, when one of them (each channel on
its own) had no finite sample for ``stale_timeout_s`` (at the next command tick; the state
``stale`` and the log name the channel), on ``~/stop``, at the end of the routine, and when
the node is shut down or receives SIGINT or SIGTERM.  ``~/stop`` has a callback group of its
own and the command tick another: neither waits behind ``~/start`` (which reads
``plan_file`` and computes the routine's commands before it takes the start's time), and a
burst of calls is queued (:data:`~dcmotor_id.nodes.common.SERVICE_QOS`), so that every call
is answered.  ``exciter --plan [plan options]`` prints an experiment plan
without starting ROS (the same as ``dcmotor-id plan``: :mod:`dcmotor_id.console.plan`).
"""

from __future__ import annotations

from functools import partial
import json
import signal
import sys
import threading
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from dcmotor_id.core.errors import DcMotorIdError, InputDataError
from dcmotor_id.design.routines import DIRECTIONS, ExcitationSession, Limits, Routine, ROUTINES
from dcmotor_id.formats.batch import decode_batch_message
from dcmotor_id.nodes.common import (BulkInput, check_choice, declare, guard_parameters,
                                     own_parameters, read_regular_file, sample_qos,
                                     SERVICE_QOS)

#: QoS of ``voltage_command``: reliable, so that the final 0 V is delivered.
COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE)
#: Diagnostic level of each state.
LEVELS = {'idle': DiagnosticStatus.OK, 'ramping-in': DiagnosticStatus.OK,
          'running': DiagnosticStatus.OK, 'done': DiagnosticStatus.OK,
          'stopped': DiagnosticStatus.OK, 'stale': DiagnosticStatus.WARN,
          'stopped-by-limit': DiagnosticStatus.ERROR}
#: Zero commands sent after a stop (one a tick), in case the first one is lost.
ZERO_REPEATS = 5
#: Channels watched (each must stay fresh and finite) by ``input``.
WATCHED = {'float64': ('current', 'speed'), 'batch': ('current', 'speed', 'voltage'),
           'joint_state': ('speed',)}
#: How the routine is commanded: a Float64 voltage, or a ros2_control forward command
#: controller's Float64MultiArray (one value per joint it commands).
COMMAND_TYPES = ('float64', 'forward_command_controller')


def load_plan(path: str) -> Routine:
    """
    Return the routine of a plan JSON (``dcmotor-id plan --json``) given as ``plan_file``.

    Only a regular file is read (a FIFO, a device or a symlink loop is refused by name, never
    waited on); the routine is checked as :meth:`Routine.from_dict` does.
    """
    try:
        data = json.loads(read_regular_file(path, 'plan_file'))
    except json.JSONDecodeError as error:
        raise InputDataError(f'plan_file {path!r} is not JSON: {error}') from None
    if not isinstance(data, dict) or not isinstance(data.get('routine'), dict):
        raise InputDataError(f'plan_file {path!r}: not a plan (no "routine")')
    try:
        return Routine.from_dict(data['routine'])
    except (TypeError, ValueError) as error:
        raise InputDataError(f'plan_file {path!r}: bad routine: {error}') from None


class Exciter(Node):
    """Excitation node (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('exciter', **kwargs)
        self._routine_parameters = self._declare_routine()
        rate = declare(self, 'rate_hz', 200.0, 'command rate [Hz]', low=1.0, high=1e4)
        ramp_in = declare(self, 'ramp_in_s', 1.0, 'ramp-in time of a routine [s]', low=0.0)
        limits = self._declare_limits()
        stale = declare(self, 'stale_timeout_s', 0.5, 'stop when no measurement arrived for '
                        'this long [s]', low=1e-3)
        source = declare(self, 'input', 'float64', 'float64: current and speed topics; '
                         'batch: samples; joint_state: the velocity of joint_name in '
                         'joint_states', choices=tuple(WATCHED))
        self.joint_name = declare(self, 'joint_name', '', 'joint_state input: the joint '
                                  'watched ("" = the first)')
        depth = declare(self, 'qos_depth', 5000, 'history depth of the measurement topics',
                        low=1)
        reliability = declare(self, 'qos_reliability', 'reliable', 'reliable or best_effort',
                              choices=('reliable', 'best_effort'))
        self.autostart = declare(self, 'autostart', False, 'start the routine at once (when '
                                 'measurements arrive)')
        self.session = ExcitationSession(limits, rate, ramp_in, stale, watch=WATCHED[source])
        # The routines' code imports scipy.signal at its first use: seconds on a busy machine
        # (38 s seen under load), which the first ~/start would wait for. Paid here, before
        # the services exist: once they are found, ~/start is answered at once.
        self.session.profile_of(Routine(duration_s=1.0))
        #: Guards the session: held for microseconds, by the tick, ~/start and ~/stop.
        self._lock = threading.RLock()
        self._zeros_due = 0
        self._last_state = self.session.state
        self._declare_command()
        self._diagnostics = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._subscribe(source, sample_qos(depth, reliability))
        # the routine's parameters are read at ~/start (checked as at start-up), the others
        # once, here
        guard_parameters(self, [name for name in own_parameters(self)
                                if name not in self._routine_parameters], {
            'routine': partial(check_choice, 'routine', choices=ROUTINES),
            'direction': partial(check_choice, 'direction', choices=DIRECTIONS)})
        # ~/stop and ~/start each in a group of their own: a stop is never queued behind a
        # start (reading plan_file) nor behind the tick, and the tick never waits for either.
        self.create_service(Trigger, '~/start', self._on_start, qos_profile=SERVICE_QOS,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self.create_service(Trigger, '~/stop', self._on_stop, qos_profile=SERVICE_QOS,
                            callback_group=MutuallyExclusiveCallbackGroup())
        self.create_timer(1.0 / rate, self._tick)
        self.create_timer(0.5, self._report)
        self.get_logger().info(f'exciter ready: {source} input, limits {limits}, '
                               f'commands at {rate:g} Hz; call ~/start')

    def _declare_command(self) -> None:
        """Declare how the routine is commanded and create its publisher."""
        self.command_type = declare(
            self, 'command_type', 'float64', 'float64: std_msgs/Float64 on command_topic; '
            'forward_command_controller: std_msgs/Float64MultiArray on command_topic (e.g. '
            '/<controller>/commands), the voltage at joint_index of joint_count values, the '
            'others 0', choices=COMMAND_TYPES)
        topic = declare(self, 'command_topic', 'voltage_command', 'topic of the commands')
        self.joint_count = declare(self, 'joint_count', 1, 'forward_command_controller: '
                                   'joints the controller commands', low=1)
        self.joint_index = declare(self, 'joint_index', 0, 'forward_command_controller: '
                                   'the place of the motor among them', low=0)
        if self.joint_index >= self.joint_count:
            raise ValueError(f'joint_index {self.joint_index} is not below joint_count '
                             f'{self.joint_count}: give the place of the motor among the '
                             'joints of the controller')
        message_type = Float64 if self.command_type == 'float64' else Float64MultiArray
        self.command_publisher = self.create_publisher(message_type, topic, COMMAND_QOS)

    def _declare_routine(self) -> dict[str, Any]:
        """Declare the routine's parameters; return them by name (``plan_file`` included)."""
        return {
            'routine': declare(self, 'routine', 'prbs', 'excitation routine',
                               choices=ROUTINES),
            'direction': declare(self, 'direction', 'forward', 'forward or backward (negated)',
                                 choices=DIRECTIONS),
            'amplitude_v': declare(self, 'amplitude_v', 12.0, 'peak voltage of the routine '
                                   '[V]', low=0.0),
            'duration_s': declare(self, 'duration_s', 10.0, 'length of the routine, ramp-in '
                                  'included [s]', low=1e-3),
            'frequency_hz': declare(self, 'frequency_hz', 0.0, 'PRBS clock, lower band edge '
                                    '(multisine, chirp), step frequency (dynamic); 0 = '
                                    'default [Hz]', low=0.0),
            'max_frequency_hz': declare(self, 'max_frequency_hz', 0.0, 'upper band edge '
                                        '(multisine, chirp); 0 = default [Hz]', low=0.0),
            'offset_v': declare(self, 'offset_v', 0.0, 'constant added to the routine [V]'),
            'seed': declare(self, 'seed', 0, 'PRBS seed'),
            'plan_file': declare(self, 'plan_file', '', 'plan JSON of dcmotor-id plan: its '
                                 'routine replaces the parameters above'),
        }

    def _declare_limits(self) -> Limits:
        """Declare the hard voltage, current and speed limits."""
        return Limits(
            voltage_v=declare(self, 'voltage_limit_v', 48.0, 'hard voltage limit [V]',
                              low=1e-9),
            current_a=declare(self, 'current_limit_a', 10.0, 'hard current limit [A]',
                              low=1e-9),
            speed_rad_s=declare(self, 'speed_limit_rad_s', 100.0, 'hard speed limit [rad/s]',
                                low=1e-9))

    def _subscribe(self, source: str, qos: Any) -> None:
        """Subscribe to the measurements the session watches (Float64 topics or batches)."""
        self.inputs = BulkInput(self)
        if source == 'float64':
            self.inputs.add(Float64, 'current', qos,
                            lambda message, _: self._observe(current=[message.data]))
            self.inputs.add(Float64, 'speed', qos,
                            lambda message, _: self._observe(speed=[message.data]))
        elif source == 'batch':
            self.inputs.add(Float64MultiArray, 'samples', qos, self._on_batch)
        else:
            self.inputs.add(JointState, 'joint_states', qos, self._on_joint_state)

    def _on_joint_state(self, message: JointState, _: Any) -> None:
        """Watch the joint's velocity; a message without it is not a measurement."""
        names = list(message.name)
        if self.joint_name and self.joint_name not in names:
            self.get_logger().warning(f'joint_states: no joint {self.joint_name!r} (has '
                                      f'{names}); not counted as a measurement',
                                      throttle_duration_sec=5.0)
            return
        position = names.index(self.joint_name) if self.joint_name else 0
        if len(message.velocity) <= position:
            self.get_logger().warning(f'joint_states: no velocity for joint {position}; not '
                                      'counted as a measurement', throttle_duration_sec=5.0)
            return
        self._observe(speed=[message.velocity[position]])

    @staticmethod
    def now_s() -> float:
        """Return the monotonic time the session runs on [s]."""
        return time.monotonic()

    def _observe(self, **channels: Any) -> None:
        with self._lock:
            if self.session.observe(self.now_s(), **channels):
                self._halt()

    def _on_batch(self, message: Float64MultiArray, _: Any) -> None:
        try:
            _, voltage, current, speed = decode_batch_message(message)
        except (DcMotorIdError, ValueError, TypeError) as error:
            self.get_logger().warning(f'samples: batch refused (not counted as a '
                                      f'measurement): {error}', throttle_duration_sec=5.0)
            return
        self._observe(current=current, speed=speed, voltage=voltage)

    def routine(self) -> Routine:
        """Return the routine of the parameters (or of ``plan_file``) as they are now."""
        values = {name: self.get_parameter(name).value for name in self._routine_parameters}
        plan_file = values.pop('plan_file')
        if plan_file:
            return load_plan(plan_file)
        values['kind'] = values.pop('routine')
        return Routine(**values)

    def _on_start(self, request: Trigger.Request,
                  response: Trigger.Response) -> Trigger.Response:
        # Outside the lock (the tick and ~/stop never wait for them) and before the start's
        # time is taken (a routine that took long to compute still starts at its beginning,
        # ramp-in included, judged on fresh measurements): read plan_file, compute the
        # commands (the first PRBS imports scipy.signal, seconds on a busy machine).
        try:
            routine = self.routine()
            profile = self.session.profile_of(routine)
        except Exception as error:  # noqa: BLE001  (any bad routine is an answer, not a crash)
            response.success, response.message = False, f'bad routine: {error}'
            self.get_logger().warning(f'~/start refused: {response.message}')
            return response
        with self._lock:
            self.inputs.take()
            response.success, response.message = self.session.start(routine, self.now_s(),
                                                                    profile)
            self._report()
        self.get_logger().info(f'~/start: {response.message}')
        return response

    def _on_stop(self, request: Trigger.Request,
                 response: Trigger.Response) -> Trigger.Response:
        with self._lock:
            was = self.session.state
            self.session.stop()
            self._halt()
            response.success = True
            response.message = f'0 V commanded; state {self.session.state} (was {was})'
        return response

    def _halt(self) -> None:
        """Command 0 V now and on the next ticks."""
        self.publish_command(0.0)
        self._zeros_due = ZERO_REPEATS
        self.get_logger().warning(f'0 V: {self.session.state}: {self.session.reason}')
        self._report()

    def publish_command(self, value: float) -> None:
        """Publish one voltage command [V] (in its place of the joints' array)."""
        if self.command_type == 'float64':
            self.command_publisher.publish(Float64(data=float(value)))
            return
        values = [0.0] * self.joint_count
        values[self.joint_index] = float(value)
        self.command_publisher.publish(Float64MultiArray(data=values))

    def _tick(self) -> None:
        try:
            with self._lock:
                self._tick_locked()
        except Exception as error:  # noqa: BLE001  (the watchdog must outlive any fault)
            with self._lock:
                self.session.stop(f'internal error: {type(error).__name__}: {error}',
                                  'stopped-by-limit')
                self.publish_command(0.0)
            self.get_logger().error(f'tick: {type(error).__name__}: {error}; 0 V commanded',
                                    throttle_duration_sec=5.0)

    def _tick_locked(self) -> None:
        self.inputs.take()
        if self.autostart and self.session.state == 'idle' and \
                self.session.fresh(self.now_s()):
            self.autostart = False
            self._on_start(Trigger.Request(), Trigger.Response())
        was_active = self.session.active
        value = self.session.command(self.now_s())
        if value is not None:
            self.publish_command(value)
        if was_active and not self.session.active:
            self._halt()
        elif value is None and self._zeros_due > 0:
            self._zeros_due -= 1
            self.publish_command(0.0)
        if self.session.state != self._last_state:
            self._report()

    def _report(self) -> None:
        with self._lock:
            self._report_locked()

    def _report_locked(self) -> None:
        values = self.session.status()
        self._last_state = self.session.state
        status = DiagnosticStatus(level=LEVELS[self.session.state],
                                  name=f'{self.get_name()}: excitation',
                                  hardware_id=self.get_fully_qualified_name(),
                                  message=self.session.state + (
                                      f': {self.session.reason}' if self.session.reason
                                      else ''))
        status.values = [KeyValue(key=key, value=value) for key, value in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def shutdown_command(self, reason: str) -> None:
        """Stop with 0 V before the node goes away and wait until the command is delivered."""
        with self._lock:
            self.session.stop(reason)
            self.publish_command(0.0)
        try:
            self._report()
            self.command_publisher.wait_for_all_acked(Duration(seconds=1.0))
        except Exception:  # noqa: BLE001  (the 0 V went out; an ack is best effort)
            pass

    def close(self) -> None:
        """Release the helper node of the measurement subscriptions."""
        self.inputs.destroy()


def main(args: Optional[list[str]] = None) -> int:
    """Run the ``exciter`` node; ``exciter --plan ...`` prints a plan instead (no ROS)."""
    argv = list(sys.argv[1:] if args is None else args)
    own = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if '--plan' in own:
        from dcmotor_id.console.command_line import run_reporting
        from dcmotor_id.console.plan import plan_parser, run_plan
        return run_reporting(run_plan, plan_parser().parse_args(
            [item for item in own if item != '--plan']))
    # Own handlers: rclpy's would shut the context down before the 0 V could be published.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    received: list[int] = []
    node: Optional[Exciter] = None

    def on_signal(number: int, _: Any) -> None:
        received.append(number)
        if node is not None:
            try:
                node.publish_command(0.0)  # at once; the loop below stops cleanly after it
            except Exception:  # noqa: BLE001  (publishing mid-callback: the loop repeats it)
                pass

    previous = {number: signal.signal(number, on_signal)
                for number in (signal.SIGINT, signal.SIGTERM)}
    code = 0
    # threads: the command tick, ~/stop and ~/start (see the module docstring), one spare
    executor = MultiThreadedExecutor(num_threads=4)
    try:
        node = Exciter()
        executor.add_node(node)
        while rclpy.ok() and not received:
            executor.spin_once(timeout_sec=0.05)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as error:  # a bad parameter: say which and stop
        print(f'exciter: {error}', file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            if rclpy.ok():
                reason = f'signal {signal.Signals(received[0]).name}' if received else \
                    'node shut down'
                node.shutdown_command(reason)
            node.close()
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown()
        for number, handler in previous.items():
            signal.signal(number, handler)
    return code


if __name__ == '__main__':
    raise SystemExit(main())
