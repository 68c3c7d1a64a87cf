"""The identifier on topics published as a robot's drives publish them (issue 32)."""

import pytest
from support import spinning_executor

from dcmotor_id.core.model import PAPER_MOTORS, relative_errors_pct
from dcmotor_id.nodes.drive_emulator import identify_published

pytestmark = [pytest.mark.ros, pytest.mark.slow]

TRUTH = PAPER_MOTORS['paper2']

CASES = {
    # name: (rate [Hz], transport, identifier overrides, drive_messages options)
    'joint_states now() in 50 ms bursts, voltage by source time': (
        500.0, 'joint_state', {}, {'stamps': 'now', 'burst_s': 0.05}),
    'joint_states on the grid with 20 % jitter, in bursts; voltage by source time': (
        1000.0, 'joint_state', {}, {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05}),
    'voltage at 1 kHz beside joint_states at 500 Hz, now() bursts': (
        500.0, 'joint_state', {}, {'stamps': 'now', 'burst_s': 0.05, 'voltage_rate': 2}),
    'float64 topics by timestamp, published when due': (
        1000.0, 'float64', {}, {'stamps': 'now'}),
    'float64 topics by timestamp, 50 ms bursts': (
        500.0, 'float64', {}, {'stamps': 'now', 'burst_s': 0.05}),
    'batches of 50 ms bursts, sample times with 20 % jitter': (
        1000.0, 'batch', {}, {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05}),
}


@pytest.fixture(scope='module')
def ros(ros_env):
    with spinning_executor() as executor:
        yield executor


@pytest.mark.parametrize('case', sorted(CASES))
def test_robot_topics_are_used_whole_and_identify_the_motor(ros, case):
    rate_hz, transport, overrides, publish = CASES[case]
    namespace = 'robot_' + str(sorted(CASES).index(case))
    out = identify_published(ros, namespace, rate_hz, 6.0, transport, identifier=overrides,
                             seed=1, **publish)
    response = out['response']
    assert response.success, response.message
    result = out['result']
    used = result['n_samples'] / out['samples']
    assert used >= 0.99, (used, out['stats'], out['regrid'])
    errors = relative_errors_pct(result['parameters'], TRUTH)
    for key in ('Ra', 'CPhi', 'J', 'b'):
        assert abs(errors[key]) < 1.0, (key, errors, out['regrid'])
    if transport == 'batch':  # the times are in the messages: nothing to place
        assert out['stats']['duplicates'] == out['stats']['lost'] == 0
        return
    # what was placed and how is said in the answer and on /diagnostics
    assert 'placed on the grid' in response.message
    keys = dict(out['health'])
    source = 'joint_states' if transport == 'joint_state' else 'current'
    assert int(keys[f'regrid.{source}.on_grid']) >= 0.99 * out['samples']
    if 'burst_s' in publish and publish['stamps'] == 'now':  # else as the thread manages
        assert keys[f'regrid.{source}.bursty'] == 'True'


def test_mechanical_only_joint_states_with_now_stamps_in_bursts(ros):
    """The issue's third case: torque_constant, no voltage, now() stamps (1,159 of 6,500)."""
    out = identify_published(ros, 'robot_mech', 500.0, 6.0, 'joint_state',
                             identifier={'torque_constant': TRUTH.CPhi}, seed=2,
                             stamps='now', burst_s=0.05)
    assert out['response'].success, out['response'].message
    result = out['result']
    assert result['n_samples'] >= 0.99 * out['samples'], out['regrid']
    errors = relative_errors_pct(result['parameters'], TRUTH)
    for key in ('J', 'b'):
        assert abs(errors[key]) < 1.0, (key, errors)
