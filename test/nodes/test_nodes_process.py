"""The installed executables in their own processes: colcon layout, identify, SIGKILL."""

import os
import shutil
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger
from support import alive, children

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.bag import read_bag
from dcmotor_id.nodes.common import spin_until
from dcmotor_id.nodes.identifier import LATCHED, RESULT_KEYS

pytestmark = pytest.mark.ros

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BIN = os.path.dirname(sys.executable)
COLCON = shutil.which('colcon', path=BIN) or shutil.which('colcon')
EXECUTABLES = ('identifier', 'sim_motor', 'replay')


def test_executables_are_on_the_venv_path():
    for name in EXECUTABLES:
        assert shutil.which(name, path=BIN), f'{name} is not in {BIN}'


@pytest.fixture(scope='module')
def installed(tmp_path_factory):
    """``colcon build`` of this package against the wheels; return the install prefix."""
    if COLCON is None:
        pytest.skip('colcon is not installed (pip install -r requirements.txt installs it)')
    base = tmp_path_factory.mktemp('colcon')
    result = subprocess.run(
        [COLCON, '--log-base', str(base / 'log'), 'build', '--base-paths', ROOT,
         '--build-base', str(base / 'build'), '--install-base', str(base / 'install')],
        cwd=base, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    installed = base / 'install' / 'dcmotor_id'
    # the installed copy has a numba cache of its own: fill it as the set-up step does, or
    # the nodes' first samples wait for the compiler (minutes on a loaded machine)
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(next((installed / 'lib').glob('python3*/site-packages'))),
         os.environ.get('PYTHONPATH', '')]))
    result = subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.warmup'], cwd=base,
                            env=environment, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return installed


def test_colcon_installs_the_ros_layout(installed):
    for name in EXECUTABLES:
        assert os.access(installed / 'lib' / 'dcmotor_id' / name, os.X_OK)
    share = installed / 'share' / 'dcmotor_id'
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'identifier.yaml').is_file()
    assert (share / 'config' / 'sim_motor.yaml').is_file()
    assert (share / 'launch' / 'dcmotor_id.launch.py').is_file()
    assert (installed.parent.parent / 'install' / 'dcmotor_id' / 'share' / 'ament_index' /
            'resource_index' / 'packages' / 'dcmotor_id').is_file()


def start(installed, name, ros_env, log_dir, *arguments):
    environment = dict(ros_env)
    site = next((installed / 'lib').glob('python3*/site-packages'))
    environment['PYTHONPATH'] = str(site) + os.pathsep + environment.get('PYTHONPATH', '')
    environment['PYTHONUNBUFFERED'] = '1'
    log = open(log_dir / f'{name}.log', 'w')
    return subprocess.Popen(
        [str(installed / 'lib' / 'dcmotor_id' / name), '--ros-args',
         '--params-file', str(installed / 'share' / 'dcmotor_id' / 'config' / f'{name}.yaml'),
         *arguments], env=environment, stdout=log, stderr=subprocess.STDOUT)


def stop(process):
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.fixture(scope='module')
def client(ros_env):
    rclpy.init()
    node = rclpy.create_node('test_client')
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    yield node, executor
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()


def spin_while_progressing(executor, progress, target, stall_s=60.0, limit_s=600.0):
    """Spin until ``progress()`` reaches ``target``; give up when it stalls for ``stall_s``."""
    start = last_change = time.monotonic()
    seen = progress()
    while seen < target:
        now = time.monotonic()
        if now - last_change > stall_s or now - start > limit_s:
            return False
        executor.spin_once(timeout_sec=0.05)
        value = progress()
        if value != seen:
            seen, last_change = value, time.monotonic()
    return True


@pytest.mark.slow
def test_installed_nodes_identify_across_processes_and_survive_sigkill(
        installed, ros_env, client, tmp_path):
    node, executor = client
    record_dir = tmp_path / 'windows'
    # the batched transport keeps this test independent of how busy the machine is; the
    # Float64 topics are tested in-process and measured by bench/bench_throughput.py
    sim = start(installed, 'sim_motor', ros_env, tmp_path, '-p', 'transport:=batch')
    ident = start(installed, 'identifier', ros_env, tmp_path, '-p', 'input:=batch', '-p',
                  f'record_dir:={record_dir}', '-p', 'window_s:=3.0')
    try:
        trigger = node.create_client(Trigger, '/identifier/identify')
        assert trigger.wait_for_service(timeout_sec=30.0), \
            (tmp_path / 'identifier.log').read_text()
        online = []
        node.create_subscription(DiagnosticStatus, '/identifier/online_parameters',
                                 online.append, 10)

        def updates():
            values = {kv.key: kv.value for kv in online[-1].values} if online else {}
            return int(values.get('n_updates', 0))
        # more than two windows of 3 s; on a loaded machine the nodes run slower than real
        # time, so the wait lasts as long as the samples keep coming
        assert spin_while_progressing(executor, updates, 6500), (
            updates(), (tmp_path / 'identifier.log').read_text(),
            (tmp_path / 'sim_motor.log').read_text())
        future = trigger.call_async(Trigger.Request())
        assert spin_until(executor, future.done, 120.0)
        response = future.result()
        assert response.success, response.message
        latched = []
        node.create_subscription(DiagnosticStatus, '/identifier/parameters', latched.append,
                                 LATCHED)
        assert spin_until(executor, lambda: latched, 10.0)
        values = {kv.key: float(kv.value) for kv in latched[-1].values}
        truth = PAPER_MOTORS['paper2'].as_dict()
        for key in RESULT_KEYS:
            assert values[key] == pytest.approx(truth[key], rel=0.02), key
        # kill the identifier in the middle of a window: what it finished stays readable
        assert spin_while_progressing(
            executor, lambda: len(list(record_dir.glob('window_*'))), 3)
        time.sleep(1.0)
        workers = children(ident.pid)  # the fitting process started by ~/identify
        assert workers
        ident.send_signal(signal.SIGKILL)
        ident.wait(timeout=10)
        deadline = time.monotonic() + 10  # ... does not outlive the killed node
        while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(alive(pid) for pid in workers)
        windows = sorted(path for path in record_dir.iterdir()
                         if path.name.startswith('window_'))
        assert len(windows) >= 2
        for window in windows:
            assert len(read_bag(str(window))) >= 500
        # a restarted identifier cleans up, carries on numbering and keeps recording
        ident = start(installed, 'identifier', ros_env, tmp_path, '-p', 'input:=batch', '-p',
                      f'record_dir:={record_dir}', '-p', 'window_s:=1.0')
        leftovers = {path.name for path in record_dir.glob('.partial_*')}
        deadline = time.monotonic() + 90
        finished = {path.name for path in windows}
        while time.monotonic() < deadline:
            new = sorted({path.name for path in record_dir.glob('window_*')} - finished)
            if new:
                break
            time.sleep(0.2)
        assert new, (tmp_path / 'identifier.log').read_text()
        assert not leftovers & {path.name for path in record_dir.iterdir()}
        assert int(new[0].split('_')[1]) > int(windows[-1].name.split('_')[1])
        assert ident.poll() is None and sim.poll() is None
    finally:
        stop(ident)
        stop(sim)
