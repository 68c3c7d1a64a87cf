"""
The identifier on topics published as a robot's drives publish them (issue 32).

For each publisher mode, at 500 Hz and 1 kHz, the paper's motor 2 under the paper's
excitation (6 s, 1 % noise on current and speed) is published in real time by
:class:`dcmotor_id.nodes.drive_emulator.DrivePlayer` (header stamps from ``now()`` or on the
grid with jitter, 50 ms bursts, a voltage without header, the voltage at twice the rate,
Float64 topics by timestamp, batches, ros2_control's DynamicJointState: needs control_msgs,
``make control-msgs``) to an ``identifier`` node in the same process; ``~/identify``
is called once the drive has published everything. The table gives the share of the
published samples (at the identification rate) that the fit used, how each topic was placed
on the grid, and the relative errors of Ra, CPhi, J and b against the emulator's truth.

Usage (from the repository root; writes bench/robot_topics_results.md, about 3 minutes)::

    .venv/bin/python bench/bench_robot_topics.py [--duration 6] [--out FILE]
"""

import argparse
import datetime
import os
import platform
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

#: name -> (transport, identifier overrides, drive_messages options)
MODES = {
    'joint_states now() stamps, 50 ms bursts; voltage by source time': (
        'joint_state', {}, {'stamps': 'now', 'burst_s': 0.05}),
    'joint_states now() stamps, published when due; voltage by source time': (
        'joint_state', {}, {'stamps': 'now'}),
    'joint_states on the grid, 20 % jitter, 50 ms bursts; voltage by source time': (
        'joint_state', {}, {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05}),
    'voltage at twice the joint_states rate, now() bursts': (
        'joint_state', {}, {'stamps': 'now', 'burst_s': 0.05, 'voltage_rate': 2}),
    'Float64 topics by timestamp, 50 ms bursts': (
        'float64', {}, {'stamps': 'now', 'burst_s': 0.05}),
    'Float64 topics by timestamp, published when due': (
        'float64', {}, {'stamps': 'now'}),
    'batches of 50 ms bursts, sample times with 20 % jitter': (
        'batch', {}, {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05}),
    'mechanical only (torque_constant), now() bursts': (
        'joint_state', {'torque_constant': 0.7}, {'stamps': 'now', 'burst_s': 0.05}),
    # control_msgs' Python messages needed (make control-msgs, docs/nodes.md)
    'dynamic_joint_states now() stamps, 50 ms bursts (voltage an interface)': (
        'dynamic_joint_state', {}, {'stamps': 'now', 'burst_s': 0.05}),
    'dynamic_joint_states on the grid, 20 % jitter, 50 ms bursts': (
        'dynamic_joint_state', {}, {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05}),
}
KEYS = ('Ra', 'CPhi', 'J', 'b')


def placement(regrid):
    """Say in a few words how each topic was placed."""
    words = []
    for name, stats in regrid.items():
        how = 'on grid' if stats['snapped'] else 'resampled'
        kind = 'bursts' if stats['bursty'] else 'stamps'
        words.append(f"{name}: {how} ({kind}, x{stats['ratio']:g})")
    return '; '.join(words) or 'by the times in the batches'


def main():
    """Run the benchmark and write its table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--duration', type=float, default=6.0)
    parser.add_argument('--out', default=os.path.join(ROOT, 'bench',
                                                      'robot_topics_results.md'))
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    import threading

    from dcmotor_id.core.model import PAPER_MOTORS, relative_errors_pct
    from dcmotor_id.nodes.drive_emulator import identify_published

    truth = PAPER_MOTORS['paper2']
    rclpy.init()
    executor = SingleThreadedExecutor()
    running = threading.Event()
    running.set()

    def spin():
        while running.is_set() and rclpy.ok():
            try:
                executor.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001  (a node removed while waited on)
                pass
    thread = threading.Thread(target=spin, daemon=True)
    thread.start()
    rows = []
    started = time.monotonic()
    try:
        for number, (name, (transport, overrides, publish)) in enumerate(MODES.items()):
            for rate_hz in (500.0, 1000.0):
                overrides = dict(overrides)
                if 'torque_constant' in overrides:
                    overrides['torque_constant'] = truth.CPhi
                out = identify_published(executor, f'bench{number}_{int(rate_hz)}', rate_hz,
                                         args.duration, transport, identifier=overrides,
                                         seed=number, **publish)
                result = out['result']
                if not out['response'].success or result is None:
                    rows.append((name, rate_hz, out['samples'], 0, 'failed: ' +
                                 out['response'].message[:120], {}))
                    continue
                errors = relative_errors_pct(result['parameters'], truth)
                rows.append((name, rate_hz, out['samples'], result['n_samples'],
                             placement(out['regrid']),
                             {key: errors[key] for key in KEYS if key in errors and
                              not (key == 'Ra' and 'torque_constant' in overrides)}))
                print(f'{name} at {rate_hz:g} Hz: {result["n_samples"]} of '
                      f'{out["samples"]}', file=sys.stderr)
    finally:
        running.clear()
        thread.join(timeout=5)
        executor.shutdown()
        rclpy.try_shutdown()
    write(args, rows, time.monotonic() - started)
    return 0


def write(args, rows, elapsed_s):
    """Write the markdown table."""
    lines = ["# The identifier on a robot's topics (issue 32)", '',
             f'`bench/bench_robot_topics.py --duration {args.duration:g}`, '
             f'{datetime.date.today()}, {platform.node()} ({os.cpu_count()} cores, shared), '
             f'Python {platform.python_version()}; {elapsed_s:.0f} s in all.', '',
             'Paper motor 2, paper excitation, 1 % noise on current and speed; published in '
             'real time by `DrivePlayer`; `~/identify` with one window longer than the '
             'record. Used: samples fitted / samples published at the identification rate. '
             'Errors: relative to the emulator\'s truth [%] ("-": not identified in that '
             'mode). Every mode publishes the same noisy record at a rate: equal errors mean '
             'the alignment gave back the record sample for sample.',
             '', '| mode | rate | used | placement | ' + ' | '.join(
                 f'{key} [%]' for key in KEYS) + ' |',
             '|---|---|---|---|' + '---|' * len(KEYS)]
    for name, rate_hz, samples, used, how, errors in rows:
        share = f'{100.0 * used / samples:.2f} % ({used}/{samples})' if samples else '-'
        cells = ' | '.join(f'{errors[key]:+.3f}' if key in errors else '-' for key in KEYS)
        lines.append(f'| {name} | {rate_hz:g} Hz | {share} | {how} | {cells} |')
    text = '\n'.join(lines) + '\n'
    with open(args.out, 'w') as stream:
        stream.write(text)
    print(text)


if __name__ == '__main__':
    raise SystemExit(main())
