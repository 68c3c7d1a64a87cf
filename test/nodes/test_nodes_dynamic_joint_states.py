"""The identifier on ros2_control's ``/dynamic_joint_states`` (issue 32)."""

import sys

import pytest
from support import spinning_executor

from dcmotor_id.core.model import PAPER_MOTORS, relative_errors_pct

pytestmark = [pytest.mark.ros]

TRUTH = PAPER_MOTORS['paper2']

CASES = {
    # name: (rate [Hz], identifier overrides, drive_messages options)
    'now() stamps in 50 ms bursts': (500.0, {}, {'stamps': 'now', 'burst_s': 0.05}),
    'grid stamps with 20 % jitter, in bursts': (
        1000.0, {}, {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05}),
}


def test_without_control_msgs_the_node_refuses_at_start_up_saying_how_to_install(
        ros_env, monkeypatch):
    import rclpy
    from rclpy.parameter import Parameter

    from dcmotor_id.nodes.identifier import Identifier

    monkeypatch.setitem(sys.modules, 'control_msgs', None)  # import fails as if absent
    monkeypatch.setitem(sys.modules, 'control_msgs.msg', None)
    rclpy.init()
    try:
        with pytest.raises(ValueError, match='make control-msgs'):
            Identifier(parameter_overrides=[Parameter('input', value='dynamic_joint_state'),
                                            Parameter('record', value=False)])
    finally:
        rclpy.try_shutdown()


@pytest.fixture(scope='module')
def ros(ros_env):
    pytest.importorskip('control_msgs.msg', reason='control_msgs not installed: '
                        'make control-msgs (docs/nodes.md)')
    with spinning_executor() as executor:
        yield executor


@pytest.mark.slow
@pytest.mark.parametrize('case', sorted(CASES))
def test_dynamic_joint_states_are_used_whole_and_identify_the_motor(ros, case):
    from dcmotor_id.nodes.drive_emulator import identify_published

    rate_hz, overrides, publish = CASES[case]
    namespace = 'dynamic_' + str(sorted(CASES).index(case))
    out = identify_published(ros, namespace, rate_hz, 6.0, 'dynamic_joint_state',
                             identifier=overrides, seed=1, **publish)
    response = out['response']
    assert response.success, response.message
    result = out['result']
    used = result['n_samples'] / out['samples']
    assert used >= 0.99, (used, out['stats'], out['regrid'])
    errors = relative_errors_pct(result['parameters'], TRUTH)
    for key in ('Ra', 'CPhi', 'J', 'b'):
        assert abs(errors[key]) < 1.0, (key, errors, out['regrid'])
    assert 'placed on the grid' in response.message
    keys = dict(out['health'])
    assert int(keys['regrid.dynamic_joint_states.on_grid']) >= 0.99 * out['samples']
    if publish['stamps'] == 'now':
        assert keys['regrid.dynamic_joint_states.bursty'] == 'True'


@pytest.mark.slow
def test_a_joint_without_the_asked_interface_is_refused_and_counted(ros):
    from dcmotor_id.nodes.drive_emulator import identify_published

    out = identify_published(ros, 'dynamic_refused', 500.0, 1.0, 'dynamic_joint_state',
                             identifier={'current_interface': 'armature_current'},
                             stamps='now')
    response = out['response']
    assert not response.success
    assert 'malformed joint_states refused' in response.message
    assert 'no interface armature_current' in response.message
    keys = dict(out['health'])
    assert int(keys['malformed_joint_states']) == out['published']['dynamic_joint_states']
