"""sim_motor with effects switched on: the published samples carry the effect."""

import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.batch import decode_batch
from dcmotor_id.nodes.common import sample_qos, spin_until as spin_executor_until
from dcmotor_id.nodes.sim_motor import parse_effects, SimMotor
from dcmotor_id.simulation import simulate_motor

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def ros(ros_env):
    rclpy.init()
    yield
    rclpy.try_shutdown()


def spin_until(node, condition, timeout_s):
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        return spin_executor_until(executor, condition, timeout_s)
    finally:
        executor.shutdown()


def published_samples(effects, count=2000):
    """Run a sim_motor without noise, receive ``count`` batched samples, return them."""
    node = SimMotor(parameter_overrides=[
        Parameter('transport', value='batch'), Parameter('effects', value=effects),
        Parameter('noise_current_a', value=0.0), Parameter('noise_speed_rad_s', value=0.0),
        Parameter('signal', value='sine'), Parameter('amplitude_v', value=20.0)])
    probe = rclpy.create_node('probe')
    sent = []
    try:
        probe.create_subscription(Float64MultiArray, 'samples', sent.append,
                                  sample_qos(5000, 'reliable'))
        assert spin_until(probe, lambda: node.count_subscribers('samples') > 0, 10.0)
        node.publish_samples(count)  # the node is not spun: no timer publishes besides
        assert spin_until(probe, lambda: sum(m.layout.dim[1].size for m in sent) >= count,
                          10.0)
    finally:
        probe.destroy_node()
        node.destroy_node()
    rows = np.hstack([decode_batch([dim.label for dim in message.layout.dim],
                                   [dim.size for dim in message.layout.dim],
                                   np.asarray(message.data)) for message in sent])
    return dict(zip(('t', 'voltage', 'current', 'speed'), rows))


def test_without_effects_it_is_the_exact_simulator(ros):
    samples = published_samples('')
    params = PAPER_MOTORS['paper2']
    current, speed = simulate_motor(params, samples['voltage'], 1e-3)
    assert np.allclose(samples['current'], current, atol=1e-9)
    assert np.allclose(samples['speed'], speed, atol=1e-9)


def test_current_offset_and_load_torque_show_in_the_samples(ros):
    clean = published_samples('')
    offset = published_samples('current_offset:offset_A=0.5')
    assert np.allclose(offset['current'] - clean['current'], 0.5, atol=1e-6)
    loaded = published_samples('load_torque:torque_Nm=0.5')
    # A load torque opposing positive motion slows the shaft while it turns forward.
    forward = clean['speed'] > 1.0
    assert np.all(loaded['speed'][forward] < clean['speed'][forward])


def test_bad_effects_parameter_names_the_entry():
    with pytest.raises(ValueError, match='no_such_effect'):
        parse_effects('load_torque:torque_Nm=0.3;no_such_effect:x=1')
    assert parse_effects('') == []
