"""
The ROS demo (``make demo``): sim_motor and identifier as processes, then ``~/identify``.

Starts the two executables with the package's parameter files (the identifier's
``window_s`` and ``min_window_s`` set to ``--record-s``), waits until the identifier holds a
whole window of ``--record-s`` seconds of aligned samples (printing the online estimate as
it converges; it gives up, saying so, when none comes within a minute more), calls
``/identifier/identify`` and prints the identified parameters against the simulated motor's,
the paper method's for comparison, the online estimate and where the window bags are, with
the samples and windows fitted. A fit of less data than announced is refused (exit code 1),
never printed as a result.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from typing import IO, Optional, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import rclpy
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from std_srvs.srv import Trigger

from dcmotor_id.core.model import DERIVED_NAMES, PAPER_MOTORS, PARAMETER_NAMES, UNITS
from dcmotor_id.nodes.common import spin_until, stop_processes
from dcmotor_id.nodes.identifier import LATCHED

KEYS = PARAMETER_NAMES + DERIVED_NAMES
#: How long past ``--record-s`` the demo waits for the samples it announced [s].
WAIT_EXTRA_S = 60.0


def _config(name):
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    path = os.path.join(here, 'config', f'{name}.yaml')
    return ['--params-file', path] if os.path.isfile(path) else []


def _executable(name):
    path = os.path.join(os.path.dirname(sys.executable), name)
    if not os.path.exists(path):
        raise FileNotFoundError(f'{path} not found: install the package (pip install -e .)')
    return path


def status_values(status: DiagnosticStatus) -> dict[str, str]:
    """Return the key-value pairs of a diagnostic status as a dict."""
    return {kv.key: kv.value for kv in status.values}


def local_ros_domain() -> None:
    """Keep a demo's discovery on this host, in a domain of its own (unless set already)."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))


def close_demo(processes: Sequence[subprocess.Popen], executor: Executor, node: Node,
               logs: IO[str]) -> None:
    """End a demo: stop its node processes, its executor and node, rclpy; close the log."""
    stop_processes(processes)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    logs.close()


def run_demo(record_s: float = 12.0, record_dir: Optional[str] = None) -> int:
    """Run the demo; return the exit code."""
    local_ros_domain()
    record_dir = record_dir or os.path.join(tempfile.gettempdir(), 'dcmotor_id_demo',
                                            time.strftime('%Y%m%d-%H%M%S'))
    truth = PAPER_MOTORS['paper2'].as_dict()
    processes, logs = _start_nodes(record_dir, record_s)
    rclpy.init()
    node = rclpy.create_node('dcmotor_id_demo')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    online: list[DiagnosticStatus] = []
    latched: list[DiagnosticStatus] = []
    diagnostics: list[DiagnosticArray] = []
    node.create_subscription(DiagnosticStatus, '/identifier/online_parameters', online.append,
                             10)
    node.create_subscription(DiagnosticStatus, '/identifier/parameters', latched.append,
                             LATCHED)
    node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 50)
    try:
        client = node.create_client(Trigger, '/identifier/identify')
        if not client.wait_for_service(timeout_sec=60.0):
            print(f'the identifier did not come up; see {logs.name}')
            return 1
        rate_hz = _sample_rate(node, executor)
        if not _record(executor, online, diagnostics, record_s, rate_hz):
            print(f'the identifier did not receive {record_s:g} s of samples within '
                  f'{record_s + WAIT_EXTRA_S:g} s (a loaded machine, or a node that failed); '
                  f'see {logs.name}')
            return 1
        print('calling /identifier/identify ...', flush=True)
        future = client.call_async(Trigger.Request())
        if not spin_until(executor, future.done, 300.0):
            print('no answer from /identifier/identify within 300 s')
            return 1
        response = future.result()
        if not response.success:
            print(f'identification failed: {response.message}')
            return 1
        if not _enough(response.message, record_s, rate_hz):
            return 1
        spin_until(executor, lambda: latched, 10.0)
        _print_results(truth, latched, diagnostics, online, response.message)
        print(f'all windows: {record_dir}   node logs: {logs.name}')
        return 0
    finally:
        close_demo(processes, executor, node, logs)


def _print_results(truth: dict[str, float], latched: list[DiagnosticStatus],
                   diagnostics: list[DiagnosticArray], online: list[DiagnosticStatus],
                   answer: str) -> None:
    """Print the table, the online estimate's state and the bags identified."""
    paper = {}
    for array in diagnostics:
        for status in array.status:
            if status.name.endswith('paper method') and status.values:
                paper = status_values(status)
    estimate = status_values(online[-1]) if online else {}
    _print_table(truth, status_values(latched[-1]), paper, estimate)
    if estimate:
        print(f'online estimate: converged={estimate["converged"]}, innovation RMS '
              f'current {float(estimate["innovation_rms_current_A"]):.3g} A, speed '
              f'{float(estimate["innovation_rms_speed_rad_s"]):.3g} rad/s, '
              f'{estimate["n_updates"]} sample pairs')
    bags = answer.split('; bags: ')[-1].split('; ')[0].split(', ') \
        if '; bags: ' in answer else []
    print('window bags identified (rosbag2, MCAP; dcmotor-id identify BAG reads them):')
    for bag in bags:
        print(f'  {bag}')


def _enough(message: str, record_s: float, rate_hz: float) -> bool:
    """Say how much data the fit used; refuse (False) less than announced."""
    found = re.search(r'(\d+) samples in (\d+) window', message)
    if found is None:
        print(f'the answer does not say how much data was fitted: {message}')
        return False
    samples, windows = int(found.group(1)), int(found.group(2))
    print(f'fitted {samples} samples ({samples / rate_hz:.3f} s at {rate_hz:g} Hz) in '
          f'{windows} window(s); announced {record_s:g} s', flush=True)
    if samples < round(record_s * rate_hz) - 1:  # a window is closed at its last sample
        print(f'refused: the fit used {samples / rate_hz:.3f} s of data, less than the '
              f'{record_s:g} s announced (samples lost on a loaded machine?); run again')
        return False
    return True


def _sample_rate(node: Node, executor: Executor) -> float:
    """Return the identifier's ``sample_rate_hz`` (1000.0 when it cannot be read)."""
    from rcl_interfaces.srv import GetParameters

    client = node.create_client(GetParameters, '/identifier/get_parameters')
    try:
        if not client.wait_for_service(timeout_sec=10.0):
            return 1000.0
        future = client.call_async(GetParameters.Request(names=['sample_rate_hz']))
        if not spin_until(executor, future.done, 10.0) or not future.result().values:
            return 1000.0
        return float(future.result().values[0].double_value) or 1000.0
    finally:
        node.destroy_client(client)


def _start_nodes(record_dir: str, record_s: float) -> tuple[list[subprocess.Popen], IO[str]]:
    """Start sim_motor and the identifier; return the processes and their log."""
    print(f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}; starting sim_motor (motor 2 of the '
          "paper's Table 1, 1 kHz, Float64 topics) and identifier (windows to "
          f'{record_dir})', flush=True)
    logs = open(os.path.join(tempfile.gettempdir(), 'dcmotor_id_demo_nodes.log'), 'w')
    processes = [
        subprocess.Popen([_executable('sim_motor'), '--ros-args', *_config('sim_motor')],
                         stdout=logs, stderr=subprocess.STDOUT),
        subprocess.Popen([_executable('identifier'), '--ros-args', *_config('identifier'),
                          '-p', f'record_dir:={record_dir}',
                          '-p', f'window_s:={float(record_s)!r}',
                          '-p', f'min_window_s:={float(record_s)!r}'],
                         stdout=logs, stderr=subprocess.STDOUT)]
    return processes, logs


def _record(executor: Executor, online: list[DiagnosticStatus],
            diagnostics: list[DiagnosticArray], record_s: float, rate_hz: float) -> bool:
    """
    Spin until the identifier holds a full window of ``record_s``; print the online estimate.

    The identifier runs with ``window_s`` and ``min_window_s`` both ``record_s``: it keeps
    only whole windows of that length (a run cut short by a lost sample is dropped), and
    ``~/identify`` fits the newest one, the same length every time. Returns False when none
    is complete within ``record_s + WAIT_EXTRA_S`` seconds.
    """
    need = int(round(record_s * rate_hz))
    print(f'recording {record_s:g} s ({need} samples at {rate_hz:g} Hz) ...', flush=True)
    start = time.monotonic()
    while True:
        spin_until(executor, lambda: False, 2.0)
        emitted, windows = _streams(diagnostics)
        elapsed = time.monotonic() - start
        if online:
            values = status_values(online[-1])
            print(f'  {elapsed:4.0f} s  {emitted:6d} samples  online: '
                  f'Ra={float(values["Ra"]):.4g} La={float(values["La"]):.4g} '
                  f'CPhi={float(values["CPhi"]):.4g} J={float(values["J"]):.4g}  '
                  f'converged={values["converged"]}', flush=True)
        if windows >= 1:
            return True
        if elapsed > record_s + WAIT_EXTRA_S:
            return False


def _streams(diagnostics: list[DiagnosticArray]) -> tuple[int, int]:
    """Return the aligned samples and whole windows of the latest ``streams`` status."""
    for array in reversed(diagnostics):
        for status in array.status:
            if status.name.endswith('streams'):
                values = status_values(status)
                return (int(values.get('emitted', '0')),
                        int(values.get('windows_in_memory', '0')))
    return 0, 0


def _print_table(truth: dict[str, float], *sources: dict[str, str]) -> None:
    """Print the identified, paper and online values beside the truth, with their errors."""
    print()
    print(f'{"":<6}{"truth":>12}' + ''.join(
        f'{name:>13}{"err %":>9}' for name in ('identified', 'paper', 'online')))
    for key in KEYS:
        row = f'{key:<6}{truth[key]:>12.5g}'
        for source in sources:
            if key in source:
                value = float(source[key])
                row += f'{value:>13.5g}{abs(value / truth[key] - 1) * 100:>9.2g}'
            else:
                row += f'{"-":>13}{"":>9}'
        print(row + f'  {UNITS[key]}')


def main(argv: Optional[list[str]] = None) -> int:
    """Parse the options and run the demo."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--record-s', type=float, default=12.0,
                        help='seconds to record before identifying (default 12)')
    parser.add_argument('--record-dir', help='where the identifier writes its window bags')
    args = parser.parse_args(argv)
    return run_demo(args.record_s, args.record_dir)


if __name__ == '__main__':
    sys.exit(main())
