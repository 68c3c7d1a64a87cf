"""Placing real publishers' messages on the identification grid (no ROS graph)."""

import numpy as np
import pytest

from dcmotor_id.formats.batch import BATCH_LABEL, decode_batch
from dcmotor_id.formats.regrid import StampRegridder
from dcmotor_id.formats.streams import SampleInbox, StreamAligner
from dcmotor_id.simulation.drive_publisher import drive_messages

CHANNELS = ('voltage', 'current', 'speed')
SOURCES = {'joint_states': ('current', 'speed'), 'voltage': ('voltage',)}


def record(count, seed=1):
    """Return a PRBS-like voltage held over 4 samples (repeated values), distinct currents."""
    rng = np.random.default_rng(seed)
    voltage = np.repeat(rng.choice([-10.0, 10.0], count // 4 + 1), 4)[:count]
    return voltage, rng.normal(size=count), rng.normal(size=count)


def align(messages, rate_hz, sources=SOURCES, drain_every_s=0.02, channels=CHANNELS):
    """Feed the messages as a node does (drained at its processing rate); return the output."""
    regridder = StampRegridder(1.0 / rate_hz)
    for name, names in sources.items():
        regridder.add_source(name, names)
    inbox = SampleInbox(channels, 1.0 / rate_hz)
    aligner = StreamAligner(channels, int(0.5 * rate_hz))
    due = messages[0].publish_ns + drain_every_s * 1e9
    pieces = []
    for message in messages:
        if message.publish_ns > due:
            regridder.drain_into(inbox)
            inbox.drain_into(aligner)
            pieces.append(aligner.pop_ready())
            due += drain_every_s * 1e9
        regridder.put(message.topic, message.stamp_ns, message.sequence, message.values)
    regridder.drain_into(inbox)
    inbox.drain_into(aligner)
    aligner.flush()
    pieces.append(aligner.pop_ready())
    indices = np.concatenate([piece[0] for piece in pieces])
    values = np.vstack([piece[1] for piece in pieces])
    return indices, values, regridder, aligner


def assert_exact(indices, values, truth, minimum_used=0.99):
    """At least ``minimum_used`` of the samples out, each paired exactly with its truth."""
    voltage, current, speed = truth
    order = np.argsort(current)
    sample = order[np.searchsorted(current[order], values[:, 1])]
    assert np.array_equal(current[sample], values[:, 1])
    assert np.array_equal(voltage[sample], values[:, 0]), 'voltage paired with the wrong sample'
    assert np.array_equal(speed[sample], values[:, 2])
    assert np.unique(indices - sample).size == 1, 'the grid index does not follow the sample'
    assert indices.size >= minimum_used * current.size


MODES = {
    'grid stamps, 20 % jitter': {'stamps': 'grid', 'jitter': 0.2},
    'now() stamps': {'stamps': 'now'},
    'now() stamps, 50 ms bursts': {'stamps': 'now', 'burst_s': 0.05},
    'grid stamps with jitter, bursts': {'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05},
    'voltage without header beside stamped joint states': {
        'stamps': 'grid', 'jitter': 0.1, 'burst_s': 0.05, 'voltage_stamp': 'publish'},
    'voltage at twice the rate, now() bursts': {'stamps': 'now', 'burst_s': 0.05,
                                                'voltage_rate': 2},
    'voltage at twice the rate without header': {
        'stamps': 'grid', 'jitter': 0.2, 'burst_s': 0.05, 'voltage_rate': 2,
        'voltage_stamp': 'publish'},
}


@pytest.mark.parametrize('rate_hz', [500.0, 1000.0])
@pytest.mark.parametrize('mode', sorted(MODES))
def test_joint_states_and_voltage_of_real_publishers_are_paired_exactly(mode, rate_hz):
    truth = record(int(4 * rate_hz))
    messages = drive_messages(*truth, rate_hz, seed=3, **MODES[mode])
    indices, values, regridder, aligner = align(messages, rate_hz)
    assert_exact(indices, values, truth)
    assert aligner.stats.duplicates == 0 and aligner.stats.lost == 0
    stats = regridder.stats
    assert stats['joint_states'].snapped and stats['voltage'].snapped
    assert stats['voltage'].ratio == MODES[mode].get('voltage_rate', 1)
    assert stats['joint_states'].bursty == ('burst_s' in MODES[mode] and
                                            MODES[mode]['stamps'] == 'now')


@pytest.mark.parametrize('mode', ['now() stamps, 50 ms bursts', 'grid stamps, 20 % jitter'])
def test_float64_topics_by_timestamp_are_paired_exactly(mode):
    """The float64 input by timestamp: three sources of one channel each."""
    rate_hz = 1000.0
    truth = record(3000)
    messages = []
    for message in drive_messages(*truth, rate_hz, seed=5, **MODES[mode]):
        if message.topic == 'voltage':
            messages.append(message)
        else:  # current and speed on topics of their own, stamped alike
            messages.append(message._replace(topic='current', values=message.values[:1]))
            messages.append(message._replace(topic='speed', values=message.values[1:]))
    sources = {'voltage': ('voltage',), 'current': ('current',), 'speed': ('speed',)}
    indices, values, _, _ = align(messages, rate_hz, sources)
    assert_exact(indices, values, truth)


def test_a_repeated_value_is_a_sample_and_a_repeated_sequence_number_a_duplicate():
    regridder = StampRegridder(1e-3, settle_s=0.5)
    regridder.add_source('voltage', ('voltage',))
    inbox = SampleInbox(('voltage',), 1e-3)
    for number in range(1, 1001):
        regridder.put('voltage', 10 ** 9 + number * 10 ** 6, number, (5.0,))  # one value
    regridder.put('voltage', 10 ** 9 + 1000 * 10 ** 6, 1000, (5.0,))  # the last one again
    regridder.drain_into(inbox)
    aligner = StreamAligner(('voltage',), 10)
    inbox.drain_into(aligner)
    aligner.flush()
    indices, values = aligner.pop_ready()
    assert indices.size == 1000 and np.all(values == 5.0)
    stats = regridder.stats['voltage']
    assert stats.duplicates == 1 and stats.on_grid == 1000 and stats.lost == 0


def test_without_sequence_numbers_a_repeated_stamp_is_the_duplicate():
    regridder = StampRegridder(1e-3, settle_s=0.5)
    regridder.add_source('voltage', ('voltage',))
    for number in range(1, 601):
        regridder.put('voltage', number * 10 ** 6, None, (1.0,))
        if number == 300:
            regridder.put('voltage', number * 10 ** 6, None, (1.0,))
    inbox = SampleInbox(('voltage',), 1e-3)
    regridder.drain_into(inbox)
    assert regridder.stats['voltage'].duplicates == 1
    assert regridder.stats['voltage'].on_grid == 600


def test_lost_messages_are_counted_and_leave_a_gap_not_a_shifted_pairing():
    rate_hz = 500.0
    truth = record(2000)
    messages = drive_messages(*truth, rate_hz, stamps='now', burst_s=0.05, seed=2)
    lost = {('joint_states', 700), ('joint_states', 701), ('voltage', 1500)}
    kept = [message for message in messages if (message.topic, message.sequence) not in lost]
    indices, values, regridder, aligner = align(kept, rate_hz)
    assert_exact(indices, values, truth, minimum_used=0.998)
    assert indices.size == 2000 - 3
    assert regridder.stats['joint_states'].lost == 2 and regridder.stats['voltage'].lost == 1
    assert aligner.stats.lost == 3


def test_a_source_between_the_grid_instants_is_resampled():
    """Speed measured half a period after the current: interpolated onto the grid."""
    regridder = StampRegridder(1e-3, hold_channels=('voltage',), settle_s=0.5)
    regridder.add_source('current', ('current',))
    regridder.add_source('speed', ('speed',))
    inbox = SampleInbox(('current', 'speed'), 1e-3)
    for number in range(1, 1001):
        regridder.put('current', number * 10 ** 6, number, (float(number),))
        regridder.put('speed', number * 10 ** 6 + 500_000, number, (2.0 * number + 1.0,))
    regridder.drain_into(inbox)
    aligner = StreamAligner(('current', 'speed'), 10)
    inbox.drain_into(aligner)
    aligner.flush()
    _, values = aligner.pop_ready()
    # speed = 2 n + 1 at n + 0.5: 2 n at n; interpolated exactly for a line
    np.testing.assert_allclose(values[:, 1], 2.0 * values[:, 0])
    assert values.shape[0] >= 998
    stats = regridder.stats['speed']
    assert not stats.snapped and stats.resampled >= 998 and abs(stats.shift - 0.5) < 0.01


def test_a_held_voltage_at_a_lower_rate_is_a_zero_order_hold():
    """A command at 250 Hz onto a 1 kHz grid: held, never interpolated."""
    regridder = StampRegridder(1e-3, settle_s=0.5)
    regridder.add_source('current', ('current',))
    regridder.add_source('voltage', ('voltage',))
    inbox = SampleInbox(('voltage', 'current'), 1e-3)
    for number in range(1, 2001):
        regridder.put('current', number * 10 ** 6, number, (float(number),))
        if number % 4 == 1:
            regridder.put('voltage', number * 10 ** 6, number // 4 + 1,
                          (float(number // 4 % 2),))
    regridder.drain_into(inbox)
    aligner = StreamAligner(('voltage', 'current'), 10)
    inbox.drain_into(aligner)
    aligner.flush()
    _, values = aligner.pop_ready()
    expected = ((values[:, 1] - 1) // 4) % 2
    assert np.array_equal(values[:, 0], expected)
    assert regridder.stats['voltage'].ratio == 0.25
    assert regridder.stats['voltage'].resampled > 1000


def test_a_restarted_publisher_is_placed_anew():
    regridder = StampRegridder(1e-3, settle_s=0.1)
    regridder.add_source('voltage', ('voltage',))
    inbox = SampleInbox(('voltage',), 1e-3)
    for number in range(1, 501):
        regridder.put('voltage', number * 10 ** 6, number, (1.0,))
    regridder.drain_into(inbox)
    for number in range(1, 501):  # sequence numbers from 1 again, half a second later
        regridder.put('voltage', (1000 + number) * 10 ** 6, number, (2.0,))
    regridder.drain_into(inbox)
    stats = regridder.stats['voltage']
    assert stats.restarts == 1 and stats.on_grid == 1000 and stats.duplicates == 0
    assert any('restarts' in phrase for phrase in regridder.summary())


def test_batches_with_jittered_times_keep_every_sample():
    """The batch input: per-sample times with 20 % jitter still give one index each."""
    rate_hz = 1000.0
    rng = np.random.default_rng(4)
    count = 2000
    time_s = (np.arange(count) + rng.uniform(-0.2, 0.2, count)) / rate_hz
    truth = record(count)
    inbox = SampleInbox(CHANNELS, 1.0 / rate_hz)
    aligner = StreamAligner(CHANNELS, 100)
    for start in range(0, count, 25):  # 25 samples a message
        part = slice(start, start + 25)
        block = decode_batch([BATCH_LABEL, 'samples'], [4, 25], np.concatenate(
            [time_s[part], truth[0][part], truth[1][part], truth[2][part]]))
        inbox.put_times(block[0], dict(zip(CHANNELS, block[1:])))
    inbox.drain_into(aligner)
    aligner.flush()
    indices, values = aligner.pop_ready()
    assert_exact(indices, values, truth, minimum_used=1.0)
    assert aligner.stats.duplicates == 0


def test_a_stream_shorter_than_the_settling_time_is_placed_when_it_stops():
    regridder = StampRegridder(1e-3)
    regridder.add_source('voltage', ('voltage',))
    inbox = SampleInbox(('voltage',), 1e-3)
    for number in range(1, 301):
        regridder.put('voltage', number * 10 ** 6, number, (1.0,))
    regridder.drain_into(inbox)
    assert regridder.stats['voltage'].on_grid == 0  # waits for a second of stamps
    assert 'not placed yet' in regridder.summary()[0]
    regridder.drain_into(inbox, force=True)
    assert regridder.stats['voltage'].on_grid == 300


def test_a_stalled_publisher_does_not_bend_the_rate_or_the_offset():
    """A voltage publisher that stalls 150 ms once at the start, then catches up at once."""
    rate_hz = 1000.0
    truth = record(3000)
    messages = drive_messages(*truth, rate_hz, stamps='grid', jitter=0.1, burst_s=0.01,
                              voltage_stamp='publish', seed=4)
    resume = next(message.publish_ns for message in messages
                  if message.topic == 'voltage' and message.sequence == 350)
    messages = [message._replace(publish_ns=resume - (350 - message.sequence) * 1000,
                                 stamp_ns=resume - (350 - message.sequence) * 1000)
                if message.topic == 'voltage' and 200 <= message.sequence < 350 else message
                for message in messages]
    messages.sort(key=lambda message: message.publish_ns)
    indices, values, regridder, _ = align(messages, rate_hz)
    assert_exact(indices, values, truth)
    assert regridder.stats['voltage'].ratio == 1.0


def test_a_source_on_another_clock_is_not_paired_and_is_said():
    """A voltage stamped by DDS (now) beside joint states replayed with old header stamps."""
    regridder = StampRegridder(1e-3, settle_s=0.5)
    regridder.add_source('joint_states', ('current', 'speed'))
    regridder.add_source('voltage', ('voltage',))
    inbox = SampleInbox(CHANNELS, 1e-3)
    for number in range(1, 601):
        regridder.put('joint_states', 10 ** 12 + number * 10 ** 6, number, (1.0, 2.0))
    regridder.drain_into(inbox)
    for number in range(1, 601):
        regridder.put('voltage', 10 ** 15 + number * 10 ** 6, number, (3.0,))
    regridder.drain_into(inbox)
    stats = regridder.stats['voltage']
    assert stats.on_grid == 0 and stats.other_clock == 600 and stats.clock_gap_s > 900
    assert any('another clock' in phrase for phrase in regridder.summary())
