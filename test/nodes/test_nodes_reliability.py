"""
The node's side of the bad-input matrix of issue 9: every answer names its reason.

In-process (one executor): a 5000-sample batch aligned whole, a fit over its time limit
stopped and the next call answered, malformed batches, NaN values, absurd times, a missing
topic and duplicates named in ``~/identify`` and ``/diagnostics``, window stamps after a
publisher restart. As processes: the fitting worker dies with a node killed by SIGKILL, and
SIGINT stops a node in the middle of a fit, leaving no process behind.
"""

import os
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger
from support import (alive, call as trigger, children, remove_nodes, spinning_executor,
                     wait_for)

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.batch import batch_message
from dcmotor_id.nodes.identifier import Identifier
from dcmotor_id.nodes.sim_motor import RCLPY_BATCH
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

pytestmark = pytest.mark.ros

BIN = os.path.dirname(sys.executable)


def simulated(duration_s, dt=1e-3, seed=0):
    """Return t, voltage, current, speed of motor 2 under the paper excitation, with noise."""
    t, voltage = make_excitation('paper', duration_s, dt)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, dt)
    rng = np.random.default_rng(seed)
    return (t, voltage, current + rng.normal(0, 0.01, t.size),
            speed + rng.normal(0, 0.05, t.size))


def batch(t, voltage, current, speed):
    """Build one batch message (the documented layout)."""
    return batch_message(RCLPY_BATCH, np.asarray(t, float), np.asarray(voltage, float),
                         np.asarray(current, float), np.asarray(speed, float))


@pytest.fixture(scope='module')
def ros(ros_env):
    with spinning_executor() as executor:
        yield executor


def call(node, service):
    return trigger(node, service, timeout_s=120.0, wait_s=20.0)


@pytest.fixture
def graph(ros, tmp_path):
    """Return a factory of identifier nodes plus a probe node; all removed afterwards."""
    made = []

    def make(namespace, **overrides):
        parameters = {'record': False, 'window_s': 2.0, 'min_window_s': 0.2,
                      'compare_paper': False, 'discover': False, 'online': False,
                      'record_dir': str(tmp_path / namespace)}
        parameters.update(overrides)
        ident = Identifier(namespace=namespace, parameter_overrides=[
            Parameter(name, value=value) for name, value in parameters.items()])
        probe = rclpy.create_node('probe', namespace=namespace)
        for node in (ident, probe):
            ros.add_node(node)
        made.extend([ident, probe])
        return ident, probe

    yield make
    remove_nodes(ros, *made)


def publish(probe, topic, messages, message_type=Float64MultiArray):
    publisher = probe.create_publisher(message_type, topic, 100)
    assert wait_for(lambda: publisher.get_subscription_count() > 0, 20.0)
    for message in messages:
        publisher.publish(message)
        time.sleep(0.02)
    return publisher


def test_a_5000_sample_batch_is_whole_and_a_fit_over_its_limit_is_stopped(graph):
    # 1000 structure-bootstrap resamples make the first fit last about a thousand fits (a
    # minute): far beyond its 0.3 s limit however fast the machine (one fit takes 0.05 s)
    ident, probe = graph('big', input='batch', identify_timeout_s=0.3, discover=True,
                         structure_bootstrap=1000)
    publish(probe, 'samples', [batch(*simulated(5.0))])
    assert wait_for(lambda: ident.aligner.stats.emitted == 5000, 30.0), ident.aligner.stats
    stats = ident.aligner.stats
    assert stats.lost == stats.late == 0
    assert wait_for(lambda: ident._fits.pid is not None, 30.0)
    worker = ident._fits.pid
    response = call(probe, 'identifier/identify')
    assert not response.success
    assert 'did not finish within identify_timeout_s = 0.3 s' in response.message
    assert 'call again' in response.message.lower()
    assert wait_for(lambda: not os.path.exists(f'/proc/{worker}'), 10.0)
    ident._fits.timeout_s = None  # a later call (with time enough) works
    assert ident.set_parameters([Parameter('structure_bootstrap', value=0)])[0].successful
    response = call(probe, 'identifier/identify')
    assert response.success, response.message
    assert response.message.startswith('refined: Ra=')
    assert 'input so far' not in response.message  # nothing was lost or refused


def test_answers_name_malformed_batches_invalid_values_and_absurd_times(graph):
    ident, probe = graph('why', input='batch')
    statuses = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda array: statuses.extend(
        status for status in array.status if status.hardware_id == '/why/identifier'
        and status.name == 'identifier: streams'), 50)
    t, voltage, current, speed = simulated(1.0)
    bad_label = batch(t, voltage, current, speed)
    bad_label.layout.dim[0].label = 'time,u,i,w'
    wrong_size = batch(t, voltage, current, speed)
    wrong_size.layout.dim[1].size = 12
    reversed_time = batch(t[::-1], voltage, current, speed)
    absurd = batch((t + 1.0) * 1e290, voltage, current, speed)
    nan_speed = batch(t + 10.0, voltage, current, np.full(t.size, np.nan))
    publish(probe, 'samples', [bad_label, wrong_size, reversed_time, absurd, nan_speed])
    assert wait_for(lambda: ident.aligner.stats.invalid == 1000, 20.0)
    response = call(probe, 'identifier/identify')
    assert not response.success
    for phrase in ('not enough data', '3 malformed batches refused',
                   'bad labels 1, times not increasing 1, wrong sizes 1',
                   'invalid values (NaN/inf) refused: speed 1000',
                   '1000 samples with NaN or absurd times dropped'):
        assert phrase in response.message, (phrase, response.message)
    assert wait_for(lambda: statuses and {kv.key: kv.value for kv in statuses[-1].values}.get(
        'malformed_batches') == '3', 10.0)
    values = {kv.key: kv.value for kv in statuses[-1].values}
    assert values['invalid.speed'] == '1000' and values['invalid_times'] == '1000'
    assert 'times do not increase' in values['malformed_reason']
    assert int(values['first_sample']) == 10000  # never -2^63
    assert int(values['lost']) <= 1000


def test_a_missing_topic_and_duplicates_are_named(graph):
    ident, probe = graph('miss')
    publishers = {name: probe.create_publisher(Float64, name, 2000)
                  for name in ('voltage', 'current')}
    assert wait_for(lambda: all(p.get_subscription_count() for p in publishers.values()), 20)
    for k in range(1500):
        for publisher in publishers.values():
            publisher.publish(Float64(data=float(k)))
        if k % 100 == 0:
            time.sleep(0.01)
    for sequence in range(1, 201):  # a storm of duplicated messages (same sequence number)
        for _ in range(5):
            ident.inbox.put_message('speed', 1.0, {'publication_sequence_number': 10 ** 6 +
                                                   sequence})
    assert wait_for(lambda: ident.aligner.stats.duplicates >= 800, 20.0)
    ident.inbox.last_seen.pop('speed', None)   # only the storm came on speed, through the API
    response = call(probe, 'identifier/identify')
    assert not response.success
    assert 'nothing received on speed' in response.message, response.message
    assert '800 duplicate values dropped' in response.message


def test_windows_after_a_publisher_restart_are_not_stamped_in_the_past(graph):
    ident, probe = graph('restart', input='batch', window_s=1.0)
    data = simulated(3.0)
    publish(probe, 'samples', [batch(*data)])
    assert wait_for(lambda: ident.aligner.stats.emitted == 3000, 20.0)
    time.sleep(0.5)
    publish(probe, 'samples', [batch(*data)])  # the publisher restarted: t from 0 again
    assert wait_for(lambda: ident.aligner.stats.emitted == 6000, 20.0)
    ident._close_window()
    windows = sorted(ident.cutter.windows, key=lambda window: window.number)
    assert ident.aligner.stats.restarts == 1 and ident.cutter.restarts == 1
    assert sum(window.size for window in windows) >= 3000
    for before, after in zip(windows, windows[1:]):
        assert after.stamps_ns[0] > before.stamps_ns[-1]


# ---------------------------------------------------------------- as processes
def start_identifier(ros_env, tmp_path, namespace, *parameters):
    environment = dict(ros_env, PYTHONUNBUFFERED='1')
    log = open(tmp_path / 'identifier.log', 'w')
    arguments = ['-r', f'__ns:=/{namespace}']
    for parameter in ('record:=false', 'online:=false', 'compare_paper:=false',
                      *parameters):
        arguments += ['-p', parameter]
    return subprocess.Popen([os.path.join(BIN, 'identifier'), '--ros-args', *arguments],
                            env=environment, stdout=log, stderr=subprocess.STDOUT)


def test_the_worker_dies_with_a_node_killed_by_sigkill(ros_env, tmp_path):
    node = start_identifier(ros_env, tmp_path, 'killed')
    try:
        assert wait_for(lambda: children(node.pid), 60.0), \
            (tmp_path / 'identifier.log').read_text()
        workers = children(node.pid)
        node.send_signal(signal.SIGKILL)
        node.wait(timeout=10)
        # PR_SET_PDEATHSIG: at once, not after the watchdog's next poll
        assert wait_for(lambda: not any(alive(pid) for pid in workers), 5.0)
    finally:
        if node.poll() is None:
            node.kill()
            node.wait()


def test_sigint_stops_a_node_in_the_middle_of_a_fit(ros, ros_env, tmp_path):
    node = start_identifier(ros_env, tmp_path, 'interrupted', 'input:=batch', 'window_s:=3.0',
                            'discover:=true')
    probe = rclpy.create_node('probe', namespace='interrupted')
    ros.add_node(probe)
    try:
        assert wait_for(lambda: children(node.pid), 60.0), \
            (tmp_path / 'identifier.log').read_text()
        workers = children(node.pid)
        publish(probe, 'samples', [batch(*simulated(5.0))])
        client = probe.create_client(Trigger, 'identifier/identify')
        assert client.wait_for_service(timeout_sec=20.0)
        time.sleep(1.0)
        client.call_async(Trigger.Request())
        time.sleep(2.0)  # the fit runs in the worker now
        node.send_signal(signal.SIGINT)
        node.wait(timeout=30)
        assert wait_for(lambda: not any(alive(pid) for pid in workers), 10.0)
        assert 'Traceback' not in (tmp_path / 'identifier.log').read_text()
    finally:
        ros.remove_node(probe)
        probe.destroy_node()
        if node.poll() is None:
            node.kill()
            node.wait()


# ---------------------------------------------------------------- issue 21
def test_twenty_concurrent_identify_calls_are_all_answered(graph):
    """Issue 21: 9 of 20 concurrent calls were never answered (a queue of 10 requests)."""
    ident, probe = graph('storm', input='batch')
    publish(probe, 'samples', [batch(*simulated(3.0))])
    assert wait_for(lambda: ident.aligner.stats.emitted == 3000, 30.0)
    # deep response readers: with the default 10, twenty clients of one process lose
    # answers among themselves (every reader sees every response)
    clients = [probe.create_client(Trigger, 'identifier/identify',
                                   qos_profile=QoSProfile(depth=1000)) for _ in range(20)]
    assert all(client.wait_for_service(timeout_sec=30.0) for client in clients)
    time.sleep(1.0)  # let the response writer match every client
    futures = [client.call_async(Trigger.Request()) for client in clients]
    assert wait_for(lambda: all(future.done() for future in futures), 240.0), \
        f'{sum(future.done() for future in futures)} of 20 answered'
    answers = [future.result() for future in futures]
    busy = [answer for answer in answers if answer.message.startswith('busy: ')]
    assert busy and all(not answer.success for answer in busy)
    done = [answer for answer in answers if answer not in busy]  # a result or why not
    assert done and all(answer.success or answer.message.startswith('identification failed')
                        for answer in done), [answer.message for answer in done]


def test_a_fit_that_fails_unexpectedly_is_answered_and_the_node_lives_on(graph):
    ident, probe = graph('broken', input='batch')
    publish(probe, 'samples', [batch(*simulated(3.0))])
    assert wait_for(lambda: ident.aligner.stats.emitted == 3000, 30.0)
    fits = ident._fits.identify
    ident._fits.identify = lambda *arguments: {'parameters': {}}  # a malformed result
    response = call(probe, 'identifier/identify')
    assert not response.success
    assert response.message.startswith('identification failed unexpectedly: KeyError')
    ident._fits.identify = fits
    response = call(probe, 'identifier/identify')  # the node lives on and answers
    assert response.success, response.message


def test_bad_joint_states_are_said_and_the_node_lives_on(graph):
    """NaN, inf and wrong sizes on joint_states: refused, counted and named."""
    from sensor_msgs.msg import JointState

    ident, probe = graph('joints', input='joint_state', torque_constant=0.5,
                         joint_name='axis')
    messages = []
    for k, (velocity, effort) in enumerate([([float('nan')], [1.0]), ([1.0], [float('inf')]),
                                            ([], [1.0]), ([1.0], [])]):
        message = JointState(name=['axis'], velocity=velocity, effort=effort)
        message.header.stamp.sec = 100 + k
        messages.append(message)
    publish(probe, 'joint_states', messages, JointState)
    assert wait_for(lambda: ident.input_node.errors == 0 and
                    ident.health.malformed_joint_states == 2, 20.0), \
        (ident.input_node.errors, getattr(ident.health, 'malformed_joint_states', None))
    response = call(probe, 'identifier/identify')
    assert not response.success
    for phrase in ('not enough data', '2 malformed joint_states refused',
                   'invalid values (NaN/inf) refused: current 1, speed 1'):
        assert phrase in response.message, (phrase, response.message)


def test_sim_motor_survives_an_absurd_command_and_says_so(ros):
    """A command of 1.7e308 V overflows the simulated state: reset to rest, said, and on."""
    from dcmotor_id.formats.batch import decode_batch_message
    from dcmotor_id.nodes.sim_motor import SimMotor

    sim = SimMotor(namespace='huge', parameter_overrides=[
        Parameter('use_voltage_command', value=True), Parameter('transport', value='batch')])
    probe = rclpy.create_node('probe', namespace='huge')
    received = []
    probe.create_subscription(Float64MultiArray, 'samples', lambda message: received.append(
        decode_batch_message(message)), 100)
    for node in (sim, probe):
        ros.add_node(node)
    try:
        command = probe.create_publisher(Float64, 'voltage_command', 10)
        assert wait_for(lambda: command.get_subscription_count() > 0, 20.0)
        command.publish(Float64(data=1.7e308))
        assert wait_for(lambda: sim.overflows > 0, 20.0)
        command.publish(Float64(data=0.0))
        assert wait_for(lambda: sim._command == 0.0, 10.0)
        seen = len(received)
        assert wait_for(lambda: len(received) > seen + 5, 20.0)
        assert np.all(np.isfinite(received[-1][1:]))  # the motor is simulated again
    finally:
        remove_nodes(ros, sim, probe)


# ---------------------------------------------------------------- round 4 (issue 30)
@pytest.mark.parametrize('name, value', [
    ('method', 'bogus'), ('input', 'telepathy'), ('window_s', 1e12), ('min_window_s', 1e9),
    ('record_dir', '/proc/forbidden'), ('effort_scale', float('inf'))])
def test_identifier_refuses_a_start_up_parameter_changed_at_run_time(graph, name, value):
    """Issue 30, item 12: these were answered successful=True and then ignored."""
    ident, _ = graph(f'runtime_{name}')
    before = ident.get_parameter(name).value
    outcome, = ident.set_parameters([Parameter(name, value=value)])
    assert not outcome.successful
    assert name in outcome.reason and 'restart the node' in outcome.reason
    assert ident.get_parameter(name).value == before
    assert ident.set_parameters([Parameter('structure_bootstrap', value=5)])[0].successful
    assert ident.structure_bootstrap == 5


@pytest.mark.parametrize('overrides, phrase', [
    ({'min_window_s': 3.0, 'window_s': 2.0}, 'min_window_s = 3 s is longer than window_s'),
    ({'record': True, 'record_dir': '/proc/forbidden'},
     "record_dir = '/proc/forbidden': cannot write there"),
    ({'effort_scale': float('inf')}, 'effort_scale = inf'),
    ({'window_s': 1e12}, 'window_s = 1e+12 s is 1e+15 samples'),
])
def test_identifier_refuses_settings_that_cannot_work_at_start_up(ros, overrides, phrase):
    with pytest.raises(ValueError) as caught:
        Identifier(namespace='refused', parameter_overrides=[
            Parameter(name, value=value) for name, value in overrides.items()])
    assert phrase in str(caught.value)


def test_sim_motor_refuses_a_motor_changed_at_run_time(ros):
    from dcmotor_id.nodes.sim_motor import SimMotor

    sim = SimMotor(namespace='runtime_sim')
    try:
        outcome, = sim.set_parameters([Parameter('J', value=0.0)])
        assert not outcome.successful and 'restart the node' in outcome.reason
        assert sim.params.J == PAPER_MOTORS['paper2'].J
    finally:
        sim.destroy_node()


def test_exciter_checks_a_routine_changed_at_run_time_by_the_start_up_rules(ros):
    from dcmotor_id.nodes.exciter import Exciter

    exciter = Exciter(namespace='runtime_exciter')
    try:
        outcome, = exciter.set_parameters([Parameter('routine', value='bogus')])
        assert not outcome.successful and 'choose one of' in outcome.reason
        outcome, = exciter.set_parameters([Parameter('rate_hz', value=50.0)])
        assert not outcome.successful and 'restart the node' in outcome.reason
        assert exciter.set_parameters([Parameter('amplitude_v', value=2.0)])[0].successful
    finally:
        exciter.destroy_node()


@pytest.mark.parametrize('node, parameter, phrase', [
    ('exciter', 'rate_hz:=1e9', 'parameter rate_hz = 1000000000.0 is out of range'),
    ('replay', 'rate:=0.0', 'parameter rate = 0.0 is out of range'),
    ('replay', 'rate:=-1.0', 'parameter rate = -1.0 is out of range'),
])
def test_an_out_of_range_start_up_value_is_one_line_and_exit_2(ros_env, tmp_path, node,
                                                               parameter, phrase):
    """Issue 30, item 17: a traceback of InvalidParameterValueException."""
    result = subprocess.run(
        [sys.executable, '-m', f'dcmotor_id.nodes.{node}', '--ros-args', '-p', parameter,
         '-p', f'bag:={tmp_path}'], env=ros_env, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stderr
    assert 'Traceback' not in result.stderr and phrase in result.stderr, result.stderr


def test_replay_shortens_absurd_gaps_and_says_so():
    """Issue 30, item 5: a 31-year gap between two messages was slept out."""
    from dcmotor_id.nodes.replay import schedule

    year_ns = 365 * 86400 * 10 ** 9
    stamps = [0, 10 ** 6, 31 * year_ns, 31 * year_ns + 10 ** 6]
    due, shortened = schedule(stamps, rate=1.0, max_gap_s=10.0)
    assert due == pytest.approx([0.0, 1e-3, 10.001, 10.002])
    assert [index for index, _ in shortened] == [2]
    assert shortened[0][1] == pytest.approx(31 * 365 * 86400, rel=1e-6)
    due, shortened = schedule(stamps[:2], rate=0.5, max_gap_s=10.0)
    assert due == pytest.approx([0.0, 2e-3]) and not shortened
