"""
Throughput and footprint of sim_motor -> identifier, as separate processes over real DDS.

Runs the installed executables (``.venv/bin/sim_motor`` and ``.venv/bin/identifier``) for each
case and reads the identifier's own counters from its ``/diagnostics`` streams status: samples
emitted (complete, aligned), lost (a channel never arrived), late, and the start-up samples
published before every topic was connected (not losses). CPU is process time over wall time
(100 % = one core); memory is the resident set size. Cases:

* Float64 topics (3 messages a sample) at 1 kHz for 60 s, then rising rates to find the
  highest sustainable message rate (no sample lost, the identifier keeps up);
* the batched transport (Float64MultiArray, 100 samples a message) at 10, 20 and 50 kHz;
* a soak at 1 kHz (Float64) with the resident memory sampled every 30 s.

Usage (from the repository root; writes bench/throughput_results.md)::

    .venv/bin/python bench/bench_throughput.py [--quick] [--soak-s 600] [--out FILE]
"""

import argparse
import datetime
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.executors import SingleThreadedExecutor

BIN = os.path.dirname(sys.executable)
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid):
    """User + system CPU time of a process [s]."""
    with open(f'/proc/{pid}/stat') as stream:
        fields = stream.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def rss_mib(pid):
    """Resident set size of a process [MiB]."""
    with open(f'/proc/{pid}/status') as stream:
        for line in stream:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    return float('nan')


class Streams:
    """Latest counters of the identifier (streams) and of sim_motor (drive) on /diagnostics."""

    def __init__(self, node):
        self.values = {}
        self.drive = {}
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_array, 50)

    def _on_array(self, array):
        for status in array.status:
            if status.name.endswith(': streams'):
                self.values = {kv.key: kv.value for kv in status.values}
            elif status.name.endswith(': drive'):
                self.drive = {kv.key: kv.value for kv in status.values}

    def count(self, key):
        """Integer counter ``key`` (0 before the first status)."""
        return int(self.values.get(key, 0))


def spin_for(executor, seconds):
    """Spin the executor for a while."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)


def run_case(executor, streams, rate_hz, transport, duration_s, record_dir, soak_every_s=0):
    """Run one case; return a dict of measurements."""
    common = ['-p', f'sample_rate_hz:={float(rate_hz)}']
    sim_args = common + ['-p', f'transport:={transport}']
    if transport == 'batch':
        sim_args += ['-p', 'batch_samples:=100', '-p', 'publish_rate_hz:=100.0']
    ident_args = common + ['-p', f'input:={transport}', '-p', f'record_dir:={record_dir}',
                           '-p', 'disk_budget_mb:=50.0']
    logs = open(os.path.join(record_dir, 'nodes.log'), 'a')
    ident = subprocess.Popen([os.path.join(BIN, 'identifier'), '--ros-args', *ident_args],
                             stdout=logs, stderr=subprocess.STDOUT)
    streams.values = {}
    spin_for(executor, 3.0)  # discovery and start-up before the drive starts
    sim = subprocess.Popen([os.path.join(BIN, 'sim_motor'), '--ros-args', *sim_args],
                           stdout=logs, stderr=subprocess.STDOUT)
    try:
        spin_for(executor, 5.0)  # warm-up: connections, first windows
        start = time.monotonic()
        cpu_start = {name: cpu_seconds(p.pid) for name, p in (('sim', sim), ('id', ident))}
        emitted_start = streams.count('emitted')
        published_start = int(streams.drive.get('published', 0))
        rss_trace = []
        while time.monotonic() - start < duration_s:
            spin_for(executor, min(soak_every_s or 5.0, duration_s - (time.monotonic() - start)))
            rss_trace.append((time.monotonic() - start, rss_mib(ident.pid)))
        wall = time.monotonic() - start
        cpu = {name: (cpu_seconds(p.pid) - cpu_start[name]) / wall * 100.0
               for name, p in (('sim', sim), ('id', ident))}
        rss = {'sim': rss_mib(sim.pid), 'id': rss_mib(ident.pid)}
        emitted_rate = (streams.count('emitted') - emitted_start) / wall
        published_rate = (int(streams.drive.get('published', 0)) - published_start) / wall
        spin_for(executor, 1.5)
        published = int(streams.drive.get('published', 0))  # the last report before the stop
        sim.send_signal(signal.SIGINT)
        sim.wait(timeout=30)
        spin_for(executor, 4.0)  # let the identifier drain and report
        counts = {key: streams.count(key) for key in
                  ('emitted', 'lost', 'late', 'duplicates', 'invalid', 'unmatched_at_start',
                   'first_sample', 'next_sample')}
    finally:
        for process in (sim, ident):
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
        logs.close()
    messages_per_sample = 3 if transport == 'float64' else 1.0 / 100
    # everything from the first sample it saw to the last one published went through
    kept_up = counts['lost'] == 0 and counts['late'] == 0 and \
        counts['next_sample'] >= published and \
        counts['emitted'] + counts['unmatched_at_start'] == \
        counts['next_sample'] - counts['first_sample']
    return {'rate_hz': rate_hz, 'transport': transport, 'duration_s': wall,
            'messages_per_s': rate_hz * messages_per_sample, 'emitted_rate': emitted_rate,
            'published_rate': published_rate, 'cpu': cpu, 'rss': rss, 'rss_trace': rss_trace,
            **counts, 'kept_up': kept_up,
            'sustained': kept_up and published_rate > 0.98 * rate_hz
            and emitted_rate > 0.98 * rate_hz}


def row(result):
    """One markdown table row."""
    return (f"| {result['transport']} | {result['rate_hz']:g} | "
            f"{result['messages_per_s']:g} | {result['duration_s']:.0f} | "
            f"{result['emitted']} | {result['lost']} | {result['late']} | "
            f"{result['first_sample'] + result['unmatched_at_start']} | "
            f"{result['published_rate']:.0f} | "
            f"{result['emitted_rate']:.0f} | {'yes' if result['kept_up'] else 'no'} | "
            f"{result['cpu']['sim']:.0f} | {result['cpu']['id']:.0f} | "
            f"{result['rss']['sim']:.0f} | {result['rss']['id']:.0f} | "
            f"{'yes' if result['sustained'] else 'no'} |")


HEADER = ('| transport | sample rate [Hz] | messages/s | duration [s] | samples emitted | lost | '
          'late | before connect | published/s | emitted/s | identifier kept up | '
          'sim CPU [%] | identifier CPU [%] | sim RSS [MiB] | identifier RSS [MiB] | '
          'sustained |\n'
          '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|')


def main(argv=None):
    """Run the cases and write the markdown report."""
    parser = argparse.ArgumentParser(description='sim_motor -> identifier throughput')
    parser.add_argument('--quick', action='store_true', help='short cases (smoke test)')
    parser.add_argument('--soak-s', type=float, default=600.0, help='soak duration [s]')
    parser.add_argument('--out', default=os.path.join(ROOT, 'bench', 'throughput_results.md'))
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    scale = 0.2 if args.quick else 1.0
    load_before = os.getloadavg()
    rclpy.init()
    node = rclpy.create_node('bench_throughput')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    streams = Streams(node)
    results = []
    try:
        with tempfile.TemporaryDirectory() as record_dir:
            cases = [(1000, 'float64', 60.0)]
            cases += [(rate, 'float64', 20.0) for rate in (2000, 3000, 4000, 5000)]
            cases += [(10000, 'batch', 60.0), (20000, 'batch', 30.0), (50000, 'batch', 30.0)]
            for rate, transport, duration in cases:
                result = run_case(executor, streams, rate, transport, duration * scale,
                                  record_dir)
                print(row(result), flush=True)
                results.append(result)
            soak = run_case(executor, streams, 1000, 'float64', args.soak_s * scale,
                            record_dir, soak_every_s=30.0 * scale)
            print(row(soak), flush=True)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    sustained = [r['messages_per_s'] for r in results
                 if r['transport'] == 'float64' and r['sustained']]
    kept_up = [r['messages_per_s'] for r in results
               if r['transport'] == 'float64' and r['kept_up']]
    trace = soak['rss_trace']
    lines = [
        '# Throughput and footprint: sim_motor -> identifier (separate processes, Fast DDS)',
        '',
        f'Generated by `bench/bench_throughput.py{" --quick" if args.quick else ""}` on '
        f'{datetime.date.today()} ({platform.machine()}, {os.cpu_count()} cores, Python '
        f'{platform.python_version()}, rclpy Jazzy wheels). Load average before the run: '
        f'{load_before[0]:.1f} (other work on the machine takes CPU from both nodes).',
        '',
        "Counters are the identifier's own (`/diagnostics`, status `identifier: streams`). "
        '"before connect" = samples published before all topics of the identifier were '
        'connected (discovery takes seconds across processes; not losses). "published/s": '
        'what sim_motor managed in real time (its `sim_motor: drive` status). "identifier '
        'kept up": no sample lost or late and every published sample emitted. "sustained": '
        'kept up, and both nodes ran at 98 % of the sample rate or more. CPU: 100 % = one '
        'core.',
        '',
        HEADER,
    ]
    lines += [row(result) for result in results + [soak]]
    lines += [
        '',
        f'Highest sustained Float64 message rate: '
        f'{max(sustained) if sustained else "none"} messages/s (three per sample); highest '
        f'Float64 rate the identifier took without loss: '
        f'{max(kept_up) if kept_up else "none"} messages/s.',
        '',
        f'Soak ({soak["duration_s"]:.0f} s at 1 kHz, Float64): identifier RSS [MiB] every '
        f'{30 * scale:g} s: ' + ', '.join(f'{rss:.0f}' for _, rss in trace)
        + (f'; growth first to last {trace[-1][1] - trace[0][1]:+.1f} MiB.' if trace else '.'),
    ]
    text = '\n'.join(lines) + '\n'
    with open(args.out, 'w') as stream:
        stream.write(text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
