"""Both nodes in one executor over real DDS: identify, latched results, bags, bad input."""

import json
import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from support import call, remove_nodes, spinning_executor, wait_for

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.bag import read_bag
from dcmotor_id.nodes.identifier import Identifier, LATCHED, RESULT_KEYS
from dcmotor_id.nodes.sim_motor import SimMotor

pytestmark = pytest.mark.ros

TRUTH = PAPER_MOTORS['paper2'].as_dict()
EXPECTED_KEYS = list(RESULT_KEYS) + [f'{key}_stderr' for key in RESULT_KEYS]


@pytest.fixture(scope='module')
def ros(ros_env):
    with spinning_executor() as executor:
        yield executor


def add(executor, node):
    executor.add_node(node)
    return node


def identifier(executor, namespace, tmp_path, **overrides):
    parameters = {'record_dir': str(tmp_path / namespace), 'window_s': 6.0}
    parameters.update(overrides)
    return add(executor, Identifier(namespace=namespace, parameter_overrides=[
        Parameter(name, value=value) for name, value in parameters.items()]))


@pytest.fixture(scope='module')
def identified(ros, tmp_path_factory):
    """Run sim_motor -> identifier for 7 s at 1 kHz (Float64 topics) and call ~/identify."""
    tmp_path = tmp_path_factory.mktemp('inprocess')
    sim = add(ros, SimMotor(namespace='run'))
    ident = identifier(ros, 'run', tmp_path)
    probe = add(ros, rclpy.create_node('probe', namespace='run'))
    diagnostics, online = [], []
    probe.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 50)
    probe.create_subscription(DiagnosticStatus, 'identifier/online_parameters', online.append,
                              10)
    assert wait_for(lambda: ident.aligner.stats.emitted >= 7000, 30.0)
    stats = ident.aligner.stats.as_dict()
    first = call(probe, 'identifier/identify')
    second_client = probe.create_client(Trigger, 'identifier/identify')
    results = [second_client.call_async(Trigger.Request()) for _ in range(2)]
    assert wait_for(lambda: all(f.done() for f in results), 60.0)
    latched = []
    late = add(ros, rclpy.create_node('late_subscriber', namespace='run'))
    late.create_subscription(DiagnosticStatus, 'identifier/parameters', latched.append,
                             LATCHED)
    assert wait_for(lambda: latched, 10.0)
    assert wait_for(lambda: online, 5.0)
    # the online estimator runs off the executor: under load its status may lag the samples
    wait_for(lambda: any(kv.key == 'converged' and kv.value == 'true'
                         for kv in online[-1].values), 30.0)
    # stop the drive: the other tests share this executor
    remove_nodes(ros, sim)
    ros.remove_node(ident)
    yield {'sim': sim, 'ident': ident, 'first': first, 'stats': stats,
           'concurrent': [f.result() for f in results], 'latched': latched[-1],
           'diagnostics': diagnostics, 'online': online, 'tmp_path': tmp_path}
    remove_nodes(ros, late, probe)
    ident.close()
    ident.destroy_node()


def test_identify_returns_the_truth_within_2_percent(identified):
    response = identified['first']
    assert response.success, response.message
    assert response.message.startswith('refined: Ra=')
    assert 'paper: Ra=' in response.message
    values = {kv.key: float(kv.value) for kv in identified['latched'].values}
    for key, true in TRUTH.items():
        assert values[key] == pytest.approx(true, rel=0.02), key
    ident = identified['ident']
    for key in RESULT_KEYS:
        assert ident.get_parameter(f'identified.{key}').value == values[key]
    stats = identified['stats']
    assert stats['lost'] == 0 and stats['late'] == 0


def test_results_are_latched_with_exactly_the_documented_keys(identified):
    keys = [kv.key for kv in identified['latched'].values]
    assert [key for key in keys if not key.startswith('effect.')] == EXPECTED_KEYS
    assert all(math.isfinite(float(kv.value)) for kv in identified['latched'].values)
    names = {status.name for array in identified['diagnostics'] for status in array.status}
    assert {'identifier: identified parameters', 'identifier: paper method',
            'identifier: streams'} <= names


def test_second_concurrent_identify_is_refused_and_the_node_lives_on(identified):
    responses = identified['concurrent']
    refused = [r for r in responses if not r.success]
    assert len(refused) == 1, [r.message for r in responses]
    assert 'already running' in refused[0].message
    assert any(r.success for r in responses)


def test_result_parameters_cannot_be_set_from_outside(identified):
    ident = identified['ident']
    before = ident.get_parameter('identified.Ra').value
    outcome, = ident.set_parameters([Parameter('identified.Ra', value=1.0)])
    assert not outcome.successful and 'result of ~/identify' in outcome.reason
    assert ident.get_parameter('identified.Ra').value == before
    assert ident.set_parameters([Parameter('structure_bootstrap', value=0)])[0].successful


def test_online_estimate_converges_near_the_truth(identified):
    status = identified['online'][-1]
    values = {kv.key: kv.value for kv in status.values}
    assert values['converged'] == 'true'
    assert float(values['innovation_rms_current_A']) > 0
    for key in ('Ra', 'CPhi', 'La'):
        assert float(values[key]) == pytest.approx(TRUTH[key], rel=0.05), key


def test_bag_recorded_by_the_node_gives_the_services_answer_in_the_cli(identified, tmp_path):
    ident = identified['ident']
    bags = list(ident.get_parameter('identified.bags').value)
    assert bags and all(bag.startswith(str(identified['tmp_path'])) for bag in bags)
    for bag in bags:
        assert len(read_bag(bag)) >= 500
    out = tmp_path / 'cli.json'
    discover = [] if ident.settings.discover else ['--no-discover']
    assert cli_main(['identify', *bags, '--json', str(out)] + discover) == 0
    from_cli = json.loads(out.read_text())
    from_node = {key: ident.get_parameter(f'identified.{key}').value for key in RESULT_KEYS}
    assert from_cli['parameters'] == pytest.approx(from_node, rel=1e-9)


def test_identify_before_any_data_fails_clearly(ros, tmp_path):
    ident = identifier(ros, 'empty', tmp_path)
    probe = add(ros, rclpy.create_node('probe_empty', namespace='empty'))
    response = call(probe, 'identifier/identify')
    assert not response.success
    assert 'not enough data' in response.message and 'voltage, current, speed' in response.message
    remove_nodes(ros, probe, ident)


def test_nan_payloads_and_a_stopped_topic_leave_the_node_alive(ros, tmp_path):
    # the stream timeout is longer than this thread may be kept from publishing on a loaded
    # machine: a pause of the feeder beyond it is a stop (its pending samples given up)
    ident = identifier(ros, 'bad', tmp_path, stream_timeout_s=2.0, window_s=2.0)
    feeder = add(ros, rclpy.create_node('feeder', namespace='bad'))
    streams = []
    feeder.create_subscription(DiagnosticArray, '/diagnostics', lambda array: streams.extend(
        status.message for status in array.status if status.hardware_id == '/bad/identifier'
        and status.name == 'identifier: streams'), 50)
    publishers = {name: feeder.create_publisher(Float64, name, 1000)
                  for name in ('voltage', 'current', 'speed')}
    assert wait_for(lambda: all(p.get_subscription_count() for p in publishers.values()), 10)
    rng = np.random.default_rng(0)
    for k in range(1500):
        for name, publisher in publishers.items():
            value = float('nan') if name == 'current' and k % 3 == 0 else rng.normal()
            publisher.publish(Float64(data=value))
        if k % 100 == 0:
            time.sleep(0.01)
    assert wait_for(lambda: ident.aligner.stats.invalid >= 500, 60.0)
    # the topics stop: the node notices, keeps running and answers
    assert wait_for(lambda: streams and streams[-1] == 'stopped: current, speed, voltage', 30.0)
    response = call(feeder, 'identifier/identify')
    assert not response.success and 'not enough data' in response.message
    stats = ident.aligner.stats
    assert stats.lost + stats.unmatched_at_start == 500 and ident.cutter.discarded_samples > 0
    remove_nodes(ros, feeder, ident)


def test_topics_are_not_called_stopped_while_their_messages_wait_to_be_taken(ros, tmp_path):
    """A busy node (its process timer late by more than stream_timeout_s) loses nothing."""
    ident = Identifier(namespace='busy', parameter_overrides=[
        Parameter(name, value=value) for name, value in {
            'record_dir': str(tmp_path / 'busy'), 'record': False, 'online': False,
            'discover': False, 'compare_paper': False, 'stream_timeout_s': 0.3}.items()])
    feeder = rclpy.create_node('feeder', namespace='busy')  # neither node is spun: the
    publishers = [feeder.create_publisher(Float64, name, 1000)  # test runs the timers
                  for name in ('voltage', 'current', 'speed')]
    try:
        assert wait_for(lambda: all(p.get_subscription_count() for p in publishers), 30.0)

        def publish(count):
            for _ in range(count):
                for publisher in publishers:
                    publisher.publish(Float64(data=1.0))
        publish(10)
        assert wait_for(lambda: ident.process() or len(ident.inbox.last_seen) == 3, 30.0)
        taken = time.monotonic()
        publish(10)  # they wait in the queues while the node is busy for twice the timeout
        wait_for(lambda: time.monotonic() - taken > 0.6, 5.0)
        ident._health()
        assert ident.health.stalled == set() and ident.aligner.stats.lost == 0
        assert ident.aligner.stats.received == 60
    finally:
        ident.close()
        ident.destroy_node()
        feeder.destroy_node()


def test_lost_late_and_reordered_messages_land_on_their_samples(ros, tmp_path):
    """Drive the node's message path with the DDS metadata of a lossy, reordering link."""
    from dcmotor_id.simulation import simulate_motor
    from dcmotor_id.simulation.excitation import make_excitation

    # not spun: the test thread is the only one calling into the node
    ident = Identifier(namespace='lossy', parameter_overrides=[
        Parameter('window_s', value=8.0), Parameter('record', value=False),
        Parameter('min_window_s', value=0.1)])
    _, voltage = make_excitation('paper', 8.0, 1e-3)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, 1e-3)
    rng = np.random.default_rng(4)
    messages = []
    for name, values in (('voltage', voltage), ('current', current), ('speed', speed)):
        for k, value in enumerate(values):
            messages.append((k + rng.uniform(0, 40), name, k + 1, value))  # up to 40 late
    messages.sort()
    lost = set(rng.choice(len(messages), 30, replace=False).tolist())
    for position, (_, name, sequence, value) in enumerate(messages):
        if position in lost:
            continue
        ident.inbox.put_message(name, float(value), {'publication_sequence_number': sequence,
                                                     'source_timestamp': 0})
        if position % 300 == 0:
            ident.process()
    ident.close()  # aligns the rest, gives up what is missing, closes the current window
    stats = ident.aligner.stats
    assert stats.reordered > 0 and stats.lost == len({messages[p][2] for p in lost})
    windows = ident.cutter.windows
    assert sum(window.stamps_ns.size for window in windows) > 7000
    for window in windows:
        k = np.rint((window.stamps_ns - ident.cutter.anchor_ns) / 1e6).astype(int)
        np.testing.assert_array_equal(window.channels['voltage'], voltage[k])
        np.testing.assert_array_equal(window.channels['current'], current[k])
        np.testing.assert_array_equal(window.channels['speed'], speed[k])
    assert ident.estimator.estimate().converged
    ident.destroy_node()


@pytest.mark.slow
@pytest.mark.parametrize('case', ['unwritable', 'full'])
def test_unwritable_or_full_record_dir_is_reported_and_identify_still_works(ros, tmp_path,
                                                                            case):
    if case == 'unwritable':
        # issue 30: refused at start-up (it used to run without recording, an error logged)
        blocker = tmp_path / 'a_file'
        blocker.write_text('x')
        with pytest.raises(ValueError, match='parameter record_dir = .*: cannot write there'):
            Identifier(namespace='disk_unwritable', parameter_overrides=[
                Parameter('record_dir', value=str(blocker / 'windows'))])
        return
    overrides = {'min_free_mb': 1e12}
    namespace = f'disk_{case}'
    sim = add(ros, SimMotor(namespace=namespace))
    ident = identifier(ros, namespace, tmp_path, window_s=3.0, **overrides)
    assert wait_for(lambda: ident.aligner.stats.emitted >= 3500, 20.0)
    probe = add(ros, rclpy.create_node('probe_disk', namespace=namespace))
    response = call(probe, 'identifier/identify')
    assert response.success, response.message
    assert 'not recorded' in response.message
    record_error = ident.recorder.error
    assert record_error and ('cannot record' in record_error or 'free' in record_error)
    remove_nodes(ros, probe, sim, ident)
