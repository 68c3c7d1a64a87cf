"""The stream aligner: lost, late, duplicated and reordered samples land where they belong."""

import numpy as np
import pytest

from dcmotor_id.core.errors import InputDataError
from dcmotor_id.formats.streams import (align_timestamps, contiguous_runs, grid_indices,
                                        SampleInbox, StreamAligner)

CHANNELS = ('voltage', 'current', 'speed')


def values_of(index):
    """Distinct values per channel so that a misplaced one is seen."""
    index = np.asarray(index, dtype=float)
    return {'voltage': index, 'current': 1000.0 + index, 'speed': -index}


def drain(aligner):
    aligner.flush()
    return aligner.pop_ready()


def feed(aligner, blocks, chunk=20):
    """Feed per-channel ``(indices, values)`` interleaved in chunks, as the node does."""
    longest = max(indices.size for indices, _ in blocks.values())
    for start in range(0, longest, chunk):
        for name, (indices, values) in blocks.items():
            aligner.add_block(name, indices[start:start + chunk], values[start:start + chunk])


def check_placed(indices, values):
    expected = values_of(indices)
    for column, name in enumerate(CHANNELS):
        np.testing.assert_array_equal(values[:, column], expected[name])


def test_in_order_streams_come_out_complete():
    aligner = StreamAligner(CHANNELS, max_delay_samples=10)
    truth = values_of(np.arange(500))
    for k in range(500):
        for name in CHANNELS:
            aligner.add(name, k, truth[name][k])
    indices, values = drain(aligner)
    np.testing.assert_array_equal(indices, np.arange(500))
    check_placed(indices, values)
    assert aligner.stats.lost == 0 and aligner.stats.emitted == 500


def test_reordered_and_duplicated_values_are_placed_exactly():
    rng = np.random.default_rng(3)
    aligner = StreamAligner(CHANNELS, max_delay_samples=50)
    order = np.arange(2000)
    truth = values_of(order)
    blocks = {}
    for name in CHANNELS:
        # local shuffles within blocks of 20 (reordering inside the delay horizon)
        shuffled = np.concatenate([rng.permutation(order[i:i + 20])
                                   for i in range(0, order.size, 20)])
        duplicated = np.insert(shuffled, np.arange(0, order.size, 97), order[::97])
        blocks[name] = (duplicated, truth[name][duplicated])
    feed(aligner, blocks)
    indices, values = drain(aligner)
    np.testing.assert_array_equal(indices, order)
    check_placed(indices, values)
    assert aligner.stats.reordered > 0
    # a copy arriving after its sample went out is late rather than a duplicate
    assert aligner.stats.duplicates + aligner.stats.late == 3 * order[::97].size
    assert aligner.stats.lost == 0


def test_lost_messages_leave_gaps_and_are_counted():
    aligner = StreamAligner(CHANNELS, max_delay_samples=5)
    order = np.arange(300)
    truth = values_of(order)
    dropped = {'voltage': [10, 11], 'current': [150], 'speed': []}
    blocks = {}
    for name in CHANNELS:
        keep = np.setdiff1d(order, dropped[name])
        blocks[name] = (keep, truth[name][keep])
    feed(aligner, blocks)
    indices, values = drain(aligner)
    np.testing.assert_array_equal(indices, np.setdiff1d(order, [10, 11, 150]))
    check_placed(indices, values)
    assert aligner.stats.lost == 3
    runs = contiguous_runs(indices)
    assert [(r.start, r.stop) for r in runs] == [(0, 10), (10, 148), (148, 297)]


def test_value_after_its_sample_was_given_up_is_late():
    aligner = StreamAligner(CHANNELS, max_delay_samples=5)
    truth = values_of(np.arange(100))
    feed(aligner, {'voltage': (np.arange(100), truth['voltage']),
                   'current': (np.arange(100), truth['current']),
                   'speed': (np.arange(1, 100), truth['speed'][1:])})
    aligner.add('speed', 0, truth['speed'][0])  # sample 0 expired long ago
    indices, _ = drain(aligner)
    assert indices[0] == 1
    assert aligner.stats.late == 1


def test_nan_payloads_are_refused_and_their_samples_lost():
    aligner = StreamAligner(CHANNELS, max_delay_samples=5)
    truth = values_of(np.arange(50))
    bad = truth['current'].copy()
    bad[20] = np.nan
    bad[21] = np.inf
    feed(aligner, {'voltage': (np.arange(50), truth['voltage']),
                   'current': (np.arange(50), bad), 'speed': (np.arange(50), truth['speed'])})
    indices, values = drain(aligner)
    assert 20 not in indices and 21 not in indices
    assert np.all(np.isfinite(values))
    assert aligner.stats.invalid == 2 and aligner.stats.lost == 2


def test_a_jump_beyond_the_ring_counts_the_skipped_samples_as_lost():
    aligner = StreamAligner(CHANNELS, max_delay_samples=10, capacity=64)
    truth = values_of(np.arange(1000))
    feed(aligner, {name: (np.arange(20), truth[name][:20]) for name in CHANNELS})
    feed(aligner, {name: (np.arange(900, 1000), truth[name][900:]) for name in CHANNELS})
    indices, values = drain(aligner)
    np.testing.assert_array_equal(indices, np.concatenate([np.arange(20),
                                                           np.arange(900, 1000)]))
    check_placed(indices, values)
    assert aligner.stats.lost == 880


def test_channels_connecting_late_are_not_counted_as_lost():
    aligner = StreamAligner(CHANNELS, max_delay_samples=5)
    truth = values_of(np.arange(200))
    # the first values of current and speed were published before they were connected
    feed(aligner, {'voltage': (np.arange(200), truth['voltage']),
                   'current': (np.arange(30, 230), np.append(truth['current'][30:],
                                                             np.full(30, np.nan))),
                   'speed': (np.arange(40, 240), np.append(truth['speed'][40:],
                                                           np.full(40, np.nan)))})
    indices, _ = drain(aligner)
    np.testing.assert_array_equal(indices, np.arange(40, 200))
    assert aligner.stats.lost == 0 and aligner.stats.unmatched_at_start == 40


def test_a_restarted_source_is_followed():
    aligner = StreamAligner(CHANNELS, max_delay_samples=5, capacity=32)
    truth = values_of(np.arange(200))
    feed(aligner, {name: (np.arange(100, 200), truth[name][100:]) for name in CHANNELS}, 10)
    first, _ = aligner.pop_ready()
    feed(aligner, {name: (np.arange(0, 50), truth[name][:50]) for name in CHANNELS}, 10)
    indices, values = drain(aligner)
    assert aligner.stats.restarts == 1
    np.testing.assert_array_equal(indices[-50:], np.arange(50))
    check_placed(indices[-50:], values[-50:])


def test_align_timestamps_snaps_jittered_stamps_onto_the_grid():
    rng = np.random.default_rng(1)
    period_ns = 1_000_000
    grid = 1_700_000_000_000_000_000 + np.arange(1000) * period_ns
    truth = values_of(np.arange(1000))
    stamps, values = {}, {}
    for name in CHANNELS:
        keep = np.setdiff1d(np.arange(1000), [500]) if name == 'speed' else np.arange(1000)
        order = rng.permutation(keep)
        stamps[name] = grid[order] + rng.integers(-200_000, 200_000, order.size)
        values[name] = truth[name][order]
    out_stamps, aligned = align_timestamps(stamps, values, sample_period_s=1e-3)
    expected = np.setdiff1d(np.arange(1000), [500])
    np.testing.assert_array_equal(out_stamps - out_stamps[0], expected * period_ns)
    assert abs(out_stamps[0] - grid[0]) < 0.1 * period_ns
    np.testing.assert_array_equal(aligned['current'], truth['current'][expected])
    np.testing.assert_array_equal(aligned['speed'], truth['speed'][expected])


def test_align_timestamps_refuses_stamps_off_any_grid():
    rng = np.random.default_rng(2)
    stamps = np.sort(rng.integers(0, 10 ** 9, 500))
    with pytest.raises(InputDataError, match='not on a uniform grid'):
        align_timestamps({'current': stamps, 'speed': stamps},
                         {'current': np.zeros(500), 'speed': np.zeros(500)},
                         sample_period_s=1e-3, source='x.mcap')


def test_inbox_places_messages_by_sequence_number_or_by_timestamp():
    inbox = SampleInbox(CHANNELS, 1e-3, align_by='sequence')
    aligner = StreamAligner(CHANNELS, max_delay_samples=10)
    for sequence in (3, 1, 2):  # reordered on the way
        for name, value in values_of(sequence - 1).items():
            inbox.put_message(name, float(value), {'publication_sequence_number': sequence,
                                                   'source_timestamp': 123})
    assert set(inbox.last_seen) == set(CHANNELS)
    inbox.drain_into(aligner)
    indices, values = drain(aligner)
    assert indices.tolist() == [0, 1, 2]
    assert values[:, 1].tolist() == [1000.0, 1001.0, 1002.0]
    # by timestamp: on the grid that starts at the first stamp seen (one origin for all)
    inbox = SampleInbox(CHANNELS, 1e-3, align_by='timestamp')
    inbox.put_message('voltage', 1.0, {'publication_sequence_number': 7,
                                       'source_timestamp': 10_000_000})
    inbox.put_message('speed', 1.0, {'received_timestamp': 12_000_400})
    assert inbox.index_of_stamp(10_499_999) == 0 and inbox.index_of_stamp(13_000_000) == 3
    # a channel placed by timestamp although the others go by sequence number
    inbox = SampleInbox(CHANNELS, 1e-3)
    inbox.put_message('voltage', 1.0, {'publication_sequence_number': 7,
                                       'source_timestamp': 5_000_000}, by_timestamp=True)
    aligner = StreamAligner(CHANNELS, max_delay_samples=10)
    inbox.drain_into(aligner)
    assert aligner.first_index == 0
    assert grid_indices([5_000_000, 7_000_000], 1e-3, 5_000_000).tolist() == [0, 2]


def test_inbox_takes_blocks_by_time_and_drops_nan_times():
    inbox = SampleInbox(('current', 'speed'), 1e-3)
    time_s = np.array([0.0, 1e-3, np.nan, 3e-3])
    inbox.put_times(time_s, {'voltage': np.zeros(4), 'current': np.arange(4.0),
                             'speed': -np.arange(4.0)})
    aligner = StreamAligner(('current', 'speed'), max_delay_samples=10)
    inbox.drain_into(aligner)
    indices, values = drain(aligner)
    assert indices.tolist() == [0, 1, 3]
    assert values.tolist() == [[0.0, -0.0], [1.0, -1.0], [3.0, -3.0]]
    assert set(inbox.last_seen) == {'current', 'speed'}
    inbox.drain_into(aligner)  # nothing new
    assert drain(aligner)[0].size == 0


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('jitter_ns', [100_000, 400_000])
def test_jittered_stamps_keep_their_period_over_thousands_of_samples(seed, jitter_ns):
    """
    Up to 20 % of jitter at 2 ms: the median step is a little off.

    Over 10 000 samples that drifts by periods; the period is refined over doubling spans
    and every sample placed. Joint states share their stamps; the voltage has its own.
    """
    rng = np.random.default_rng(seed)
    count, period_ns = 10_000, 2_000_000
    true = 10 ** 18 + np.arange(count, dtype=np.int64) * period_ns
    joint = true + rng.integers(-jitter_ns, jitter_ns + 1, count)
    stamps = {'voltage': true + rng.integers(-jitter_ns, jitter_ns + 1, count),
              'current': joint, 'speed': joint}
    values = {name: np.arange(count, dtype=float) for name in stamps}
    grid, aligned = align_timestamps(stamps, values, source='robot.mcap')
    assert grid.size == count
    assert np.median(np.diff(grid)) == pytest.approx(period_ns, abs=1)
    assert np.array_equal(aligned['voltage'], aligned['current'])
