"""Helpers shared by the tests: processes in /proc, a spinning ROS executor, waits, goals."""

import contextlib
import os
import threading
import time

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

#: Bag time of the first sample of :func:`motor_samples` [ns].
START_NS = 1_700_000_000_000_000_000


def children(pid):
    """
    Process ids whose parent is ``pid``, from /proc (psutil is not installed).

    Zombies and multiprocessing's resource tracker (it ends with its parent) are left out: what
    remains is what a test must see gone.
    """
    found = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/stat') as stream:
                fields = stream.read().rsplit(')', 1)[1].split()
            with open(f'/proc/{entry}/cmdline', 'rb') as stream:
                command = stream.read()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != 'Z' and b'resource_tracker' not in command:
            found.append(int(entry))
    return found


def alive(pid):
    """Whether a process exists and is not a zombie."""
    try:
        with open(f'/proc/{pid}/stat') as stream:
            return stream.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def wait_for(condition, timeout_s, step_s=0.05):
    """Poll ``condition`` until it is true or ``timeout_s`` has passed; return whether it was."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(step_s)
    return False


@contextlib.contextmanager
def spinning_executor(errors=None):
    """
    Initialise rclpy and spin a SingleThreadedExecutor on a thread; shut both down after.

    Exceptions of ``spin_once`` (a node removed while the executor waited on it) are appended to
    ``errors`` when a list is given, else ignored.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    rclpy.init()
    executor = SingleThreadedExecutor()
    running = threading.Event()
    running.set()

    def spin():
        while running.is_set() and rclpy.ok():
            try:
                executor.spin_once(timeout_sec=0.1)
            except Exception as error:  # noqa: BLE001  (see the docstring)
                if errors is not None:
                    errors.append(error)

    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    try:
        yield executor
    finally:
        running.clear()
        thread.join(timeout=5)
        executor.shutdown()
        rclpy.try_shutdown()


def call(node, service, timeout_s=60.0, wait_s=10.0):
    """Call a std_srvs/Trigger service from ``node`` (spun elsewhere); return the response."""
    from std_srvs.srv import Trigger

    client = node.create_client(Trigger, service)
    assert client.wait_for_service(timeout_sec=wait_s)
    future = client.call_async(Trigger.Request())
    assert wait_for(future.done, timeout_s, 0.01), f'{service} did not answer in {timeout_s} s'
    node.destroy_client(client)
    return future.result()


def motor_samples(duration_s=10.0, sample_period_s=1e-3, noise=(0.01, 0.02), seed=0):
    """
    Return the sample stamps [ns] and noisy channels of paper2 under the paper excitation.

    ``noise``: standard deviations of the current [A] and speed [rad/s] noise; the stamps
    start at :data:`START_NS`.
    """
    _, voltage = make_excitation('paper', duration_s, sample_period_s)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, sample_period_s)
    rng = np.random.default_rng(seed)
    current = current + rng.normal(0, noise[0], current.size)
    speed = speed + rng.normal(0, noise[1], speed.size)
    stamps = START_NS + np.arange(voltage.size, dtype=np.int64) * int(round(sample_period_s * 1e9))
    return stamps, {'voltage': voltage, 'current': current, 'speed': speed}


def remove_nodes(executor, *nodes):
    """Remove ``nodes`` from ``executor``, close those that have ``close`` and destroy them."""
    for node in nodes:
        executor.remove_node(node)
        closer = getattr(node, 'close', None)
        if closer:
            closer()
        node.destroy_node()


def assert_near_truth(parameters, truth, **relative):
    """Assert each named parameter within its relative tolerance of the truth's (``Ra=0.05``)."""
    for name, tolerance in relative.items():
        assert parameters[name] == pytest.approx(getattr(truth, name), rel=tolerance), name
