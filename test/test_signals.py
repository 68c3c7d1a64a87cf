"""The hand-written Butterworth filter of dcmotor_id.signals against scipy.signal."""

import numpy as np
import pytest
from scipy.signal import butter, sosfiltfilt

from dcmotor_id.signals import butter_sos, low_pass


@pytest.mark.parametrize('order', [1, 2, 3, 4, 6])
@pytest.mark.parametrize('fraction', [0.004, 0.02, 0.05, 0.1, 0.3])
def test_design_and_filter_match_scipy(order, fraction):
    reference = butter(order, 2.0 * fraction, output='sos')
    if order % 2 == 0:
        np.testing.assert_allclose(butter_sos(order, 2.0 * fraction), reference, rtol=1e-12,
                                   atol=1e-15)
    rng = np.random.default_rng(order)
    values = np.cumsum(rng.standard_normal(5000)) + np.sin(np.arange(5000) * 0.01)
    expected = sosfiltfilt(reference, values)
    np.testing.assert_allclose(low_pass(values, fraction, order=order), expected,
                               rtol=0, atol=1e-9 * np.max(np.abs(expected)))


def test_short_signals_are_returned_as_they_are():
    values = np.arange(10.0)
    assert np.array_equal(low_pass(values, 0.1), values)
