"""Residual analysis against direct formulas and known sequences."""

import numpy as np
import pytest
from scipy.stats import chi2

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.error_model import residuals
from dcmotor_id.identification.error_model.residuals import (analyse_channel, autocorrelation,
                                                             confidence_band, correlation_summary,
                                                             cross_correlation, ljung_box,
                                                             one_step_error, predictable_fraction)
from dcmotor_id.signals.filters import noise_std as noise_std_estimate
from dcmotor_id.simulation import simulate_mechanical, simulate_motor
from dcmotor_id.simulation.excitation import make_excitation

RNG = np.random.default_rng(12)


def ar1(n, pole, rng):
    out = np.zeros(n)
    noise = rng.normal(size=n)
    for k in range(1, n):
        out[k] = pole * out[k - 1] + noise[k]
    return out


def test_autocorrelation_matches_the_direct_sum():
    x = RNG.normal(size=500) + 0.3
    direct = np.array([np.sum(x[:x.size - k] * x[k:]) for k in range(11)]) / np.sum(x * x)
    assert np.allclose(autocorrelation(x, 10), direct, atol=1e-12)
    centred = x - x.mean()
    direct = np.array([np.sum(centred[:x.size - k] * centred[k:])
                       for k in range(11)]) / np.sum(centred ** 2)
    assert np.allclose(autocorrelation(x, 10, centred=True), direct, atol=1e-12)


def test_cross_correlation_matches_the_direct_sum():
    x = RNG.normal(size=300) + 0.5
    y = RNG.normal(size=300) - 0.2
    xc, yc = x - x.mean(), y - y.mean()
    n = x.size
    direct = [np.sum(xc[tau:] * yc[:n - tau]) if tau >= 0 else np.sum(xc[:n + tau] * yc[-tau:])
              for tau in range(-7, 8)]
    lags, rho = cross_correlation(x, y, 7)
    assert np.array_equal(lags, np.arange(-7, 8))
    assert np.allclose(rho, np.array(direct) / np.sqrt(np.sum(xc ** 2) * np.sum(yc ** 2)),
                       atol=1e-13)


def test_cross_correlation_finds_the_lag_with_its_sign():
    y = RNG.normal(size=2000)
    x = np.concatenate([np.zeros(4), y[:-4]])  # x follows y by 4 samples
    lags, rho = cross_correlation(x, y, 10)
    assert lags[np.argmax(rho)] == 4
    assert rho.max() == pytest.approx(1.0, abs=0.01)
    summary = correlation_summary(x, y, 10)
    assert summary['lag'] == 4 and summary['outside']


def test_band_and_ljung_box_statistic():
    assert confidence_band(10000) == pytest.approx(2.5758293 / 100.0, rel=1e-6)
    x = RNG.normal(size=4000)
    rho = autocorrelation(x, 20)[1:]
    n = x.size
    q = n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, 21)))
    test = ljung_box(x, 20)
    assert test['statistic'] == pytest.approx(q, rel=1e-12)
    assert test['p_value'] == pytest.approx(chi2.sf(q, 20), rel=1e-9)


def test_white_noise_passes_and_structure_fails():
    passed = sum(ljung_box(RNG.normal(size=3000))['white'] for _ in range(200))
    assert 190 <= passed <= 200  # a 1 % test: about 2 rejections in 200
    assert not ljung_box(ar1(3000, 0.3, RNG))['white']
    # A bias is structure: zero-mean whiteness fails.
    assert not ljung_box(RNG.normal(size=3000) + 0.3)['white']


def test_predictable_fraction_is_a_size():
    assert predictable_fraction(RNG.normal(size=5000)) < 0.01
    assert predictable_fraction(ar1(5000, 0.8, RNG)) == pytest.approx(0.64, abs=0.05)
    assert predictable_fraction(np.sin(np.arange(3000) * 0.01)) > 0.99


def test_predictable_fraction_in_blocks_is_the_least_squares_fit(monkeypatch):
    x = ar1(4000, 0.6, RNG) + 0.2
    order = residuals.AR_ORDER
    past = np.column_stack([x[order - lag:x.size - lag] for lag in range(1, order + 1)])
    target = x[order:]
    error = target - past @ np.linalg.lstsq(past, target, rcond=None)[0]
    expected = 1.0 - (error @ error) / (target @ target)
    monkeypatch.setattr(residuals, 'PREDICTOR_BLOCK', 333)  # many blocks, a short last one
    assert predictable_fraction(x) == pytest.approx(expected, rel=1e-10)


def test_one_step_error_in_blocks_equals_one_block(monkeypatch):
    params = PAPER_MOTORS['paper2'].as_dict()
    n = 2500
    t = np.arange(n) * 1e-3
    record = Record(t, RNG.normal(size=n), 50.0 * np.sin(t * 7.0), RNG.normal(size=n) * 10.0)
    extras = {'voltage_extra': RNG.normal(size=n), 'torque_extra': RNG.normal(size=n),
              'current_offset': RNG.normal(size=n), 'speed_offset': RNG.normal(size=n)}
    whole = one_step_error(params, record, coulomb_delta=0.1, **extras)
    whole_mechanical = one_step_error(params, record, 0.5, **extras)
    monkeypatch.setattr(residuals, 'ONE_STEP_BLOCK', 97)
    blocks = one_step_error(params, record, coulomb_delta=0.1, **extras)
    blocks_mechanical = one_step_error(params, record, 0.5, **extras)
    for channel in ('current', 'speed'):
        assert blocks[channel].shape == (n - 1,)
        assert np.array_equal(blocks[channel], whole[channel])
    assert np.array_equal(blocks_mechanical['speed'], whole_mechanical['speed'])


def test_noise_estimate_on_a_smooth_signal():
    t = np.arange(20000) * 1e-3
    signal = 50.0 * np.sin(2 * np.pi * 0.5 * t)
    noisy = signal + RNG.normal(scale=0.4, size=t.size)
    assert noise_std_estimate(noisy) == pytest.approx(0.4, rel=0.05)


def test_one_step_error_is_zero_for_the_true_model():
    params = PAPER_MOTORS['paper2']
    dt = 1e-3
    t, voltage = make_excitation('sine', 3.0, dt)
    current, speed = simulate_motor(params, voltage, dt)
    errors = one_step_error(params.as_dict(), Record(t, current, voltage, speed))
    # Exact except in the few samples where the speed reverses or sticks within the sample.
    moving = (np.sign(speed[:-1]) == np.sign(speed[1:])) & (speed[:-1] != 0)
    for channel in ('current', 'speed'):
        assert np.max(np.abs(errors[channel][moving])) < 1e-9 * np.ptp(speed)
    wrong = one_step_error(params.replace(J=1.2 * params.J).as_dict(),
                           Record(t, current, voltage, speed))
    assert np.max(np.abs(wrong['speed'][moving])) > 1e-4 * np.ptp(speed)


def test_one_step_error_mechanical_mode():
    dt = 1e-3
    torque = 3.0 * np.sin(np.linspace(0.0, 12.0, 3000))
    speed = simulate_mechanical(0.03, 0.3, 1.0, torque, dt)
    record = Record(np.arange(3000) * dt, current=torque / 0.5, speed=speed)
    errors = one_step_error({'J': 0.03, 'b': 0.3, 'Mc': 1.0}, record, torque_constant=0.5)
    moving = (np.sign(speed[:-1]) == np.sign(speed[1:])) & (speed[:-1] != 0)
    assert set(errors) == {'speed'}
    assert np.max(np.abs(errors['speed'][moving])) < 1e-9 * np.ptp(speed)


def test_analyse_channel_reports_json_ready_evidence():
    measured = np.sin(np.arange(3000) * 0.01)
    result = analyse_channel(RNG.normal(scale=0.01, size=3000), measured,
                             inputs={'voltage': measured}, regressors={'load_torque':
                                                                       np.ones(3000)})
    assert result['ljung_box']['white']
    assert not result['inputs']['voltage']['outside']
    assert set(result) >= {'rms', 'nrmse_pct', 'ljung_box', 'predictable_fraction',
                           'acf_outside_band', 'inputs', 'regressors', 'noise_std'}
    structured = analyse_channel(0.05 * measured, measured, inputs={'voltage': measured})
    assert not structured['ljung_box']['white']
    assert structured['inputs']['voltage']['outside']
    assert structured['predictable_fraction'] > 0.9


def test_chi_square_survival_matches_scipy():
    from scipy.special import chdtrc

    from dcmotor_id.identification.error_model.residuals import chi_square_sf
    for dof in (1, 2, 3, 10, 25, 26, 99, 400):
        for statistic in (1e-6, 0.5, dof * 0.3, dof * 1.0, dof + 3.0 * np.sqrt(2.0 * dof),
                          dof * 5.0, 1e3, 1e5, 1e9):
            expected = chdtrc(dof, statistic)
            assert chi_square_sf(dof, statistic) == pytest.approx(expected, rel=1e-12,
                                                                  abs=1e-300)
    assert chi_square_sf(5, 0.0) == 1.0
