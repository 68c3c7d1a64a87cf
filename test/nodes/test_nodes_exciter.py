"""
The installed ``exciter`` against ``sim_motor`` in a real graph: limits, stale data, signals.

In-process (issue 21): one stale or non-finite channel, malformed batches, ~/stop while
~/start is busy, plan files that are not regular files; as a process: a burst of ~/stop calls.
"""

import os
import signal
import subprocess
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger
from support import remove_nodes, wait_for
import test_nodes_process as process

from dcmotor_id.design import routines
from dcmotor_id.formats.batch import batch_message, decode_batch_message
from dcmotor_id.nodes.common import spin_until
from dcmotor_id.nodes.exciter import Exciter
from dcmotor_id.nodes.sim_motor import RCLPY_BATCH

pytestmark = pytest.mark.ros

# the colcon-installed package and a client node, as in test_nodes_process
installed = process.installed
client = process.client


class Graph:
    """sim_motor following voltage_command, an exciter, and what the test node sees."""

    def __init__(self, installed, ros_env, client, tmp_path, *exciter_arguments):
        self.node, self.executor = client
        self.args = (installed, ros_env, tmp_path)
        self.processes = {}
        self.commands, self.states, self.voltage = [], [], []
        self.subscriptions = [
            self.node.create_subscription(Float64, '/voltage_command',
                                          lambda m: self.commands.append(m.data), 100),
            self.node.create_subscription(DiagnosticArray, '/diagnostics', self._diagnostics,
                                          50),
            self.node.create_subscription(Float64MultiArray, '/samples', self._samples, 50)]
        self.start_sim()
        self.start_exciter(*exciter_arguments)

    def _diagnostics(self, message):
        for status in message.status:
            if status.name.endswith('excitation'):
                self.states.append({kv.key: kv.value for kv in status.values})

    def _samples(self, message):
        self.voltage.append(decode_batch_message(message)[1])

    def start_sim(self):
        installed, ros_env, log_dir = self.args
        self.processes['sim_motor'] = process.start(
            installed, 'sim_motor', ros_env, log_dir, '-p', 'transport:=batch', '-p',
            'use_voltage_command:=true')

    def start_exciter(self, *arguments):
        installed, ros_env, log_dir = self.args
        self.processes['exciter'] = process.start(
            installed, 'exciter', ros_env, log_dir, '-p', 'input:=batch', '-p',
            'ramp_in_s:=0.5', '-p', 'stale_timeout_s:=0.5', *arguments)
        self.trigger = self.node.create_client(Trigger, '/exciter/start')
        # the exciter imports what its routines need before its services exist (a minute on
        # a loaded machine)
        assert self.trigger.wait_for_service(timeout_sec=180.0), self.log('exciter')

    def log(self, name):
        return (self.args[2] / f'{name}.log').read_text()

    def call(self, service='/exciter/start'):
        trigger = self.trigger if service == '/exciter/start' else \
            self.node.create_client(Trigger, service)
        assert trigger.wait_for_service(timeout_sec=10.0)
        # A response can be lost while the server's response writer has not yet matched this
        # client (rmw_fastrtps logs "failed to send response (timeout)"): ask again, as a
        # user would; Trigger calls of the exciter are safe to repeat.
        for _ in range(3):
            future = trigger.call_async(Trigger.Request())
            if spin_until(self.executor, future.done, 8.0):
                return future.result()
            trigger.remove_pending_request(future)
        raise AssertionError(f'{service} did not answer three calls: {self.log("exciter")}')

    def start_routine(self):
        """Start once measurements flow; wait until the drive follows a non-zero command."""
        # the first sim_motor of a fresh install compiles its kernels: slow on a busy machine
        assert spin_until(self.executor, lambda: self.voltage, 180.0), self.log('sim_motor')
        deadline = time.monotonic() + 30.0
        while True:
            response = self.call()
            if response.message.startswith('a routine is running'):
                break  # an earlier request started it and its answer was lost
            if response.success or time.monotonic() > deadline:
                break
            spin_until(self.executor, lambda: False, 0.5)
        assert response.success or response.message.startswith('a routine is running'), \
            response.message
        assert spin_until(self.executor, lambda: self.voltage and
                          np.any(self.voltage[-1] != 0.0), 20.0), self.log('exciter')

    def state(self):
        return self.states[-1]['state'] if self.states else ''

    def wait_state(self, state, timeout_s=20.0):
        assert spin_until(self.executor, lambda: self.state() == state, timeout_s), \
            (self.states[-3:], self.log('exciter'))

    def drive_settles_at_zero(self):
        """Check that the last command is 0 V and that the drive applies 0 V afterwards."""
        spin_until(self.executor, lambda: False, 0.5)
        assert self.commands and self.commands[-1] == 0.0
        # The drive applies it within 10 s (a loaded machine delays the simulated drive's
        # batches and this process's backlog of them), and holds it for 3 batches more.
        assert spin_until(self.executor, lambda: bool(self.voltage) and
                          np.all(self.voltage[-1] == 0.0), 10.0), \
            self.voltage[-3:]
        seen = len(self.voltage)
        assert spin_until(self.executor, lambda: len(self.voltage) > seen + 3, 10.0)
        assert all(np.all(batch == 0.0) for batch in self.voltage[seen:])

    def close(self):
        for subscription in self.subscriptions:
            self.node.destroy_subscription(subscription)
        for item in self.processes.values():
            process.stop(item)


@pytest.fixture
def graph(installed, ros_env, client, tmp_path, request):
    made = []

    def make(*arguments):
        made.append(Graph(installed, ros_env, client, tmp_path, *arguments))
        return made[-1]
    yield make
    for item in made:
        item.close()


def test_colcon_installs_the_exciter(installed):
    assert (installed / 'lib' / 'dcmotor_id' / 'exciter').is_file()
    assert (installed / 'share' / 'dcmotor_id' / 'config' / 'exciter.yaml').is_file()


def test_current_limit_stops_at_zero_volt_and_done_ends_at_zero(graph):
    run = graph('-p', 'routine:=dynamic', '-p', 'amplitude_v:=20.0', '-p',
                'current_limit_a:=3.0')
    run.start_routine()
    run.wait_state('stopped-by-limit')
    assert 'current' in run.states[-1]['reason']
    run.drive_settles_at_zero()
    # a short routine within the limits (parameters read at ~/start) runs to its end
    setter = run.node.create_client(SetParameters, '/exciter/set_parameters')
    assert setter.wait_for_service(timeout_sec=10.0)
    future = setter.call_async(SetParameters.Request(parameters=[
        Parameter('amplitude_v', value=2.0).to_parameter_msg(),
        Parameter('duration_s', value=1.5).to_parameter_msg()]))
    assert spin_until(run.executor, future.done, 10.0)
    assert all(result.successful for result in future.result().results)
    run.start_routine()
    run.wait_state('done')
    run.drive_settles_at_zero()


def test_stale_measurements_stop_the_excitation(graph):
    run = graph('-p', 'routine:=prbs', '-p', 'amplitude_v:=5.0', '-p', 'duration_s:=60.0')
    run.start_routine()
    response = run.call('/exciter/stop')
    assert response.success and 'state stopped' in response.message
    run.wait_state('stopped')
    run.drive_settles_at_zero()
    run.start_routine()
    run.processes['sim_motor'].send_signal(signal.SIGSTOP)  # the drive hangs
    try:
        run.wait_state('stale')
        assert 'no measurement' in run.states[-1]['reason']
        spin_until(run.executor, lambda: False, 0.3)
        assert run.commands[-1] == 0.0
    finally:
        run.processes['sim_motor'].send_signal(signal.SIGCONT)
    run.drive_settles_at_zero()


@pytest.mark.parametrize('number', [signal.SIGTERM, signal.SIGINT])
def test_a_signal_commands_zero_before_the_exciter_exits(graph, number):
    run = graph('-p', 'routine:=multisine', '-p', 'amplitude_v:=8.0', '-p',
                'duration_s:=60.0')
    run.start_routine()
    exciter = run.processes['exciter']
    exciter.send_signal(number)
    assert exciter.wait(timeout=20) == 0
    run.drive_settles_at_zero()
    assert 'stopped' in [state['state'] for state in run.states[-3:]] or \
        run.commands[-1] == 0.0


# ------------------------------------------------------------------ in-process (issue 21)
class Bench:
    """An Exciter in a multi-threaded executor (as ``main`` runs it), a feeder and a caller."""

    def __init__(self, **parameters):
        # stale_timeout_s: longer than the feeder (a timer of this process) can be kept from
        # publishing on a loaded machine, which the exciter rightly calls stale
        values = {'input': 'float64', 'stale_timeout_s': 2.0, 'ramp_in_s': 0.0,
                  'routine': 'dynamic', 'amplitude_v': 12.0, 'duration_s': 60.0,
                  'rate_hz': 200.0}
        values.update(parameters)
        self.exciter = Exciter(parameter_overrides=[Parameter(key, value=value)
                                                    for key, value in values.items()])
        # (time, value) of every command the exciter published, at the time it decided on
        # it (its latest now_s(): ticks, starts and stops run under its lock), so that a
        # thread preempted between deciding and publishing does not blur the count
        self.sent = []
        publish, now_s = self.exciter.publish_command, self.exciter.now_s
        decided = [now_s()]

        def now():
            decided[0] = now_s()
            return decided[0]

        def record(value):
            self.sent.append((decided[0], value))
            publish(value)
        self.exciter.now_s = now
        self.exciter.publish_command = record
        self.feeder = rclpy.create_node('feeder')
        self.feeding = {'current': 0.5, 'speed': 1.0}  # channel -> value; absent: silent
        self.publishers = {name: self.feeder.create_publisher(Float64, name, 100)
                           for name in ('current', 'speed')}
        self.batches = self.feeder.create_publisher(Float64MultiArray, 'samples', 100)
        self.statuses = []
        self.feeder.create_subscription(DiagnosticArray, '/diagnostics', lambda array:
                                        self.statuses.extend(array.status), 100)
        self.feeder.create_timer(0.005, self._feed)
        self.executor = MultiThreadedExecutor(num_threads=4)
        for node in (self.exciter, self.feeder):
            self.executor.add_node(node)
        self.running = True
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        topics = ('samples',) if values['input'] == 'batch' else ('current', 'speed')
        assert wait_for(lambda: all(self.feeder.count_subscribers(f'/{name}') for name in
                                    topics), 30.0)

    def _spin(self):
        while self.running:
            self.executor.spin_once(timeout_sec=0.05)

    def _feed(self):
        for name, value in list(self.feeding.items()):
            self.publishers[name].publish(Float64(data=value))

    def client(self, service, depth=1000):
        """Return a client whose response reader keeps every answer of a burst (README)."""
        client = self.feeder.create_client(Trigger, service, qos_profile=QoSProfile(depth=depth))
        assert client.wait_for_service(timeout_sec=20.0)
        return client

    def start(self):
        """Start the routine (retried until measurements are fresh); wait for 12 V."""
        deadline = time.monotonic() + 30.0
        while True:
            response = self.exciter._on_start(Trigger.Request(), Trigger.Response())
            if response.success or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert response.success, response.message
        assert wait_for(lambda: self.sent and self.sent[-1][1] != 0.0, 10.0)

    def close(self):
        self.running = False
        self.thread.join(timeout=10)
        remove_nodes(self.executor, self.exciter, self.feeder)
        self.executor.shutdown()


@pytest.fixture
def bench(client):  # client: rclpy is initialised
    made = []

    def make(**parameters):
        made.append(Bench(**parameters))
        return made[-1]
    yield make
    for item in made:
        item.close()


def test_one_stale_channel_stops_at_zero_volt_within_one_tick(bench):
    """Issue 21: speed stopped while current kept arriving; 440 non-zero commands in 2.5 s."""
    run = bench()
    run.start()
    # driving for a while (100 commands at 200 Hz: a loaded machine takes longer)
    assert wait_for(lambda: sum(value != 0.0 for _, value in run.sent) > 100, 30.0)
    del run.feeding['speed']  # only the speed stream stops; current keeps coming
    stopped = time.monotonic()
    assert wait_for(lambda: run.exciter.session.state == 'stale', 30.0)
    stale = time.monotonic()
    session = run.exciter.session
    # current still arrives all this time
    assert wait_for(lambda: session.last_seen['current'] > stale + 1.0, 30.0)
    last_speed = session.last_seen['speed']
    timeout = session.stale_timeout_s
    late = [(t, value) for t, value in run.sent if value != 0.0 and t > last_speed + timeout]
    assert late == [], f'{len(late)} non-zero commands after the speed went stale'
    # within one tick of the timeout: the first command past it is the 0 V
    first = next(value for t, value in run.sent if t > last_speed + timeout)
    assert first == 0.0
    # counted on the test's own clock too (0.25 s for samples in flight at the stop)
    assert sum(value != 0.0 for t, value in run.sent if t > stopped + timeout + 0.25) == 0
    assert sum(value != 0.0 for t, value in run.sent if t < stopped) > 50  # it was driving
    assert 'no measurement on speed' in session.reason and 'current' not in session.reason
    assert wait_for(lambda: any('stale: no measurement on speed' in status.message
                                for status in run.statuses), 5.0)


def test_a_slow_start_blocks_neither_stop_nor_the_start_of_the_routine(bench, monkeypatch):
    """
    A start whose commands take seconds to compute answers ~/stop and starts at the end.

    The first PRBS of a process imports scipy.signal (17 s under load): ~/stop is answered
    meanwhile, and the routine starts at its beginning once its commands are ready, judged on
    measurements fresh then (it started in the past: stale or done at once, ramp-in skipped).
    """
    run = bench(ramp_in_s=0.5, stale_timeout_s=5.0)
    computing, release = threading.Event(), threading.Event()
    compute = routines.command_profile

    def slow(*arguments):
        computing.set()
        release.wait(60.0)
        return compute(*arguments)
    monkeypatch.setattr(routines, 'command_profile', slow)
    assert wait_for(lambda: run.exciter.session.fresh(run.exciter.now_s()), 30.0)
    answers = {}
    starter = threading.Thread(target=lambda: answers.update(start=run.exciter._on_start(
        Trigger.Request(), Trigger.Response())), daemon=True)
    stopper = threading.Thread(target=lambda: answers.update(stop=run.exciter._on_stop(
        Trigger.Request(), Trigger.Response())), daemon=True)
    try:
        starter.start()
        assert computing.wait(30.0)
        stopper.start()
        stopped = wait_for(lambda: 'stop' in answers, 20.0)
        ready_s = run.exciter.now_s()
    finally:
        release.set()
    starter.join(timeout=30.0)
    assert stopped and answers['stop'].success, 'the stop waited for the start to compute'
    assert answers['start'].success, answers['start'].message
    assert run.exciter.session.started_s >= ready_s


def test_the_first_start_of_a_fresh_exciter_imports_nothing(ros_env):
    """What computing a routine imports (scipy.signal: 38 s under load) is paid before ready."""
    check = ('import sys\nimport rclpy\nfrom std_srvs.srv import Trigger\n'
             'from dcmotor_id.nodes.exciter import Exciter\nrclpy.init()\n'
             'node = Exciter()\nloaded = set(sys.modules)\n'
             'node.session.observe(node.now_s(), current=[0.0], speed=[0.0])\n'
             'assert node._on_start(Trigger.Request(), Trigger.Response()).success\n'
             'print(sorted(set(sys.modules) - loaded))\nnode.destroy_node()\n'
             'rclpy.try_shutdown()\n')
    env = dict(ros_env, PYTHONPATH=os.pathsep.join(sys.path))
    run = subprocess.run([sys.executable, '-c', check], capture_output=True, text=True,
                         env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == '[]', run.stdout[-600:]


@pytest.mark.parametrize('bad', [float('nan'), float('inf')])
def test_a_non_finite_channel_stops_at_once_and_start_is_refused_naming_it(bench, bad):
    run = bench()
    run.start()
    run.feeding['current'] = bad
    assert wait_for(lambda: run.exciter.session.state == 'stopped-by-limit', 10.0)
    assert 'current is not finite' in run.exciter.session.reason
    time.sleep(0.3)
    after = next(t for t, value in run.sent if value == 0.0)
    assert all(value == 0.0 for t, value in run.sent if t >= after)
    response = run.exciter._on_start(Trigger.Request(), Trigger.Response())
    assert not response.success and 'current is not finite' in response.message
    run.feeding['current'] = 0.5  # finite again: a start works
    assert wait_for(lambda: run.exciter._on_start(Trigger.Request(),
                                                  Trigger.Response()).success, 10.0)


def test_malformed_batches_are_refused_and_the_routine_stops_stale(bench):
    run = bench(input='batch')
    run.feeding.clear()
    good = batch_message(RCLPY_BATCH, np.arange(5) * 1e-3, np.zeros(5), np.zeros(5),
                         np.zeros(5))
    wrong_size = batch_message(RCLPY_BATCH, np.arange(5) * 1e-3, np.zeros(5), np.zeros(5),
                               np.zeros(5))
    wrong_size.layout.dim[1].size = 12
    feeding = {'message': good}
    run.feeder.create_timer(0.005, lambda: run.batches.publish(feeding['message']))
    run.start()
    feeding['message'] = wrong_size  # the node survives, refuses them, goes stale at 0 V
    assert wait_for(lambda: run.exciter.session.state == 'stale', 10.0)
    assert 'no measurement on current' in run.exciter.session.reason
    time.sleep(0.3)
    assert run.sent[-1][1] == 0.0 and run.thread.is_alive()


def test_stop_is_answered_while_a_start_is_still_busy(bench):
    """~/stop has a callback group of its own: it never waits behind ~/start."""
    run = bench()
    run.start()
    routine = run.exciter.routine

    def slow():
        time.sleep(4.0)
        return routine()
    run.exciter.routine = slow
    start = run.client('/exciter/start').call_async(Trigger.Request())
    time.sleep(0.5)
    began = time.monotonic()
    stop = run.client('/exciter/stop').call_async(Trigger.Request())
    assert wait_for(stop.done, 3.0), 'stop waited behind start'
    assert time.monotonic() - began < 3.0 and not start.done()
    assert stop.result().success and 'was running' in stop.result().message
    assert run.sent[-1][1] == 0.0
    assert wait_for(start.done, 20.0)  # start is answered too (routine stopped: it may start)


@pytest.mark.parametrize('kind', ['fifo', 'zero', 'loop', 'directory'])
def test_plan_file_that_is_not_a_regular_file_is_refused_by_name(bench, tmp_path, kind):
    """Issue 21: a FIFO or /dev/zero as plan_file blocked the exciter forever."""
    path = {'fifo': tmp_path / 'plan.fifo', 'zero': '/dev/zero',
            'loop': tmp_path / 'loop.json', 'directory': tmp_path}[kind]
    if kind == 'fifo':
        os.mkfifo(path)
    elif kind == 'loop':
        os.symlink(tmp_path / 'loop.json', path)
    run = bench(plan_file=str(path))
    answers = []
    thread = threading.Thread(target=lambda: answers.append(run.exciter._on_start(
        Trigger.Request(), Trigger.Response())), daemon=True)
    thread.start()
    thread.join(timeout=10.0)
    assert answers, f'~/start blocked on a {kind} plan_file'
    message = answers[0].message
    assert not answers[0].success and 'plan_file' in message and str(path) in message
    assert {'fifo': 'is a FIFO', 'zero': 'is a device', 'loop': 'symlink loop',
            'directory': 'is a directory'}[kind] in message, message
    assert run.exciter.session.state == 'idle' and all(v == 0.0 for _, v in run.sent)


def test_forty_concurrent_stops_are_all_answered(ros_env, client, tmp_path):
    """Issue 21: ~/stop answered 11 of 40 (the service queue kept the last 10 requests)."""
    node, executor = client
    exciter = subprocess.Popen(
        [sys.executable, '-m', 'dcmotor_id.nodes.exciter', '--ros-args', '-p',
         'input:=float64'], env=dict(ros_env, PYTHONUNBUFFERED='1'),
        stdout=open(tmp_path / 'exciter.log', 'w'), stderr=subprocess.STDOUT)
    clients = []
    try:
        # each client's response reader keeps 1000: with the default 10, forty clients in
        # one process lose answers among themselves (each reader sees every response)
        clients = [node.create_client(Trigger, '/exciter/stop',
                                      qos_profile=QoSProfile(depth=1000)) for _ in range(40)]
        assert all(item.wait_for_service(timeout_sec=60.0) for item in clients), \
            (tmp_path / 'exciter.log').read_text()
        spin_until(executor, lambda: False, 1.0)  # let the response writers match
        futures = [item.call_async(Trigger.Request()) for item in clients]
        spin_until(executor, lambda: all(future.done() for future in futures), 60.0)
        answered = [future.result() for future in futures if future.done()]
        assert len(answered) == 40, (len(answered), (tmp_path / 'exciter.log').read_text())
        assert all(response.success and '0 V commanded' in response.message
                   for response in answered)
    finally:
        for item in clients:
            node.destroy_client(item)
        process.stop(exciter)


@pytest.mark.parametrize('options, code', [
    (['--duration', '2', '--rate', '100', '--kinds', 'prbs'], 0),
    (['--prior', 'no_such_prior.json'], 2),
    (['--duration', '-1'], 2),
])
def test_exciter_plan_is_the_plan_command(tmp_path, options, code):
    """``exciter --plan`` prints what ``dcmotor-id plan`` prints, without the command line."""
    check = ('import sys\nfrom dcmotor_id.nodes.exciter import main\ncode = main(sys.argv[1:])\n'
             'assert "dcmotor_id.cli.main" not in sys.modules\nsys.exit(code)\n')
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    runs = [subprocess.run(command, capture_output=True, text=True, env=env, cwd=tmp_path,
                           timeout=300)
            for command in ([sys.executable, '-c', check, '--plan', *options],
                            [sys.executable, '-m', 'dcmotor_id.cli', 'plan', *options])]
    assert [run.returncode for run in runs] == [code, code], runs[0].stderr
    assert runs[0].stdout == runs[1].stdout and runs[0].stderr == runs[1].stderr
    assert ('plan: prbs' in runs[0].stdout) if code == 0 else \
        runs[0].stderr.rstrip().splitlines()[-1].startswith('dcmotor-id')
