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
