"""What the nodes share: parameter declaration, the sample QoS, bulk input, spinning, ``main``."""

from __future__ import annotations

from dataclasses import fields
import errno
import functools
import os
import re
import signal
import stat
import subprocess
import sys
import time
from typing import Any, Callable, Optional, Sequence, TypeVar

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from dcmotor_id.core.errors import InputDataError

#: Reliability names accepted by the ``qos_reliability`` parameters.
RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
               'best_effort': ReliabilityPolicy.BEST_EFFORT}
#: QoS of the nodes' services: the default (keep-last 10) drops the oldest requests of a
#: burst before the executor takes them, so that those callers never get an answer.
SERVICE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)


def declare(node: Node, name: str, default: Any, description: str, low: Optional[float] = None,
            high: Optional[float] = None, choices: Optional[Sequence[str]] = None,
            read_only: bool = False, dynamic_typing: bool = False) -> Any:
    """
    Declare a parameter with a descriptor and return its value.

    ``low``/``high`` give an inclusive range for numbers (checked by rclpy); ``choices`` is
    listed in the description and checked by :func:`check_choice`; with ``dynamic_typing`` a
    value of any type is taken (the node checks it).
    """
    descriptor = ParameterDescriptor(description=description, read_only=read_only,
                                     dynamic_typing=dynamic_typing)
    if choices:
        descriptor.additional_constraints = 'one of: ' + ', '.join(choices)
    if low is not None or high is not None:
        if isinstance(default, bool):
            pass
        elif isinstance(default, int):
            descriptor.integer_range = [IntegerRange(
                from_value=int(low if low is not None else -2 ** 62),
                to_value=int(high if high is not None else 2 ** 62), step=0)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(low if low is not None else -1e300),
                to_value=float(high if high is not None else 1e300), step=0.0)]
    try:
        value = node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException as error:
        raise ValueError(f'parameter {name}: {str(error).splitlines()[0]}') from None
    except InvalidParameterValueException as error:
        # a value given at start-up outside the range: one line, exit 2 (run)
        given = re.search(r'value \((.*?)\)', str(error))
        raise ValueError(
            f'parameter {name} = {given.group(1) if given else "?"} is out of range: give a '
            f'value from {low if low is not None else "-inf"} to '
            f'{high if high is not None else "inf"}') from None
    if choices is not None:
        check_choice(name, value, choices)
    return value


Settings = TypeVar('Settings')


def declare_settings(node: Node, settings_class: type[Settings]) -> Settings:
    """
    Declare one parameter per field of a settings dataclass; return the values as one.

    Each field's metadata holds ``description``, ``low``, ``high`` and ``choices`` (see
    :func:`dcmotor_id.nodes.settings.parameter`); fields are declared in their order.
    """
    values = {item.name: declare(node, item.name, item.default, **item.metadata)
              for item in fields(settings_class)}  # type: ignore[arg-type]
    return settings_class(**values)


def guard_parameters(node: Node, startup_only: Sequence[str],
                     checks: Optional[dict[str, Callable[[Any], Any]]] = None) -> None:
    """
    Answer every run-time change of a node's parameters truthfully.

    A parameter of ``startup_only`` is read once, when the node starts: a change is refused
    with "restart the node" instead of being taken and ignored.  A parameter of ``checks``
    applies at run time: its check (raising ``ValueError`` with the reason, the rule used at
    start-up) decides.  Call it after the parameters are declared.
    """
    names = frozenset(startup_only)

    def on_set(parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name in names:
                return SetParametersResult(successful=False, reason=(
                    f'parameter {parameter.name} is read at start-up only: restart the node '
                    f'with the new value (--ros-args -p {parameter.name}:=...)'))
            check = (checks or {}).get(parameter.name)
            if check is not None:
                try:
                    check(parameter.value)
                except ValueError as error:
                    return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)
    node.add_on_set_parameters_callback(on_set)


def own_parameters(node: Node) -> list[str]:
    """Return the names of a node's declared parameters, without rclpy's ``use_sim_time``."""
    return [name for name in node._parameters if name != 'use_sim_time']


def check_writable_directory(path: str, name: str) -> str:
    """
    Return ``path`` (``~`` expanded), created if missing; ValueError when it is not writable.

    Used at start-up for a node's output directory (``record_dir``): a node that cannot write
    where it was told refuses to start instead of running without its output.
    """
    place = os.path.expanduser(path)
    try:
        os.makedirs(place, exist_ok=True)
        probe = os.path.join(place, f'.dcmotor_id_probe_{os.getpid()}')
        with open(probe, 'w', encoding='utf-8'):
            pass
        os.unlink(probe)
    except OSError as error:
        raise ValueError(f'parameter {name} = {path!r}: cannot write there '
                         f'({error.strerror or error}); give a writable directory') from None
    return place


def guarded(callback: Callable[..., Any]) -> Callable[..., Any]:
    """Log an unexpected error of a node's timer callback instead of stopping the executor."""
    @functools.wraps(callback)
    def run(self: Node, *args: Any) -> Any:
        try:
            return callback(self, *args)
        except Exception as error:  # noqa: BLE001  (the node must outlive any bad input)
            self.get_logger().error(f'{callback.__name__}: {type(error).__name__}: {error}',
                                    throttle_duration_sec=5.0)
            return None
    return run


class ResultParameters:
    """
    Parameters ``<prefix><name>`` that publish a node's results and refuse to be set by others.

    ``defaults`` maps each name to its initial value (its type is the parameter's type);
    ``source`` names what sets them, in the refusal.
    """

    def __init__(self, node: Node, prefix: str, defaults: dict[str, Any], source: str) -> None:
        self.node = node
        self.prefix = prefix
        self.source = source
        self._setting = False
        for name, value in defaults.items():
            node.declare_parameter(prefix + name, value)
        node.add_on_set_parameters_callback(self._guard)

    def _guard(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            if not self._setting and parameter.name.startswith(self.prefix):
                return SetParametersResult(
                    successful=False,
                    reason=f'{parameter.name} is a result of {self.source}, not a setting')
        return SetParametersResult(successful=True)

    def publish(self, values: dict[str, Any]) -> None:
        """Set the result parameters named in ``values`` at once."""
        self._setting = True
        try:
            self.node.set_parameters([Parameter(self.prefix + name, value=value)
                                      for name, value in values.items()])
        finally:
            self._setting = False


def read_regular_file(path: str, what: str, max_bytes: int = 16 * 2 ** 20) -> str:
    """
    Return the text of a regular file of at most ``max_bytes``, never blocking on it.

    A FIFO, a device (``/dev/zero``), a directory or a symlink loop is refused by name: the
    file is opened without blocking and checked before anything is read.

    Raises
    ------
    InputDataError
        Naming ``what`` (e.g. ``plan_file``), the path, what it is and what to give instead.

    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, 'O_CLOEXEC', 0))
    except OSError as error:
        why = 'a symlink loop' if error.errno == errno.ELOOP else \
            (error.strerror or str(error)).lower()
        raise InputDataError(f'{what} {path!r}: {why}; give a regular file') from None
    try:
        mode = os.fstat(descriptor).st_mode
        if not stat.S_ISREG(mode):
            kind = 'a FIFO' if stat.S_ISFIFO(mode) else 'a directory' if stat.S_ISDIR(mode) \
                else 'a device' if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else \
                'a socket' if stat.S_ISSOCK(mode) else 'a special file'
            raise InputDataError(f'{what} {path!r} is {kind}, not a regular file; give a '
                                 'regular file')
        with os.fdopen(descriptor, 'rb', closefd=False) as stream:
            data = stream.read(max_bytes + 1)
    finally:
        os.close(descriptor)
    if len(data) > max_bytes:
        raise InputDataError(f'{what} {path!r} is larger than {max_bytes} bytes; give the '
                             'file that dcmotor-id wrote')
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError as error:
        raise InputDataError(f'{what} {path!r} is not UTF-8 text ({error})') from None


def check_choice(name: str, value: Any, choices: Any) -> None:
    """Raise ``ValueError`` naming the choices when ``value`` is not one of them."""
    if value not in choices:
        raise ValueError(f'parameter {name} = {value!r}: choose one of {", ".join(choices)}')


def sample_qos(depth: int, reliability: str) -> QoSProfile:
    """Return the QoS of the sample topics: keep-last ``depth``, reliable or best effort."""
    check_choice('qos_reliability', reliability, RELIABILITY)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=RELIABILITY[reliability])


class BulkInput:
    """
    Subscriptions whose messages are taken in bulk by :meth:`take` instead of by an executor.

    They live on a hidden helper node that no executor spins: a timer of the owner takes every
    queued message in one go (a few microseconds each) instead of paying a full executor
    cycle per message (about ten times more). Remapping the topics globally
    (``-r voltage:=...``) applies to the helper too.
    """

    def __init__(self, node: Node) -> None:
        self.node = rclpy.create_node(f'_{node.get_name()}_input',
                                      namespace=node.get_namespace(), context=node.context,
                                      start_parameter_services=False)
        self._inputs: list[tuple[Any, Callable[[Any, dict], None]]] = []
        #: Messages that could not be taken or handled (each logged, throttled).
        self.errors = 0
        self._logger = node.get_logger()

    def add(self, message_type: Any, topic: str, qos: QoSProfile,
            handler: Callable[[Any, dict], None]) -> None:
        """Subscribe to ``topic``; :meth:`take` calls ``handler(message, info)`` per message."""
        subscription = self.node.create_subscription(message_type, topic, lambda _: None, qos)
        self._inputs.append((subscription, handler))

    def take(self, limit: int = 200_000) -> int:
        """
        Take every queued message (at most ``limit``), hand it to its handler; count them.

        A message that cannot be taken or handled is logged with its topic and skipped; the
        others are still taken.
        """
        taken = 0
        for subscription, handler in self._inputs:
            while taken < limit:
                try:
                    with subscription.handle:
                        item = subscription.handle.take_message(subscription.msg_type, False)
                    if item is None:
                        break
                    taken += 1
                    handler(*item)
                except Exception as error:  # noqa: BLE001  (one bad message, not the node)
                    taken += 1
                    self.errors += 1
                    self._logger.error(
                        f'{subscription.topic_name}: message skipped: {type(error).__name__}: '
                        f'{error}', throttle_duration_sec=5.0)
        return taken

    def destroy(self) -> None:
        """Destroy the helper node and its subscriptions."""
        self.node.destroy_node()


def spin_until(executor: Executor, condition: Callable[[], Any], timeout_s: float) -> bool:
    """Spin ``executor`` until ``condition()`` holds; return whether it did within the time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if condition():
            return True
    return False


def stop_processes(processes: Sequence[subprocess.Popen], timeout_s: float = 20.0) -> None:
    """Stop node processes as ``ros2 launch`` does: SIGINT (reverse order), then SIGKILL."""
    for process in reversed(processes):
        process.send_signal(signal.SIGINT)
    for process in processes:
        try:
            process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()


def run(node_class: Callable[[], Node], args: Optional[list[str]] = None,
        until: Optional[Callable[[Any], bool]] = None) -> int:
    """
    Create the node, spin it, shut down cleanly.

    One thread is enough: long work (fits, bag writing) runs in workers of the node.  With
    ``until`` (a predicate of the node), spinning also stops once it returns true.
    """
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = node_class()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if until is None:
            executor.spin()
        else:
            while rclpy.ok() and not until(node):
                executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ValueError as error:  # a bad parameter: say which and stop
        print(f'{node_class.__name__}: {error}', file=sys.stderr)
        code = 2
    except Exception:  # noqa: BLE001  (the context was shut down by a signal mid-wait)
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            closer = getattr(node, 'close', None)
            if closer is not None:
                closer()
            node.destroy_node()
        rclpy.try_shutdown()
    return code
