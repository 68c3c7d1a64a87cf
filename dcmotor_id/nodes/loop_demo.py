"""
The closed-loop demo (``make demo-loop``): plan, excite, identify, compare the standard errors.

Plans a D-optimal PRBS / multisine for the paper's motor 2 within the exciter's default limits
(:mod:`dcmotor_id.design.experiment`), starts ``sim_motor`` (following ``voltage_command``, batched
samples), the ``identifier`` and the ``exciter`` (driving the plan) as processes, calls
``/exciter/start``, waits until the routine is done, calls ``/identifier/identify`` and prints
the identified parameters beside the truth with the plan's expected standard errors (the
Cramer-Rao bounds) and the identifier's achieved ones.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from typing import Any, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger

from dcmotor_id.core.model import DERIVED_NAMES, PAPER_MOTORS, PARAMETER_NAMES, UNITS
from dcmotor_id.design.experiment import DEFAULT_NOISE, design_experiment
from dcmotor_id.design.routines import Limits
from dcmotor_id.formats.json_file import write_json
from dcmotor_id.nodes.common import spin_until
from dcmotor_id.nodes.demo import close_demo, local_ros_domain, status_values
from dcmotor_id.nodes.identifier import LATCHED

KEYS = PARAMETER_NAMES + DERIVED_NAMES


def _node_command(name: str, *arguments: str) -> list[str]:
    path = os.path.join(os.path.dirname(sys.executable), name)
    command = [path] if os.path.exists(path) else \
        [sys.executable, '-m', f'dcmotor_id.nodes.{name}']
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    config = os.path.join(here, 'config', f'{name}.yaml')
    files = ['--params-file', config] if os.path.isfile(config) else []
    return command + ['--ros-args', *files, *arguments]


def _call(node: Any, executor: Any, name: str, timeout_s: float) -> Optional[Any]:
    client = node.create_client(Trigger, name)
    if not client.wait_for_service(timeout_sec=60.0):
        return None
    future = client.call_async(Trigger.Request())
    return future.result() if spin_until(executor, future.done, timeout_s) else None


def run_loop_demo(duration_s: float = 10.0, current_limit_a: float = 10.0,
                  work_dir: Optional[str] = None) -> int:
    """Run the demo; return the exit code."""
    local_ros_domain()
    work_dir = work_dir or os.path.join(tempfile.gettempdir(), 'dcmotor_id_loop',
                                        time.strftime('%Y%m%d-%H%M%S'))
    os.makedirs(work_dir, exist_ok=True)
    motor = PAPER_MOTORS['paper2']
    limits = Limits(voltage_v=48.0, current_a=current_limit_a, speed_rad_s=100.0)
    plan, plan_file = _plan(motor, limits, duration_s, work_dir)
    processes, logs = _start_nodes(work_dir, duration_s, limits, plan, plan_file)
    rclpy.init()
    node = rclpy.create_node('dcmotor_id_loop_demo')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    states: list[dict[str, str]] = []
    latched: list[DiagnosticStatus] = []

    def on_diagnostics(message: DiagnosticArray) -> None:
        states.extend(status_values(status) for status in message.status
                      if status.name.endswith('excitation'))
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 50)
    node.create_subscription(DiagnosticStatus, '/identifier/parameters', latched.append,
                             LATCHED)
    try:
        if not _start_routine(node, executor, logs.name):
            return 1
        if not _follow_routine(executor, states, duration_s):
            return 1
        spin_until(executor, lambda: False, 1.0)  # the motor comes to rest
        print('calling /identifier/identify ...', flush=True)
        response = _call(node, executor, '/identifier/identify', 300.0)
        if response is None or not response.success:
            print(f'identification failed: {response.message if response else "no answer"}')
            return 1
        if not spin_until(executor, lambda: latched, 10.0):
            print('no /identifier/parameters')
            return 1
        found = {key: float(value) for key, value in status_values(latched[-1]).items()}
        _print_comparison(found, motor.as_dict(), plan.expected_stderr)
        print(f'plan: {plan_file}; windows: {work_dir}/windows')
        return 0
    finally:
        close_demo(processes, executor, node, logs)


def _plan(motor: Any, limits: Limits, duration_s: float, work_dir: str) -> tuple[Any, str]:
    """Plan the experiment for the prior within the limits; write it; return it and its file."""
    print(f'planning for motor 2 of the paper (the prior), limits {limits.voltage_v:g} V, '
          f'{limits.current_a:g} A, {limits.speed_rad_s:g} rad/s; sim_motor noise '
          f'{DEFAULT_NOISE["current"]:g} A, {DEFAULT_NOISE["speed"]:g} rad/s ...', flush=True)
    plan = design_experiment(motor, limits, DEFAULT_NOISE, duration_s=duration_s)
    plan_file = os.path.join(work_dir, 'plan.json')
    write_json(plan_file, plan.as_dict())
    print('\n'.join(plan.describe().split('\ncandidates:')[0].splitlines()[:3]))
    return plan, plan_file


def _start_nodes(work_dir: str, duration_s: float, limits: Limits, plan: Any,
                 plan_file: str) -> tuple[list[subprocess.Popen], Any]:
    """Start sim_motor, the identifier and the exciter; return the processes and their log."""
    logs = open(os.path.join(work_dir, 'nodes.log'), 'w')
    batch = ['-p', 'input:=batch']
    commands = [
        _node_command('sim_motor', '-p', 'transport:=batch', '-p', 'use_voltage_command:=true'),
        _node_command('identifier', *batch, '-p', f'record_dir:={work_dir}/windows', '-p',
                      f'window_s:={duration_s + 2.0}', '-p', 'discover:=false', '-p',
                      'compare_paper:=false', '-p', 'online:=false'),
        _node_command('exciter', *batch, '-p', f'plan_file:={plan_file}', '-p',
                      f'current_limit_a:={limits.current_a}', '-p',
                      f'rate_hz:={plan.rate_hz}', '-p', f'ramp_in_s:={plan.ramp_in_s}')]
    print(f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}; starting sim_motor, identifier and '
          f'exciter (logs: {logs.name})', flush=True)
    return [subprocess.Popen(command, stdout=logs, stderr=subprocess.STDOUT)
            for command in commands], logs


def _start_routine(node: Any, executor: Any, log_name: str) -> bool:
    """Call ``/exciter/start`` until it starts (once measurements flow), for up to 60 s."""
    deadline = time.monotonic() + 60.0
    response = None
    while time.monotonic() < deadline:  # the exciter starts once measurements flow
        response = _call(node, executor, '/exciter/start', 20.0)
        if response is not None and response.success:
            break
        spin_until(executor, lambda: False, 1.0)
    if response is None or not response.success:
        print(f'the exciter did not start: {response.message if response else "no answer"}'
              f'; see {log_name}')
        return False
    print(f'/exciter/start: {response.message}', flush=True)
    return True


def _follow_routine(executor: Any, states: list[dict[str, str]], duration_s: float) -> bool:
    """Print the exciter's progress until its routine ends; return whether it is done."""
    shown = ''
    final = ('done', 'stopped', 'stopped-by-limit', 'stale')
    deadline = time.monotonic() + duration_s + 60.0
    while time.monotonic() < deadline:
        spin_until(executor, lambda: False, 1.0)
        if states and f'{states[-1]["state"]} {states[-1]["progress"]}' != shown:
            shown = f'{states[-1]["state"]} {states[-1]["progress"]}'
            print(f'  exciter: {states[-1]["state"]:<12} progress '
                  f'{float(states[-1]["progress"]):4.0%}  command '
                  f'{float(states[-1]["command_v"]):7.2f} V  peak current '
                  f'{float(states[-1]["peak_current_a"]):5.2f} A', flush=True)
        if states and states[-1]['state'] in final:
            break
    if not states or states[-1]['state'] != 'done':
        print(f'the routine did not complete: {states[-1] if states else "no state"}')
        return False
    return True


def _print_comparison(found: dict[str, float], truth: dict[str, float],
                      expected_stderr: dict[str, float]) -> None:
    """Print the identified values beside the truth, the expected and achieved errors."""
    print()
    print(f'{"":<6}{"truth":>11}{"identified":>13}{"error":>11}{"expected se":>13}'
          f'{"achieved se":>13}{"ach/exp":>9}{"|err|/exp":>11}')
    for key in KEYS:
        expected = expected_stderr[key]
        achieved = found.get(f'{key}_stderr', float('nan'))
        error = found[key] - truth[key]
        print(f'{key:<6}{truth[key]:>11.5g}{found[key]:>13.6g}{error:>11.2e}'
              f'{expected:>13.3g}{achieved:>13.3g}{achieved / expected:>9.2f}'
              f'{abs(error) / expected:>11.2f}  {UNITS[key]}')
    print("expected se: the plan's Cramer-Rao bound; achieved se: the identifier's "
          'reported standard error on the recorded windows.')


def main(argv: Optional[list[str]] = None) -> int:
    """Parse the options and run the demo."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').split('\n')[1])
    parser.add_argument('--duration-s', type=float, default=10.0,
                        help='length of the planned routine (default 10)')
    parser.add_argument('--current-limit', type=float, default=10.0,
                        help='current limit of the plan and of the exciter [A] (default 10)')
    parser.add_argument('--work-dir', help='where the plan, the window bags and logs go')
    args = parser.parse_args(argv)
    return run_loop_demo(args.duration_s, args.current_limit, args.work_dir)


if __name__ == '__main__':
    sys.exit(main())
