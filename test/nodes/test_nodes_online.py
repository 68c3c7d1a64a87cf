"""The online estimate and its change alarms in a real graph: sim_motor with a schedule."""


from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest
import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, MultiArrayLayout
from support import spinning_executor, wait_for

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.nodes.identifier import Identifier
from dcmotor_id.nodes.sim_motor import SimMotor

pytestmark = pytest.mark.ros

TRUTH = PAPER_MOTORS['paper2']


@pytest.fixture
def ros(ros_env):
    with spinning_executor() as executor:
        yield executor


def values_of(status):
    return {kv.key: kv.value for kv in status.values}


def test_a_scheduled_change_raises_an_alarm_on_diagnostics_and_online_parameters(ros):
    sim = SimMotor(namespace='drift', parameter_overrides=[
        Parameter('transport', value='batch'), Parameter('schedule', value='b:+50%:step:6')])
    nominal = [Parameter(f'nominal_{name}', value=float(getattr(TRUTH, name)))
               for name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc')]
    ident = Identifier(namespace='drift', parameter_overrides=[
        Parameter('input', value='batch'), Parameter('record', value=False),
        Parameter('online_window_s', value=6.0), Parameter('online_refit_interval_s', value=1.0),
        Parameter('online_cpu_budget', value=0.5), Parameter('online_rate_hz', value=5.0),
        Parameter('monitor_baseline', value='nominal')] + nominal)
    probe = rclpy.create_node('probe', namespace='drift')
    conditions, online = [], []
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda array: conditions.extend(
        s for s in array.status if s.name == 'identifier: condition'), 50)
    probe.create_subscription(DiagnosticStatus, 'identifier/online_parameters', online.append,
                              10)
    samples = probe.create_publisher(Float64MultiArray, 'samples', 10)
    for node in (sim, ident, probe):
        ros.add_node(node)
    try:
        def alarmed():
            return any(values_of(status).get('alarm.b.level') == 'ERROR'
                       for status in conditions)
        assert wait_for(alarmed, 120.0), [(s.level, s.message) for s in conditions[-3:]]
        status = next(s for s in conditions if values_of(s).get('alarm.b.level') == 'ERROR')
        assert status.level == DiagnosticStatus.ERROR and 'b +' in status.message
        pairs = values_of(status)
        assert pairs['alarm_level'] == 'ERROR' and pairs['baseline'] == 'nominal'
        assert float(pairs['alarm.b.change_pct']) > 15.0
        assert float(pairs['alarm.b.sigmas']) > 5.0
        assert 'viscous friction' in pairs['alarm.b.meaning'] and 'alarm.b.since' in pairs
        assert wait_for(lambda: 'alarm.b.level' in values_of(online[-1]), 10.0)
        latest = values_of(online[-1])
        assert latest['method'] == 'window' and 'b +' in latest['alarms']
        assert float(latest['b']) == pytest.approx(1.5 * TRUTH.b, rel=0.1)

        # a bad message and failing updates never stop the node
        samples.publish(Float64MultiArray(data=[1.0, 2.0, 3.0], layout=MultiArrayLayout(dim=[
            MultiArrayDimension(label='nonsense', size=3, stride=3)])))
        assert ident.online.update([1.0, 2.0], [1.0], [0.0]) != ''

        def broken(job):
            raise RuntimeError('refit worker unavailable')
        ident.online.estimator.submit = broken
        assert wait_for(lambda: 'refit worker unavailable' in values_of(online[-1])['status'],
                        30.0)
        assert values_of(online[-1])['converged'] == 'false'
        seen = int(values_of(online[-1])['n_updates'])
        assert wait_for(lambda: int(values_of(online[-1])['n_updates']) > seen + 1000, 30.0)
    finally:
        for node in (sim, ident, probe):
            ros.remove_node(node)
        ident.close()
        for node in (sim, ident, probe):
            node.destroy_node()
