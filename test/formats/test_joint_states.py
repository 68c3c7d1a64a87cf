"""Bags of ros2_control robots with sensor_msgs/msg/JointState: reading, identifying, errors."""

import json

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from support import motor_samples, START_NS

from dcmotor_id.cli.main import main as cli_main
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.formats import read_record
from dcmotor_id.formats.mapping import ReadOptions

PERIOD_NS = 1_000_000
TRUTH = PAPER_MOTORS['paper2']


def simulated(duration_s=8.0, seed=0):
    """Return a noisy simulated record of paper2 (SI) and its sample stamps [ns]."""
    stamps, channels = motor_samples(duration_s, PERIOD_NS * 1e-9, seed=seed)
    channels['position'] = np.cumsum(channels['speed']) * PERIOD_NS * 1e-9
    return stamps, channels


def write_joint_state_bag(path, stamps, joints, floats=None, latency_ns=300_000, seed=1,
                          header=True, clock_offset_ns=0):
    """
    Write /joint_states (one message a sample) and optional Float64 topics, as a robot does.

    ``joints``: name -> {field: values} (an absent field is an empty array); ``floats``:
    topic -> values. Messages are logged with a latency and a jitter after their header stamp;
    the header stamps are ``clock_offset_ns`` off the bag's clock (0: the same clock).
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    types = store.types
    rng = np.random.default_rng(seed)
    writer = Writer(str(path), version=9, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    state = writer.add_connection('/joint_states', 'sensor_msgs/msg/JointState',
                                  typestore=store)
    float_connections = {topic: writer.add_connection(topic, 'std_msgs/msg/Float64',
                                                      typestore=store)
                         for topic in (floats or {})}
    empty = np.zeros(0)
    for row, stamp in enumerate(stamps.tolist()):
        jitter = int(rng.integers(0, PERIOD_NS // 10))
        own = stamp + clock_offset_ns
        stamp_header = types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=own // 10**9 if header else 0,
                                                       nanosec=own % 10**9 if header else 0),
            frame_id='')
        fields = {name: np.array([joint[name][row] if name in joint else np.nan
                                  for joint in joints.values()])
                  for name in ('position', 'velocity', 'effort')}
        for name in fields:
            if not any(name in joint for joint in joints.values()):
                fields[name] = empty
        message = types['sensor_msgs/msg/JointState'](header=stamp_header, name=list(joints),
                                                      **fields)
        writer.write(state, stamp + latency_ns + jitter,
                     store.serialize_cdr(message, 'sensor_msgs/msg/JointState'))
        for topic, values in (floats or {}).items():
            writer.write(float_connections[topic], stamp + int(rng.integers(0, PERIOD_NS // 10)),
                         store.serialize_cdr(types['std_msgs/msg/Float64'](data=values[row]),
                                             'std_msgs/msg/Float64'))
    writer.close()


def identify_cli(arguments, tmp_path, capsys):
    out = tmp_path / 'result.json'
    code = cli_main(['identify', *arguments, '--no-discover', '--quiet', '--json', str(out)])
    assert code == 0, capsys.readouterr().err
    return json.loads(out.read_text())


def test_float64_voltage_and_current_with_joint_states_speed(tmp_path, capsys):
    """The common robot bag: drive topics for voltage and current, the joint's velocity."""
    stamps, channels = simulated()
    bag = tmp_path / 'robot'
    write_joint_state_bag(bag, stamps, {'wheel': {'velocity': channels['speed'],
                                                  'position': channels['position']}},
                          floats={'/voltage': channels['voltage'],
                                  '/current': channels['current']})
    record = read_record(str(bag))
    assert len(record) == stamps.size
    np.testing.assert_array_equal(record.voltage, channels['voltage'])
    np.testing.assert_array_equal(record.current, channels['current'])
    np.testing.assert_array_equal(record.speed, channels['speed'])
    np.testing.assert_array_equal(record.position, channels['position'])
    result = identify_cli([str(bag)], tmp_path, capsys)
    assert result['parameters'] == pytest.approx(TRUTH.as_dict(), rel=0.02)


def test_joint_states_effort_as_current_in_its_units_among_several_joints(tmp_path, capsys):
    """Current from effort (mA), speed in rpm, behind a 5:1 gear, the joint chosen by name."""
    stamps, channels = simulated(seed=3)
    gear = 5.0
    wheel = {'velocity': channels['speed'] * 60 / (2 * np.pi) / gear,
             'effort': channels['current'] * 1e3, 'position': channels['position'] / gear}
    arm = {name: np.zeros(stamps.size) for name in wheel}
    bag = tmp_path / 'robot.mcap'
    write_joint_state_bag(tmp_path / 'robot', stamps, {'arm': arm, 'wheel': wheel},
                          floats={'/drive/voltage': channels['voltage']})
    bag = tmp_path / 'robot' / 'robot.mcap'  # the bare MCAP file reads the same
    options = ['--joint', 'wheel', '--interface', 'current=effort', '--current-unit', 'mA',
               '--speed-unit', 'rpm', '--gear-ratio', str(gear)]
    result = identify_cli([str(bag), *options], tmp_path, capsys)
    assert result['parameters'] == pytest.approx(TRUTH.as_dict(), rel=0.02)
    record = read_record(str(bag), options=ReadOptions(
        joint='wheel', interfaces={'current': 'effort'}, current_unit='mA', speed_unit='rpm',
        gear_ratio=gear))
    np.testing.assert_allclose(record.speed, channels['speed'], rtol=1e-12)
    np.testing.assert_allclose(record.position, channels['position'], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(record.current, channels['current'], rtol=1e-12, atol=1e-15)
    # the model validates on the same bag read the same way (fit near 100 % on its own data)
    model = tmp_path / 'result.json'
    out = tmp_path / 'validation.json'
    code = cli_main(['validate', str(model), str(bag), *options, '--json', str(out)])
    assert code == 0, capsys.readouterr().err
    fit = json.loads(out.read_text())['records'][0]['fit_pct']
    assert fit['current'] > 90 and fit['speed'] > 95


def test_joint_states_alone_with_header_stamps(tmp_path):
    """Every channel from the joint: samples at the header stamps, not the bag's times."""
    stamps, channels = simulated(1.0)
    bag = tmp_path / 'robot'
    write_joint_state_bag(bag, stamps, {'wheel': {'velocity': channels['speed'],
                                                  'effort': channels['current']}},
                          latency_ns=2_000_000)
    record = read_record(str(bag), options=ReadOptions(interfaces={'current': 'effort'}))
    np.testing.assert_allclose(record.time_s, (stamps - stamps[0]) * 1e-9, atol=1e-12)
    np.testing.assert_array_equal(record.current, channels['current'])
    assert record.voltage is None and record.position is None
    unstamped = tmp_path / 'unstamped'  # zero header stamps: the bag's times instead
    write_joint_state_bag(unstamped, stamps, {'wheel': {'velocity': channels['speed'],
                                                        'effort': channels['current']}},
                          latency_ns=0, header=False)
    record = read_record(str(unstamped), options=ReadOptions(interfaces={'current': 'effort'}))
    np.testing.assert_allclose(record.time_s, (stamps - stamps[0]) * 1e-9, atol=1e-4)
    np.testing.assert_array_equal(record.speed, channels['speed'])


def test_header_stamps_on_another_clock_pair_by_the_bags_time(tmp_path):
    stamps, channels = simulated(1.0)
    bag = tmp_path / 'robot'
    write_joint_state_bag(bag, stamps, {'wheel': {'velocity': channels['speed']}},
                          floats={'/voltage': channels['voltage'],
                                  '/current': channels['current']},
                          latency_ns=50_000, clock_offset_ns=-START_NS + 12 * 10**9)
    with pytest.warns(UserWarning, match='another clock'):
        record = read_record(str(bag))
    np.testing.assert_array_equal(record.speed, channels['speed'])


def test_joint_state_errors_name_the_problem_and_the_option(tmp_path):
    stamps, channels = simulated(0.5)
    bag = tmp_path / 'two'
    write_joint_state_bag(bag, stamps, {'arm': {'velocity': channels['speed']},
                                        'wheel': {'velocity': channels['speed']}},
                          floats={'/voltage': channels['voltage'],
                                  '/current': channels['current']})
    with pytest.raises(InputDataError, match='joints arm, wheel; choose one with --joint'):
        read_record(str(bag))
    with pytest.raises(InputDataError, match="joint 'leg' is not in /joint_states; it has arm"):
        read_record(str(bag), options=ReadOptions(joint='leg'))
    with pytest.raises(InputDataError, match='fields are position, velocity, effort'):
        read_record(str(bag), options=ReadOptions(joint='arm', interfaces={'current': 'amps'}))
    with pytest.raises(InputDataError, match='no effort values for the current .* it has '
                                             'velocity'):
        read_record(str(bag), options=ReadOptions(joint='arm',
                                                  interfaces={'current': 'effort'}))
    alone = tmp_path / 'alone'
    write_joint_state_bag(alone, stamps, {'wheel': {'velocity': channels['speed'],
                                                    'effort': channels['current']}},
                          floats={'/voltage': channels['voltage']})
    with pytest.raises(InputDataError, match='no current: .*--interface current=effort'):
        read_record(str(alone))
    still = tmp_path / 'still'
    write_joint_state_bag(still, stamps, {'wheel': {'position': channels['position']}},
                          floats={'/voltage': channels['voltage'],
                                  '/current': channels['current']})
    with pytest.raises(InputDataError, match='no speed: .*--interface speed=FIELD'):
        read_record(str(still))


def test_cli_says_what_to_do_when_the_current_is_missing(tmp_path, capsys):
    stamps, channels = simulated(0.5)
    bag = tmp_path / 'robot'
    write_joint_state_bag(bag, stamps, {'wheel': {'velocity': channels['speed'],
                                                  'effort': channels['current']}},
                          floats={'/voltage': channels['voltage']})
    assert cli_main(['identify', str(bag), '--no-discover', '--quiet']) == 2
    error = capsys.readouterr().err
    assert 'no current' in error and '--interface current=effort' in error
    assert '/joint_states [sensor_msgs/msg/JointState]' in error


def test_jittered_joint_states_at_2_ms_with_a_voltage_topic_are_placed_on_the_grid(tmp_path):
    """Issue 32: two joints, header stamps with 0.1 ms of jitter at 2 ms, a voltage topic."""
    period_ns = 2_000_000
    stamps, channels = motor_samples(10.0, period_ns * 1e-9, seed=4)
    rng = np.random.default_rng(5)
    jittered = stamps + rng.integers(-100_000, 100_001, stamps.size)
    bag = tmp_path / 'robot'
    write_joint_state_bag(bag, jittered, {
        'left': {'velocity': channels['speed'], 'effort': channels['current']},
        'right': {'velocity': -channels['speed'], 'effort': channels['current']}},
        floats={'/voltage': channels['voltage']})
    record = read_record(str(bag), options=ReadOptions(joint='left', interfaces={
        'current': 'effort'}))
    assert len(record) == stamps.size == 5000
    assert np.median(np.diff(record.time_s)) == pytest.approx(2e-3, rel=1e-5)
    np.testing.assert_array_equal(record.voltage, channels['voltage'])
    np.testing.assert_array_equal(record.speed, channels['speed'])


def test_stamps_beyond_the_jitter_placed_on_the_grid_are_refused_naming_sample_period():
    from dcmotor_id.formats.streams import align_timestamps

    rng = np.random.default_rng(6)
    stamps = np.arange(2000) * 2_000_000 + rng.integers(-800_000, 800_001, 2000)
    with pytest.raises(InputDataError, match='--sample-period'):
        align_timestamps({'current': stamps, 'voltage': np.arange(2000) * 2_000_000},
                         {'current': np.zeros(2000), 'voltage': np.zeros(2000)},
                         source='robot.mcap')
