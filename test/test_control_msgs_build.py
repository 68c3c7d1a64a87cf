"""
The install step that generates control_msgs' DynamicJointState (tools/build_control_msgs.sh).

It builds the package into a temporary prefix with the generators of the venv (or of the venv
named by ``DCMOTOR_ID_CONTROL_MSGS_VENV``) and checks, in a fresh interpreter, that the
message it generates is the one the bag reader decodes: the CDR bytes rclpy serializes read
back with rosbags from the same .msg definitions, field by field, and the type hash the
build gave the type the one rosbags computes from the definition.
"""

import os
import subprocess
import sys
import textwrap

import pytest

pytestmark = [pytest.mark.slow]

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCRIPT = os.path.join(ROOT, 'tools', 'build_control_msgs.sh')
VENV = os.environ.get('DCMOTOR_ID_CONTROL_MSGS_VENV', sys.prefix)

CHECK = textwrap.dedent("""
    import pathlib, sys
    import control_msgs.msg as msg
    from rclpy.serialization import serialize_message
    from rosbags.typesys import get_types_from_msg, get_typestore, Stores

    assert pathlib.Path(msg.__file__).is_relative_to(sys.argv[1]), msg.__file__
    state = msg.DynamicJointState(joint_names=['other', 'axis'], interface_values=[
        msg.InterfaceValue(interface_names=['velocity'], values=[0.5]),
        msg.InterfaceValue(interface_names=['current', 'voltage'], values=[1.25, -12.0])])
    state.header.stamp.sec, state.header.stamp.nanosec = 1700000000, 123
    data = serialize_message(state)
    store = get_typestore(Stores.ROS2_JAZZY)
    folder = pathlib.Path(sys.argv[2])
    for name in ('InterfaceValue', 'DynamicJointState'):
        store.register(get_types_from_msg((folder / f'{name}.msg').read_text(),
                                          f'control_msgs/msg/{name}'))
    back = store.deserialize_cdr(data, 'control_msgs/msg/DynamicJointState')
    assert back.header.stamp.sec == 1700000000 and back.header.stamp.nanosec == 123
    assert list(back.joint_names) == ['other', 'axis']
    assert list(back.interface_values[1].interface_names) == ['current', 'voltage']
    assert list(back.interface_values[1].values) == [1.25, -12.0]
    # the type hash the build gave the type (what DDS discovery and bags carry) is the one
    # rosbags computes from control_msgs' definition
    import json
    described = json.loads((pathlib.Path(sys.argv[1]) / 'share' / 'control_msgs' / 'msg' /
                            'DynamicJointState.json').read_text())
    hashes = {entry['type_name']: entry['hash_string'] for entry in described['type_hashes']}
    assert hashes['control_msgs/msg/DynamicJointState'] == store.hash_rihs01(
        'control_msgs/msg/DynamicJointState')
    print('decoded', len(data), 'bytes')
""")


def test_the_generated_message_is_what_the_bag_reader_decodes(tmp_path):
    if not os.path.isfile(os.path.join(VENV, 'share', 'ament_cmake', 'cmake',
                                       'ament_cmakeConfig.cmake')):
        pytest.skip(f'no ament_cmake in {VENV}: make control-msgs installs the generators '
                    '(requirements-control-msgs.txt)')
    prefix = tmp_path / 'prefix'
    built = subprocess.run(['bash', SCRIPT, VENV, str(prefix)], capture_output=True, text=True,
                           timeout=600)
    assert built.returncode == 0, built.stdout + built.stderr
    site = next((prefix / 'lib').glob('python3*/site-packages'))
    environment = dict(os.environ, PYTHONPATH=os.pathsep.join([str(site), ROOT]),
                       LD_LIBRARY_PATH=os.pathsep.join(
                           [str(prefix / 'lib'), os.environ.get('LD_LIBRARY_PATH', '')]))
    environment.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)  # the fresh process sets it anew
    checked = subprocess.run([sys.executable, '-c', CHECK, str(prefix),
                              os.path.join(ROOT, 'tools', 'control_msgs', 'msg')],
                             env=environment, capture_output=True, text=True, timeout=120)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert 'decoded' in checked.stdout


def test_a_missing_generator_is_refused_with_exit_code_2_naming_the_requirements(tmp_path):
    venv = tmp_path / 'venv'
    (venv / 'bin').mkdir(parents=True)
    os.symlink(sys.executable, venv / 'bin' / 'python')
    refused = subprocess.run(['bash', SCRIPT, str(venv), str(tmp_path / 'prefix')],
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert 'requirements-control-msgs.txt' in refused.stderr
    assert 'Traceback' not in refused.stderr
