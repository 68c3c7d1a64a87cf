"""
The identification job of the identifier node, runnable in a separate process (no ROS here).

The node hands the windows over as plain arrays; the job builds the records exactly as
:func:`dcmotor_id.io.read_bag` does, runs the chosen method and, for comparison, the paper's.
In a process of its own the fit neither holds the node's interpreter lock nor shares its core,
so the executor keeps taking samples at full rate while it runs.
"""

import os
import threading
import time

from dcmotor_id.errors import DcMotorIdError
from dcmotor_id.identify import identify, prepare_records
from dcmotor_id.records import record_from_stamps


def watch_parent(parent_pid, period_s=1.0):
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


def warm_up():
    """Import the numerical modules (and load the numba cache) ahead of the first job."""
    from dcmotor_id.simulation import motor_system  # noqa: F401
    return True


def identify_windows(windows, method, torque_constant, discover, compare_paper):
    """
    Identify the motor from windows ``[(stamps_ns, channels, source), ...]``.

    Returns
    -------
    tuple
        ``('ok', result)`` with the result dict of :func:`dcmotor_id.identify.identify` plus
        ``paper`` (the paper method's result, its error message, or None), or
        ``('error', message)`` when the data cannot identify the motor.

    """
    try:
        records = prepare_records([record_from_stamps(stamps, channels, source)
                                   for stamps, channels, source in windows], torque_constant)
        result = identify(records, method=method, torque_constant=torque_constant,
                          discover=discover)
    except DcMotorIdError as error:
        return 'error', str(error)
    paper = None
    if compare_paper and method != 'paper':
        try:
            paper = identify(records, method='paper', torque_constant=torque_constant,
                             discover=False)
        except DcMotorIdError as error:
            paper = str(error)
    result['paper'] = paper
    return 'ok', result
