"""Low-pass filtering of dcmotor_id.signals.filters."""

import numpy as np

from dcmotor_id.signals.filters import low_pass


def test_short_signals_are_returned_as_they_are():
    values = np.arange(10.0)
    assert np.array_equal(low_pass(values, 0.1), values)


def test_sections_and_zero_phase_filter_match_scipy():
    from scipy.signal import butter, sosfiltfilt

    from dcmotor_id.signals.filters import butter_sos, speed_from_position, zero_phase
    rng = np.random.default_rng(3)
    values = np.cumsum(rng.standard_normal(5000)) + rng.standard_normal(5000)
    for order in (2, 4, 6, 8):
        for cutoff in (0.01, 0.05, 0.2, 0.6, 0.95):
            ours = butter_sos(order, cutoff)
            theirs = butter(order, cutoff, output='sos')
            assert np.allclose(ours, theirs, rtol=1e-14, atol=0.0)
            filtered = zero_phase(ours, values)
            expected = sosfiltfilt(theirs, values)
            scale = np.max(np.abs(expected))
            assert np.max(np.abs(filtered - expected)) <= 1e-12 * scale
    assert np.allclose(low_pass(values, 0.1), sosfiltfilt(butter(4, 0.2, output='sos'), values),
                       rtol=0.0, atol=1e-12 * np.max(np.abs(values)))
    position = np.cumsum(np.sin(np.linspace(0.0, 20.0, 3000))) * 1e-3
    expected = np.gradient(sosfiltfilt(butter(4, 100.0, fs=1000.0, output='sos'), position),
                           1e-3)
    assert np.allclose(speed_from_position(position, 1e-3), expected, rtol=0.0,
                       atol=1e-12 * np.max(np.abs(expected)))


def test_odd_orders_fall_back_to_scipy():
    from scipy.signal import butter

    from dcmotor_id.signals.filters import butter_sos
    assert np.array_equal(butter_sos(3, 0.2), butter(3, 0.2, output='sos'))


def test_a_record_measures_each_channels_noise_once(monkeypatch):
    # Record.noise_std / noise_level equal the functions on the channel, measured on first
    # use and kept (issue 29, speed); a replaced record measures its own.
    from dcmotor_id.core import noise as core_noise
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.error_model.criterion import noise_level
    from dcmotor_id.signals.filters import noise_std

    rng = np.random.default_rng(3)
    t = np.arange(2000) * 1e-3
    speed = np.sin(2 * np.pi * t) + 0.01 * rng.standard_normal(t.size)
    current = np.round(np.cos(2 * np.pi * t) / 0.05) * 0.05
    record = Record(t, current, np.ones_like(t), speed)
    expected = [noise_std(speed), noise_level(speed), noise_level(current), noise_std(current),
                noise_std(2.0 * speed)]
    assert expected[2] > expected[3]  # quantised: the floor decides
    calls = []
    std = core_noise.noise_std
    monkeypatch.setattr(core_noise, 'noise_std', lambda values: calls.append(1) or std(values))
    assert [record.noise_std('speed'), record.noise_level('speed'),
            record.noise_level('current'), record.noise_std('current')] == expected[:4]
    assert record.noise_std('speed') == expected[0]
    assert len(calls) == 2
    other = record.replace(speed=2.0 * speed)
    assert other.noise_std('speed') == expected[4]
    assert len(calls) == 3


def test_a_speed_from_the_position_needs_the_flag_and_two_positions():
    # Record.speed_from_position: the one predicate of the ramp check's sample speed and the
    # speed's error over the sample periods (they wrote it each).
    from dcmotor_id.core.records import Record

    t = np.arange(3) * 1e-3
    ones = np.ones_like(t)
    assert Record(t, ones, ones, ones, ones, speed_derived=True).speed_from_position
    assert not Record(t, ones, ones, ones, ones).speed_from_position
    assert not Record(t, ones, ones, ones, None, speed_derived=True).speed_from_position
    assert not Record(t[:1], ones[:1], ones[:1], ones[:1], ones[:1],
                      speed_derived=True).speed_from_position


def test_low_pass_designs_each_cut_off_once(monkeypatch):
    # identify low-passes about thirty signals at five cut-offs: each design (sections and
    # their step states) is made once, the filtered signals as before (issue 29, speed).
    from dcmotor_id.signals import filters

    filters._design.cache_clear()
    design = filters.butter_sos
    calls = []

    def counted(order, cutoff):
        calls.append((order, cutoff))
        return design(order, cutoff)

    monkeypatch.setattr(filters, 'butter_sos', counted)
    values = np.cumsum(np.random.default_rng(5).standard_normal(3000))
    first = low_pass(values, 0.1)
    assert np.array_equal(first, filters.zero_phase(design(4, 0.2), values))
    assert np.array_equal(low_pass(values, 0.1), first)
    assert np.array_equal(low_pass(values, 0.05, order=2),
                          filters.zero_phase(design(2, 0.1), values))
    assert calls == [(4, 0.2), (2, 0.1)]
    filters._design.cache_clear()


def test_an_angle_wrapped_at_a_turn_is_unwrapped_and_counted():
    from dcmotor_id.signals.filters import unwrap_turns
    angle = np.cumsum(np.full(500, 0.3)) + 0.5 * np.sin(np.arange(500) / 20.0)
    for wrapped in ((angle + np.pi) % (2 * np.pi) - np.pi, angle % (2 * np.pi)):
        unwrapped, wraps = unwrap_turns(wrapped)
        assert wraps > 10
        assert np.allclose(unwrapped - unwrapped[0], angle - angle[0])


def test_an_angle_without_wraps_or_with_jumps_of_no_whole_turn_is_kept():
    from dcmotor_id.signals.filters import unwrap_turns
    angle = np.linspace(0.0, 3.0, 300)
    assert unwrap_turns(angle)[1] == 0
    jumped = angle.copy()
    jumped[150:] += 4.0  # a jump of 4 rad is no wrap: left to the checks
    kept, wraps = unwrap_turns(jumped)
    assert wraps == 0 and np.array_equal(kept, jumped)
    fast = np.cumsum(np.full(300, 3.5))  # a multi-turn encoder at 3.5 rad a sample
    assert unwrap_turns(fast)[1] == 0 and unwrap_turns(-fast)[1] == 0
    with_nan = angle % 1.0 * 7.0
    with_nan[10] = np.nan
    assert unwrap_turns(with_nan)[1] == 0
