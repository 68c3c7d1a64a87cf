"""Low-pass filtering of dcmotor_id.signals."""

import numpy as np

from dcmotor_id.signals import low_pass


def test_short_signals_are_returned_as_they_are():
    values = np.arange(10.0)
    assert np.array_equal(low_pass(values, 0.1), values)
