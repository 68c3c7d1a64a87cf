"""The inertia check: a speed that settles within a sample leaves J undetermined."""

import math

import numpy as np
import pytest

from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.inertia import (accelerating_decay, Decay,
                                                      inertia_unresolved)


def _steps(ratio: float, noise: float, seed: int = 0) -> Record:
    """Return a speed stepping up and down, each step settling by ``ratio`` per sample."""
    rng = np.random.default_rng(seed)
    increments = np.zeros(2000)
    for number, start in enumerate(range(50, 2000, 100)):
        increments[start:start + 40] += (-1.0) ** number * 10.0 * ratio ** np.arange(40)
    speed = np.cumsum(increments) + rng.normal(0.0, noise, increments.size)
    return Record(np.arange(speed.size) * 0.01, current=np.zeros(speed.size), speed=speed)


@pytest.mark.parametrize('ratio', [0.0, 0.2, 0.6, 0.9])
def test_the_decay_of_the_speed_increments_is_measured(ratio):
    decay = accelerating_decay([_steps(ratio, 0.05)])
    assert decay is not None and decay.peaks >= 20  # a noise wiggle on a slow tail counts too
    assert decay.ratio == pytest.approx(ratio, abs=3 * decay.ratio_stderr + 0.01)


def test_undetermined_below_the_sample_period_and_only_then():
    # The limit is a time constant of one sample period (ratio 1/e), La's limit too; the half
    # range is that of the slowest decay the peaks allow (the ratio two standard errors up).
    assert inertia_unresolved(Decay(0.2, 0.01, -0.01 / math.log(0.2), 20), 0.01) == \
        pytest.approx(-math.log(0.22) / 2)
    assert inertia_unresolved(Decay(-0.1, 0.01, 0.0, 20), 0.01) == math.inf
    assert inertia_unresolved(Decay(0.5, 0.01, -0.01 / math.log(0.5), 20), 0.01) is None
    # One noise peak cannot decide it: its ratio is loose.
    assert inertia_unresolved(Decay(0.3, 0.2, -0.01 / math.log(0.3), 1), 0.01) is None
    assert inertia_unresolved(None, 0.01) is None


def test_a_step_within_a_sample_is_found_undetermined_and_a_slow_one_not():
    fast, slow = accelerating_decay([_steps(0.0, 0.05)]), accelerating_decay([_steps(0.6, 0.05)])
    assert inertia_unresolved(fast, 0.01) is not None
    assert inertia_unresolved(slow, 0.01) is None


def test_noise_alone_has_no_transients():
    speed = np.random.default_rng(1).normal(0.0, 0.05, 2000)
    record = Record(np.arange(2000) * 0.01, current=np.zeros(2000), speed=speed)
    assert accelerating_decay([record]) is None


def test_a_quantised_speed_at_rest_has_no_transients():
    # An encoder's speed ticking by one count is its resolution, not a transient.
    speed = 0.628 * (np.random.default_rng(2).uniform(size=2000) < 0.01)
    record = Record(np.arange(2000) * 0.01, current=np.zeros(2000), speed=speed)
    assert accelerating_decay([record]) is None


def test_a_speed_derived_from_a_position_is_not_judged():
    record = _steps(0.0, 0.05).replace(speed_derived=True)
    assert accelerating_decay([record]) is None


def test_an_encoders_jitter_up_and_back_is_no_transient():
    # The HSM150 servo's speed at 1 kHz: a quantised level with a few counts' jitter up and
    # back over one or two samples (taken for 10-56 transients settling at once before).
    rng = np.random.default_rng(3)
    speed = np.full(20000, -231.85) + 0.628 * rng.integers(-1, 2, 20000) * (
        rng.uniform(size=20000) < 0.3)
    for start in range(100, 20000, 400):
        speed[start:start + 2] += 0.628 * np.array([-3.0, 4.0])
    record = Record(np.arange(20000) * 1e-3, current=np.zeros(20000), speed=speed)
    assert accelerating_decay([record]) is None
