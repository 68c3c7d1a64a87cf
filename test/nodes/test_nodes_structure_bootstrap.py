"""The identifier's ``structure_bootstrap`` parameter: passed to ~/identify, bad values refused."""

import pytest
import rclpy
from rclpy.parameter import Parameter
from support import call, remove_nodes, spinning_executor, wait_for

from dcmotor_id.nodes.identifier import Identifier
from dcmotor_id.nodes.settings import check_structure_bootstrap
from dcmotor_id.nodes.sim_motor import SimMotor

pytestmark = pytest.mark.ros


@pytest.fixture(scope='module')
def ros(ros_env):
    with spinning_executor() as executor:
        yield executor


class _Log:
    """A node logger that keeps what it is told (rclpy's goes to the process's stderr)."""

    def __init__(self):
        self.lines = []

    def __getattr__(self, level):
        return lambda text, **_: self.lines.append((level, text))


def _identifier(namespace, tmp_path, monkeypatch, **overrides):
    log = _Log()
    monkeypatch.setattr(Identifier, 'get_logger', lambda self: log)
    parameters = {'record_dir': str(tmp_path / namespace), 'window_s': 6.0, 'online': False,
                  'compare_paper': False, **overrides}
    node = Identifier(namespace=namespace, parameter_overrides=[
        Parameter(name, value=value) for name, value in parameters.items()])
    return node, log


def test_the_node_passes_structure_bootstrap_to_identify(ros, tmp_path, monkeypatch):
    sim = SimMotor(namespace='boot')
    ident, _ = _identifier('boot', tmp_path, monkeypatch, structure_bootstrap=2)
    probe = rclpy.create_node('probe_boot', namespace='boot')
    for node in (sim, ident, probe):
        ros.add_node(node)
    try:
        assert wait_for(lambda: ident.aligner.stats.emitted >= 7000, 30.0)
        remove_nodes(ros, sim)
        response = call(probe, 'identifier/identify', timeout_s=240.0)
        assert response.success, response.message
        uncertainty = ident.last_result['structure_uncertainty']
        assert uncertainty['resamples'] == 2, uncertainty
    finally:
        remove_nodes(ros, probe, ident)


@pytest.mark.parametrize('bad', [-1, 1, 2.5, 'twenty', True, 1001])
def test_a_bad_structure_bootstrap_at_launch_is_logged_and_the_node_runs(ros, tmp_path,
                                                                         monkeypatch, bad):
    ident, log = _identifier('launch', tmp_path, monkeypatch, structure_bootstrap=bad)
    probe = rclpy.create_node('probe_launch', namespace='launch')
    ros.add_node(ident)
    ros.add_node(probe)
    try:
        assert ident.structure_bootstrap == 0
        errors = [text for level, text in log.lines if level == 'error']
        assert any(f'structure_bootstrap = {bad!r} refused' in text and 'from 2 to 1000' in text
                   and 'off (0)' in text for text in errors), log.lines
        response = call(probe, 'identifier/identify')  # the node answers
        assert not response.success and 'not enough data' in response.message
    finally:
        remove_nodes(ros, probe, ident)


def test_structure_bootstrap_set_while_running_is_checked(ros, tmp_path, monkeypatch):
    ident, log = _identifier('running', tmp_path, monkeypatch)
    try:
        assert ident.structure_bootstrap == 0
        assert ident.set_parameters([Parameter('structure_bootstrap', value=20)])[0].successful
        assert ident.structure_bootstrap == 20
        for bad in (1, -3, 'many', 0.5):
            outcome, = ident.set_parameters([Parameter('structure_bootstrap', value=bad)])
            assert not outcome.successful
            assert 'structure_bootstrap' in outcome.reason and 'from 2 to' in outcome.reason
            assert ident.structure_bootstrap == 20
            assert ident.get_parameter('structure_bootstrap').value == 20
        assert any('it stays 20' in text for level, text in log.lines if level == 'error')
        assert ident.set_parameters([Parameter('structure_bootstrap', value=0)])[0].successful
        assert ident.structure_bootstrap == 0
    finally:
        ident.close()
        ident.destroy_node()


def test_check_structure_bootstrap_takes_what_the_cli_takes():
    assert check_structure_bootstrap(0) == 0
    assert check_structure_bootstrap(2) == 2
    assert check_structure_bootstrap(4.0) == 4  # a whole number given as a float
    for bad in (1, -2, 2.5, 'x', False, None, 1001):
        with pytest.raises(ValueError, match='structure_bootstrap'):
            check_structure_bootstrap(bad)
