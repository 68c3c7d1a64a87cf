"""Excitation generators, sensor models and the differentiating filter."""

import numpy as np
import pytest

from dcmotor_id.signals.filters import speed_from_position
from dcmotor_id.simulation.excitation import (add_sensor_noise, EXCITATION_KINDS, make_excitation,
                                              PAPER_SAWTOOTH, PAPER_SINE, quantise, sample_times)


def dominant_frequency(signal, dt):
    """Return the frequency [Hz] of the largest non-DC spectral line."""
    spectrum = np.abs(np.fft.rfft(signal - np.mean(signal)))
    return np.fft.rfftfreq(signal.shape[0], dt)[np.argmax(spectrum)]


def test_sample_times_and_lengths():
    t = sample_times(2.0, 1e-3)
    assert t.shape == (2000,)
    assert t[0] == 0.0 and t[1] == pytest.approx(1e-3)
    for kind in EXCITATION_KINDS:
        t, u = make_excitation(kind, 2.0, 1e-3)
        assert t.shape == u.shape == (2000,)
        assert np.all(np.isfinite(u))
    with pytest.raises(ValueError, match='positive'):
        sample_times(0.0, 1e-3)


def test_paper_sine_and_sawtooth():
    dt = 1e-4
    _, sine = make_excitation('sine', 4.0, dt, amplitude_v=PAPER_SINE['amplitude_v'],
                              frequency_hz=PAPER_SINE['frequency_hz'])
    assert np.max(np.abs(sine)) == pytest.approx(110.0, rel=1e-6)
    assert dominant_frequency(sine, dt) == pytest.approx(0.5)
    assert sine[0] == 0.0
    _, saw = make_excitation('sawtooth', 4.0, dt, amplitude_v=PAPER_SAWTOOTH['amplitude_v'],
                             frequency_hz=PAPER_SAWTOOTH['frequency_hz'])
    assert saw.min() == pytest.approx(-43.0) and saw.max() == pytest.approx(43.0, rel=1e-3)
    # A rising ramp each period: positive slope except at the four resets.
    assert np.sum(np.diff(saw) < 0) == 3
    assert np.diff(saw)[0] == pytest.approx(86.0 * dt, rel=1e-9)


def test_paper_kind_is_sine_then_sawtooth():
    dt = 1e-3
    _, u = make_excitation('paper', 8.0, dt)
    _, sine = make_excitation('sine', 4.0, dt)
    _, saw = make_excitation('sawtooth', 4.0, dt)
    assert np.allclose(u[:4000], sine)
    assert np.allclose(u[4000:], saw)


def test_prbs_is_binary_and_clocked():
    dt = 1e-3
    _, u = make_excitation('prbs', 4.0, dt, amplitude_v=20.0, frequency_hz=50.0)
    assert set(np.unique(u)) == {-20.0, 20.0}
    changes = np.flatnonzero(np.diff(u) != 0) + 1
    # Bits last a whole number of 20-sample clock periods.
    assert np.all(changes % 20 == 0)
    assert abs(np.mean(u)) < 2.0  # a maximum-length sequence is nearly balanced
    _, other = make_excitation('prbs', 4.0, dt, amplitude_v=20.0, frequency_hz=50.0, seed=5)
    assert not np.array_equal(u, other)


def test_chirp_sweeps_and_multisine_peak():
    dt = 1e-3
    t, chirp = make_excitation('chirp', 10.0, dt, amplitude_v=10.0, frequency_hz=1.0,
                               max_frequency_hz=20.0)
    assert np.max(np.abs(chirp)) == pytest.approx(10.0, rel=1e-3)
    assert dominant_frequency(chirp[:2000], dt) < dominant_frequency(chirp[-2000:], dt)
    _, multi = make_excitation('multisine', 10.0, dt, amplitude_v=30.0, frequency_hz=0.5,
                               max_frequency_hz=10.0, offset_v=5.0)
    assert np.max(np.abs(multi - 5.0)) == pytest.approx(30.0)
    with pytest.raises(ValueError, match='unknown excitation'):
        make_excitation('square', 1.0, dt)


def test_sensor_noise_and_quantisation():
    rng = np.random.default_rng(0)
    clean = np.sin(np.linspace(0, 20, 200000)) * 5.0
    noisy = add_sensor_noise(clean, 0.02, rng)
    assert np.std(noisy - clean) == pytest.approx(0.02 * np.std(clean), rel=0.01)
    unchanged = add_sensor_noise(clean, 0.0, rng)
    assert np.array_equal(unchanged, clean) and unchanged is not clean
    steps = quantise(clean, 0.25)
    assert np.allclose(steps / 0.25, np.round(steps / 0.25))
    assert np.max(np.abs(steps - clean)) <= 0.125 + 1e-12
    assert np.array_equal(quantise(clean, 0.0), clean)


def test_speed_from_position_recovers_a_sine_speed():
    dt = 1e-3
    t = np.arange(5000) * dt
    speed = 30.0 * np.sin(2 * np.pi * 2.0 * t)
    position = -30.0 / (2 * np.pi * 2.0) * np.cos(2 * np.pi * 2.0 * t)
    derived = speed_from_position(position, dt)
    inner = slice(200, -200)  # away from the filter's edge transients
    assert np.max(np.abs(derived[inner] - speed[inner])) < 1e-3 * 30.0
    # Encoder quantisation (1/4096 rev) is smoothed, not amplified by 1/dt.
    encoder = quantise(position, 2 * np.pi / 4096)
    derived = speed_from_position(encoder, dt, cutoff_hz=20.0)
    assert np.max(np.abs(derived[inner] - speed[inner])) < 0.01 * 30.0
    with pytest.raises(ValueError, match='Nyquist'):
        speed_from_position(position, dt, cutoff_hz=600.0)
