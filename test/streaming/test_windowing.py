"""Cutting aligned samples into windows: full windows, gaps, short runs, selection (no ROS)."""

import numpy as np
import pytest

from dcmotor_id.formats.streams import contiguous_runs
from dcmotor_id.streaming.windowing import Window, WindowCutter

CHANNELS = ('voltage', 'current', 'speed')
RATE_HZ = 1000.0
ANCHOR_NS = 5_000_000_000


def cutter(window_s=1.0, min_window_s=0.2, min_samples=100):
    return WindowCutter(CHANNELS, RATE_HZ, window_s, min_window_s, min_samples=min_samples,
                        clock_ns=lambda: ANCHOR_NS)


def samples(indices):
    """Values that tell every sample and channel apart."""
    indices = np.asarray(indices, dtype=np.int64)
    return indices, np.column_stack([indices, 1000.0 + indices, -1.0 * indices])


def test_full_windows_hold_window_s_and_are_anchored_at_the_first_sample():
    windows = cutter()
    runs = windows.add(*samples(np.arange(2500)))
    assert [run.after_gap for run in runs] == [False]
    closed = windows.pop_closed()
    assert [window.size for window in closed] == [1000, 1000]
    assert windows.pop_closed() == []
    assert windows.held_samples == 2500
    first, second = closed
    assert first.stamps_ns[0] == ANCHOR_NS and second.number == first.number + 1
    assert np.all(np.diff(first.stamps_ns) == 1_000_000)
    assert first.duration_s == pytest.approx(1.0)
    np.testing.assert_array_equal(second.channels['current'], 1000.0 + np.arange(1000, 2000))
    assert first.source == f'window {first.number}'
    first.path = '/bags/w1'
    assert first.source == '/bags/w1'


def test_a_lost_sample_ends_the_window_and_marks_the_next_run():
    windows = cutter()
    indices = np.concatenate([np.arange(0, 400), np.arange(401, 900)])
    runs = windows.add(*samples(indices))
    assert [(run.indices[0], run.after_gap) for run in runs] == [(0, False), (401, True)]
    assert [window.size for window in windows.pop_closed()] == [400]
    # across calls too
    runs = windows.add(*samples(np.arange(950, 1000)))
    assert runs[0].after_gap
    assert [window.size for window in windows.pop_closed()] == [499]


def test_runs_shorter_than_min_window_s_are_dropped_and_counted():
    windows = cutter(min_window_s=0.2)
    assert windows.min_samples == 200
    windows.add(*samples(np.arange(0, 150)))
    windows.add(*samples(np.arange(151, 500)))
    assert [window.size for window in windows.pop_closed()] == []
    assert windows.discarded_samples == 150
    assert windows.close(keep_short=False).size == 349
    assert windows.min_samples == cutter(min_window_s=0.01).min_samples * 2


def test_a_short_window_is_kept_open_when_asked():
    windows = cutter()
    windows.add(*samples(np.arange(50)))
    assert windows.close(keep_short=True) is None
    assert windows.discarded_samples == 0 and windows.held_samples == 50
    windows.add(*samples(np.arange(50, 300)))
    window = windows.close(keep_short=True)
    assert window.size == 300 and windows.pop_closed() == [window]


def test_select_takes_the_newest_windows_until_window_s():
    windows = cutter(window_s=1.0, min_window_s=0.1, min_samples=100)
    windows.add(*samples(np.arange(0, 1000)))        # full window
    windows.add(*samples(np.arange(1001, 1601)))     # 0.6 s, ended by the gap below
    windows.add(*samples(np.arange(1602, 2002)))     # 0.4 s
    windows.close()
    sizes = [window.size for window in windows.windows]
    assert sizes == [1000, 600, 400]
    chosen = windows.select()
    assert [window.size for window in chosen] == [600, 400]
    windows.add(*samples(np.arange(2003, 2100)))     # too short to count
    windows.close()
    assert [window.size for window in windows.select()] == [600, 400]
    assert windows.discarded_samples == 97
    assert chosen[-1] is windows.windows[-1]


def test_memory_holds_the_last_three_window_s():
    windows = cutter(window_s=1.0)
    windows.add(*samples(np.arange(10_000)))
    assert len(windows.windows) == 3
    assert windows.windows[-1].stamps_ns[-1] == ANCHOR_NS + 9_999 * 1_000_000
    assert len(windows.pop_closed()) == 10


def test_nothing_happens_without_samples():
    windows = cutter()
    assert windows.add(*samples([])) == []
    assert windows.close() is None and windows.select() == []
    assert windows.anchor_ns is None


def test_a_window_of_one_sample_spans_nothing():
    window = Window(np.array([7], dtype=np.int64), {'speed': np.array([1.0])})
    assert window.duration_s == 0.0 and not window.written.is_set()


def test_runs_cover_the_samples_in_order():
    indices = np.array([3, 4, 5, 9, 10, 20])
    windows = cutter()
    runs = windows.add(*samples(indices))
    assert [run.indices.tolist() for run in runs] == \
        [indices[part].tolist() for part in contiguous_runs(indices)]


def test_samples_before_a_simulated_clock_has_time_are_stamped_from_its_first_time():
    # use_sim_time: the node's clock reads 0 until the first /clock message, which may come
    # after the first samples (the replayed bag's windows were stamped from 1970)
    times = [0, 0, ANCHOR_NS]
    windows = WindowCutter(CHANNELS, RATE_HZ, 1.0, 0.2, min_samples=100,
                           clock_ns=lambda: times.pop(0) if len(times) > 1 else times[0])
    windows.add(*samples(np.arange(300)))
    windows.add(*samples(np.arange(300, 600)))   # the clock still has no time
    windows.add(*samples(np.arange(600, 1200)))  # it has: samples 600.. arrived now
    assert windows.anchor_ns == ANCHOR_NS - 600 * 1_000_000
    first = windows.pop_closed()[0]
    assert first.stamps_ns[600] == ANCHOR_NS and windows.restarts == 0
