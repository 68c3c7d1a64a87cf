"""What the nodes share: parameter declaration, the sample QoS, spinning and ``main``."""

import sys
import time

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Reliability names accepted by the ``qos_reliability`` parameters.
RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
               'best_effort': ReliabilityPolicy.BEST_EFFORT}


def declare(node, name, default, description, low=None, high=None, choices=None,
            read_only=False):
    """
    Declare a parameter with a descriptor and return its value.

    ``low``/``high`` give an inclusive range for numbers (checked by rclpy); ``choices`` is
    listed in the description and checked by :func:`check_choice`.
    """
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
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
    value = node.declare_parameter(name, default, descriptor).value
    if choices is not None:
        check_choice(name, value, choices)
    return value


def check_choice(name, value, choices):
    """Raise ``ValueError`` naming the choices when ``value`` is not one of them."""
    if value not in choices:
        raise ValueError(f'parameter {name} = {value!r}: choose one of {", ".join(choices)}')


def sample_qos(depth, reliability):
    """Return the QoS of the sample topics: keep-last ``depth``, reliable or best effort."""
    check_choice('qos_reliability', reliability, RELIABILITY)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=RELIABILITY[reliability])


def spin_until(executor, condition, timeout_s):
    """Spin ``executor`` until ``condition()`` holds; return whether it did within the time."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
        if condition():
            return True
    return False


def run(node_class, args=None, until=None):
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
