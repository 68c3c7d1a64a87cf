"""Bags: MCAP/sqlite3 reading with the bag's timestamps, atomic window writing, the CLI."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from support import motor_samples

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats.bag import load_messages, read_bag, TruncatedBagWarning, write_bag
from dcmotor_id.formats.recording import WindowBagWriter
from dcmotor_id.identification.identify import identify, prepare_records


@pytest.mark.parametrize('batch_samples', [0, 250])
def test_written_bag_reads_back_exactly(tmp_path, batch_samples):
    stamps, channels = motor_samples(2.0)
    path = tmp_path / 'bag'
    write_bag(path, stamps, channels, batch_samples=batch_samples)
    names = sorted(os.listdir(path))
    assert names == ['bag.mcap', 'metadata.yaml']
    metadata = (path / 'metadata.yaml').read_text()
    assert 'version: 9' in metadata and 'storage_identifier: mcap' in metadata
    for source in (path, path / 'bag.mcap'):
        record = read_bag(str(source))
        np.testing.assert_array_equal(record.time_s, (stamps - stamps[0]) * 1e-9)
        for name, values in channels.items():
            np.testing.assert_array_equal(getattr(record, name), values)


def test_sqlite3_bag_with_arrival_stamps_is_aligned(tmp_path):
    """A bag as ``ros2 bag record`` writes it: sqlite3, stamped on arrival with jitter."""
    stamps, channels = motor_samples(1.0)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    float64 = typestore.types['std_msgs/msg/Float64']
    rng = np.random.default_rng(5)
    path = tmp_path / 'recorded'
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
    writer.open()
    rows = []
    for name in ('voltage', 'current', 'speed'):
        connection = writer.add_connection(f'/drive/{name}', 'std_msgs/msg/Float64',
                                           typestore=typestore)
        jitter = rng.integers(0, 300_000, stamps.size)  # up to 0.3 ms late
        rows += [(int(stamp), connection, value) for stamp, value in
                 zip(stamps + jitter, channels[name])]
    for stamp, connection, value in sorted(rows, key=lambda row: row[0]):
        writer.write(connection, stamp,
                     typestore.serialize_cdr(float64(data=float(value)), 'std_msgs/msg/Float64'))
    writer.close()
    record = read_bag(str(path))  # relative topic names match the /drive namespace
    assert len(record) == stamps.size
    np.testing.assert_allclose(np.diff(record.time_s), 1e-3, rtol=1e-4)
    for name, values in channels.items():
        np.testing.assert_array_equal(getattr(record, name), values)


def test_missing_topics_are_named(tmp_path):
    stamps, channels = motor_samples(0.5)
    write_bag(tmp_path / 'bag', stamps, channels,
              topics={'voltage': '/u', 'current': '/i', 'speed': '/w'})
    with pytest.raises(InputDataError, match=r'current \(current\).*it has: /i'):
        read_bag(str(tmp_path / 'bag'))
    record = read_bag(str(tmp_path / 'bag'),
                      topics={'voltage': 'u', 'current': 'i', 'speed': 'w'})
    np.testing.assert_array_equal(record.speed, channels['speed'])


def test_unfinished_bag_directory_is_read_from_its_file_or_refused_clearly(tmp_path):
    stamps, channels = motor_samples(0.5)
    write_bag(tmp_path / 'killed', stamps, channels)
    (tmp_path / 'killed' / 'metadata.yaml').unlink()  # rosbag2 writes it on closing
    with pytest.warns(UserWarning, match='no metadata.yaml'):
        record = read_bag(str(tmp_path / 'killed'))
    np.testing.assert_array_equal(record.current, channels['current'])
    (tmp_path / 'half').mkdir()
    (tmp_path / 'half' / 'half.mcap').write_bytes(b'\x89MCAP0\r\n')
    with pytest.warns(UserWarning), pytest.raises(InputDataError, match='cannot open'):
        read_bag(str(tmp_path / 'half'))
    (tmp_path / 'empty').mkdir()
    with pytest.raises(InputDataError, match='without metadata.yaml.*no .mcap file'):
        read_bag(str(tmp_path / 'empty'))


def test_cli_identifies_a_bag_like_the_library(tmp_path, capsys):
    stamps, channels = motor_samples(8.0)
    write_bag(tmp_path / 'bag', stamps, channels, topics={'voltage': '/m/voltage',
                                                          'current': '/m/current',
                                                          'speed': '/m/speed'})
    out = tmp_path / 'result.json'
    code = cli_main(['identify', str(tmp_path / 'bag'), '--json', str(out), '--no-discover',
                     '--current-topic', '/m/current'])
    assert code == 0, capsys.readouterr().err
    from_cli = json.loads(out.read_text())
    records = prepare_records([read_bag(str(tmp_path / 'bag'))])
    direct = identify(records, discover=False).as_dict()
    assert from_cli['parameters'] == pytest.approx(direct['parameters'], rel=1e-12)
    truth = PAPER_MOTORS['paper2'].as_dict()
    assert from_cli['parameters'] == pytest.approx(truth, rel=0.02)
    code = cli_main(['identify', str(tmp_path / 'bag'), '--speed-topic', 'nope'])
    assert code == 2
    assert 'speed (nope) not in the bag' in capsys.readouterr().err


def test_window_writer_rotates_within_the_budget(tmp_path):
    stamps, channels = motor_samples(1.0)
    one = write_bag(tmp_path / 'probe', stamps, channels)
    writer = WindowBagWriter(tmp_path / 'windows', budget_bytes=int(2.5 * one))
    paths = [writer.write(stamps + k * 10 ** 9, channels) for k in range(5)]
    remaining = writer.windows()
    assert remaining == paths[-2:]
    assert writer.deleted == paths[:3]
    for path in remaining:
        assert len(read_bag(path)) == stamps.size
    again = WindowBagWriter(tmp_path / 'windows', budget_bytes=int(2.5 * one))
    assert os.path.basename(again.write(stamps, channels)).startswith('window_000006_')


def test_window_writer_reports_full_and_unwritable_directories(tmp_path):
    stamps, channels = motor_samples(0.5)
    writer = WindowBagWriter(tmp_path / 'w', budget_bytes=10 ** 9, min_free_bytes=2 ** 62)
    with pytest.raises(OSError, match='free') as caught:
        writer.write(stamps, channels)
    assert caught.value.errno == 28  # ENOSPC
    assert os.listdir(tmp_path / 'w') == []
    blocker = tmp_path / 'file'
    blocker.write_text('not a directory')
    with pytest.raises(OSError):
        WindowBagWriter(blocker / 'windows', budget_bytes=10 ** 9)


WRITER_SCRIPT = """
import sys, numpy as np
from dcmotor_id.formats.recording import WindowBagWriter
writer = WindowBagWriter(sys.argv[1], budget_bytes=10 ** 9)
stamps = 10 ** 18 + np.arange(20000) * 10 ** 6
channels = {name: np.random.default_rng(0).normal(size=20000)
            for name in ('voltage', 'current', 'speed')}
print('ready', flush=True)
for k in range(10 ** 6):
    writer.write(stamps + k * 20 * 10 ** 9, channels)
"""


def test_sigkill_while_writing_leaves_only_readable_bags(tmp_path):
    directory = tmp_path / 'windows'
    process = subprocess.Popen([sys.executable, '-c', WRITER_SCRIPT, str(directory)],
                               stdout=subprocess.PIPE, text=True)
    try:
        assert process.stdout.readline().strip() == 'ready'
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # kill in the middle of the third window
            names = os.listdir(directory)
            if sum(name.startswith('window_') for name in names) >= 2 and \
                    any(name.startswith('.partial_') for name in names):
                break
            time.sleep(0.005)
        process.send_signal(signal.SIGKILL)
    finally:
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL
    finished = sorted(name for name in os.listdir(directory) if name.startswith('window_'))
    assert len(finished) >= 2
    for name in finished:
        assert len(read_bag(str(directory / name))) == 20000
    writer = WindowBagWriter(directory, budget_bytes=10 ** 9)  # cleans up the leftover
    assert not [name for name in os.listdir(directory) if name.startswith('.partial_')]
    assert writer.windows() == [str(directory / name) for name in finished]


@pytest.mark.parametrize('batch_samples', [0, 250])
@pytest.mark.parametrize('fraction', [0.99, 0.5])
def test_truncated_mcap_is_read_up_to_the_cut_with_a_warning(tmp_path, fraction,
                                                             batch_samples):
    """A recorder that crashed or a copy cut short: the complete chunks are still data."""
    stamps, channels = motor_samples(20.0)
    path = tmp_path / 'bag'
    write_bag(path, stamps, channels, batch_samples=batch_samples)
    mcap = path / 'bag.mcap'
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * fraction)])
    for source in (path, mcap):  # the bag directory and the bare file
        with pytest.warns(TruncatedBagWarning) as caught:
            record = read_bag(str(source))
        count = len(record)
        # every message that arrived whole is read, also those of the chunk that was cut
        assert fraction - 0.05 < count / stamps.size <= min(fraction + 0.05, 1.0)
        np.testing.assert_array_equal(record.time_s, (stamps[:count] - stamps[0]) * 1e-9)
        for name, values in channels.items():
            np.testing.assert_array_equal(getattr(record, name), values[:count])
        message = str(caught[0].message)
        assert 'truncated' in message
        assert f'recovered {count} samples' in message
        assert f'spanning {count * 1e-3:.3f} s' in message
    with pytest.warns(TruncatedBagWarning, match='messages spanning'):
        topics, messages = load_messages(str(mcap))  # undecoded, as replay reads them
    assert list(topics) == (['/samples'] if batch_samples else ['/voltage', '/current',
                                                                '/speed'])
    assert messages[0][0] == stamps[0] and len(messages) > 0.45 * len(topics) * stamps.size / \
        max(batch_samples, 1)


def test_cli_identifies_a_truncated_bag_and_says_so(tmp_path, capsys):
    stamps, channels = motor_samples(8.0)
    write_bag(tmp_path / 'bag', stamps, channels)
    mcap = tmp_path / 'bag' / 'bag.mcap'
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * 0.99)])
    code = cli_main(['identify', str(tmp_path / 'bag'), '--no-discover', '--json',
                     str(tmp_path / 'r.json')])
    err = capsys.readouterr().err
    assert code == 0, err
    assert 'dcmotor-id: warning: ' in err and 'truncated' in err
    result = json.loads((tmp_path / 'r.json').read_text())
    assert any('truncated' in text for text in result['warnings'])
    assert result['data_loss'] and 'the rest is lost' in result['data_loss'][0]


def test_a_file_that_is_not_mcap_is_still_refused(tmp_path):
    (tmp_path / 'x.mcap').write_bytes(b'not an mcap file at all')
    with pytest.raises(InputDataError, match='cannot open as a rosbag2 bag'):
        read_bag(str(tmp_path / 'x.mcap'))
    (tmp_path / 'y.mcap').write_bytes(b'\x89MCAP0\r\n')  # only the magic: nothing to recover
    with pytest.raises(InputDataError, match='cannot open as a rosbag2 bag'):
        read_bag(str(tmp_path / 'y.mcap'))


def test_one_reader_entry_point_picks_the_format(tmp_path):
    from dcmotor_id.formats import detect_format, read_record, read_records
    from dcmotor_id.formats.csv import write_csv

    stamps, channels = motor_samples(0.5)
    write_bag(tmp_path / 'bag', stamps, channels)
    bagged = read_record(tmp_path / 'bag')
    write_csv(str(tmp_path / 'r.csv'), bagged)
    assert [detect_format(path) for path in (tmp_path / 'bag', 'x.mcap', 'x.db3', 'r.csv')] \
        == ['bag', 'bag', 'bag', 'csv']
    from_bag, from_csv = read_records([str(tmp_path / 'bag'), str(tmp_path / 'r.csv')])
    for name in ('time_s', 'voltage', 'current', 'speed'):
        np.testing.assert_array_equal(getattr(from_csv, name), getattr(from_bag, name))


INTERFACE_VALUE_MSG = 'string[] interface_names\nfloat64[] values\n'
DYNAMIC_JOINT_STATE_MSG = ('std_msgs/Header header\nstring[] joint_names\n'
                           'control_msgs/InterfaceValue[] interface_values\n')


def write_dynamic_joint_states(path, stamps_ns, joints, floats=None, latency_ns=0):
    """
    Write /dynamic_joint_states with a control_msgs definition registered for writing.

    ``floats``: topic -> values written as Float64 beside, logged with a jitter of up to
    0.1 ms; the joint states are logged ``latency_ns`` after their header stamps.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, get_types_from_msg, Stores

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(INTERFACE_VALUE_MSG, 'control_msgs/msg/InterfaceValue'))
    store.register(get_types_from_msg(DYNAMIC_JOINT_STATE_MSG,
                                      'control_msgs/msg/DynamicJointState'))
    types = store.types
    writer = Writer(str(path), version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    connection = writer.add_connection('/dynamic_joint_states',
                                       'control_msgs/msg/DynamicJointState', typestore=store)
    float_connections = {topic: writer.add_connection(topic, 'std_msgs/msg/Float64',
                                                      typestore=store)
                         for topic in (floats or {})}
    rng = np.random.default_rng(2)
    for row, stamp in enumerate(stamps_ns):
        values = [types['control_msgs/msg/InterfaceValue'](
            interface_names=list(channels), values=np.array([channels[n][row] for n in channels]))
            for channels in joints.values()]
        header = types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=int(stamp // 10**9),
                                                       nanosec=int(stamp % 10**9)),
            frame_id='')
        message = types['control_msgs/msg/DynamicJointState'](
            header=header, joint_names=list(joints), interface_values=values)
        writer.write(connection, int(stamp) + latency_ns,
                     store.serialize_cdr(message, 'control_msgs/msg/DynamicJointState'))
        for topic, values in (floats or {}).items():
            writer.write(float_connections[topic], int(stamp) + int(rng.integers(0, 100_000)),
                         store.serialize_cdr(types['std_msgs/msg/Float64'](data=values[row]),
                                             'std_msgs/msg/Float64'))
    writer.close()


def test_dynamic_joint_states_with_the_bags_own_definitions(tmp_path):
    from dcmotor_id.formats import read_record
    from dcmotor_id.formats.mapping import ReadOptions

    n = 300
    stamps = 5 * 10**9 + np.arange(n, dtype=np.int64) * 1_000_000
    t = np.arange(n) * 1e-3
    wheel = {'m0_voltage': 10 * np.sin(t * 7), 'effort': np.cos(t * 7),
             'velocity': 60 * np.sin(t * 7 - 0.3), 'position': np.cumsum(np.sin(t))}
    other = {'velocity': np.zeros(n)}
    bag = tmp_path / 'djs'
    write_dynamic_joint_states(bag, stamps, {'arm': other, 'wheel': wheel})
    options = ReadOptions(joint='wheel', interfaces={'voltage': 'm0_voltage',
                                                     'current': 'effort'},
                          speed_unit='rpm')
    record = read_record(str(bag), options=options)
    np.testing.assert_allclose(record.time_s, t, atol=1e-12)
    np.testing.assert_array_equal(record.voltage, wheel['m0_voltage'])
    np.testing.assert_array_equal(record.current, wheel['effort'])
    np.testing.assert_allclose(record.speed, wheel['velocity'] * 2 * np.pi / 60)
    with pytest.raises(InputDataError, match='joints arm, wheel'):
        read_record(str(bag), options=ReadOptions(interfaces={'current': 'effort'}))
    with pytest.raises(InputDataError, match="no interface 'amps'"):
        read_record(str(bag), options=ReadOptions(joint='wheel',
                                                  interfaces={'current': 'amps'}))


def test_dynamic_joint_states_with_a_float64_voltage_identify_the_motor(tmp_path, capsys):
    """Current and velocity as interfaces, the voltage command logged as Float64 beside."""
    from dcmotor_id.formats import read_record

    stamps, channels = motor_samples(8.0)
    bag = tmp_path / 'robot'
    write_dynamic_joint_states(bag, stamps, {'wheel': {'current': channels['current'],
                                                       'velocity': channels['speed']}},
                               floats={'/voltage': channels['voltage']}, latency_ns=300_000)
    record = read_record(str(bag))
    assert len(record) == stamps.size
    for name, values in channels.items():
        np.testing.assert_array_equal(getattr(record, name), values)
    out = tmp_path / 'result.json'
    code = cli_main(['identify', str(bag), '--no-discover', '--quiet', '--json', str(out)])
    assert code == 0, capsys.readouterr().err
    truth = PAPER_MOTORS['paper2'].as_dict()
    assert json.loads(out.read_text())['parameters'] == pytest.approx(truth, rel=0.02)


def test_dynamic_joint_states_missing_channel_names_it_and_the_options(tmp_path, capsys):
    from dcmotor_id.formats import read_record
    from dcmotor_id.formats.mapping import ReadOptions

    stamps, channels = motor_samples(0.5)
    bag = tmp_path / 'robot'
    write_dynamic_joint_states(bag, stamps, {'wheel': {'voltage': channels['voltage'],
                                                       'velocity': channels['speed']}},
                               floats={'/drive/i': channels['current']})
    with pytest.raises(InputDataError, match=r"no current: joint 'wheel' in "
                                             r"/dynamic_joint_states has no 'current' interface "
                                             r'\(it has voltage, velocity\).*--interface '
                                             r'current=NAME.*--current-topic'):
        read_record(str(bag))
    assert cli_main(['identify', str(bag), '--no-discover', '--quiet']) == 2
    assert '/drive/i [std_msgs/msg/Float64]' in capsys.readouterr().err
    # following the advice: the current from its topic, the rest from the joint
    record = read_record(str(bag), topics={'current': '/drive/i'})
    np.testing.assert_array_equal(record.current, channels['current'])
    np.testing.assert_array_equal(record.voltage, channels['voltage'])
    with pytest.raises(InputDataError, match=r"joint 'wheel' has no interface 'rate' for the "
                                             r'speed; it has voltage, velocity'):
        read_record(str(bag), options=ReadOptions(interfaces={'speed': 'rate'}))
    still = tmp_path / 'still'
    write_dynamic_joint_states(still, stamps, {'wheel': {'current': channels['current'],
                                                         'position': channels['speed']}})
    with pytest.raises(InputDataError, match=r"no speed: .*no 'velocity' interface.*"
                                             r'--speed-topic'):
        read_record(str(still))
