"""The Diebold-Mariano comparison of held-out predictions (rule ``innovation-dm``, issue 29)."""

import os
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import t as student

from dcmotor_id.identification.discovery import DiscoveryLoop
from dcmotor_id.identification.discovery.comparison import (ar_innovations, cosine_terms,
                                                            diebold_mariano, fit_ar,
                                                            input_noise_innovations)
from dcmotor_id.identification.discovery.judging import HELDOUT_ALPHA, innovation_dm

N = 1500


def _rejections(draw, alpha, replications=3000, seed=0):
    """Share of ``replications`` differentials ``draw(rng)`` whose mean the test rejects."""
    rng = np.random.default_rng(seed)
    count = 0
    for _ in range(replications):
        t, dof = diebold_mariano(draw(rng))
        count += t > student.ppf(1.0 - alpha, max(dof, 1))
    return count / replications


@pytest.mark.parametrize('kind', ['white', 'ar 0.9', 'ar 0.99', 'random walk'])
def test_the_size_holds_whatever_the_differential_s_correlation(kind):
    # Nominal one-sided 5 %; 3000 replications: a standard error of 0.4 %.
    draws = {
        'white': lambda rng: rng.normal(size=N),
        'ar 0.9': lambda rng: lfilter([1.0], [1.0, -0.9], rng.normal(size=N)),
        'ar 0.99': lambda rng: lfilter([1.0], [1.0, -0.99], rng.normal(size=N)),
        'random walk': lambda rng: np.cumsum(rng.normal(size=N)),
    }
    assert _rejections(draws[kind], 0.05) < 0.065


def test_a_random_walk_differential_is_rejected_far_more_often_with_every_cosine_term():
    # What the data-chosen number of terms prevents: half the samples' terms (right for
    # white noise) read a random walk's long-run variance as tiny.
    rng = np.random.default_rng(1)
    walks = [np.cumsum(rng.normal(size=N)) for _ in range(300)]
    assert max(cosine_terms(walk) for walk in walks) <= 3
    from scipy.fft import dct
    naive = 0
    for walk in walks:
        terms = dct(walk, type=2)[1:N // 2 + 1] * np.sqrt(2.0 / N) / 2.0
        t = np.mean(walk) * np.sqrt(N) / np.sqrt(np.mean(terms ** 2))
        naive += t > student.ppf(0.95, N // 2)
    assert naive / len(walks) > 0.3


def test_a_white_differential_with_a_shift_is_rejected_at_the_loop_s_size():
    # A shift of 0.15 standard deviations over 1500 samples: t about 5.8.
    assert _rejections(lambda rng: rng.normal(size=N) + 0.15, HELDOUT_ALPHA, 500) > 0.95


def test_an_autoregression_s_order_is_chosen_by_bic():
    rng = np.random.default_rng(2)
    white = rng.normal(size=4000)
    assert fit_ar([(white, 1000)]).shape == (0,)
    second = lfilter([1.0], [1.0, -1.2, 0.5], rng.normal(size=4000))
    coefficients = fit_ar([(second, 1000)])
    assert coefficients.shape == (2,)
    assert coefficients == pytest.approx([1.2, -0.5], abs=0.05)
    innovations = ar_innovations(second, 1000, coefficients)
    assert abs(np.corrcoef(innovations[1:], innovations[:-1])[0, 1]) < 0.05


def _input_noise_residual(rng, n=6000, dt=1e-3, inertia=2e-3, damping=1e-3, torque=0.02,
                          sensor=2e-4):
    """Return a position residual: a torque noise the shaft integrates twice, sensor noise."""
    from scipy.linalg import expm

    continuous = np.array([[0.0, 1.0, 0.0], [0.0, -damping / inertia, 1.0 / inertia],
                           [0.0, 0.0, 0.0]])
    discrete = expm(continuous * dt)
    state, out = np.zeros(2), np.empty(n)
    for k, noise in enumerate(rng.normal(0.0, torque, n)):
        out[k] = state[0]
        state = discrete[:2, :2] @ state + discrete[:2, 2] * noise
    return out + rng.normal(0.0, sensor, n)


def test_the_input_noise_filter_whitens_a_position_the_shaft_integrates():
    rng = np.random.default_rng(3)
    residual = _input_noise_residual(rng)
    innovations = input_noise_innovations(residual, 1e-3, 2e-3, 1e-3, 0.02, 2e-4)
    assert innovations is not None
    tail = innovations[1000:]
    assert abs(np.corrcoef(tail[1:], tail[:-1])[0, 1]) < 0.05
    # The residual itself is a drift: its lag-1 correlation is nearly 1.
    assert np.corrcoef(residual[1:], residual[:-1])[0, 1] > 0.99
    assert input_noise_innovations(residual, 1e-3, 2e-3, 1e-3, 0.0, 2e-4) is None


def _fit(position, stop):
    """
    Return a stand-in for a Fit: one position record whose simulation misses by ``position``.

    Its logged current is exact (no noise): the residual's error model is the autoregression.
    """
    n = position.shape[0]
    record = SimpleNamespace(position=np.zeros(n), current=np.zeros(n),
                             time_s=np.arange(n) * 1e-3)
    return SimpleNamespace(stops=[stop], records=[record], simulated=[{'position': position}],
                           values={})


def _loop():
    return DiscoveryLoop([], 1.0, criterion='position', weights={'position': 1.0},
                         min_gain=0.05, acceptance='innovation-dm')


def _drifts(seed, n=20000, dt=1e-3):
    """Return a missing force's integral (a square wave), a remaining force's, sensor noise."""
    rng = np.random.default_rng(seed)
    reversals = np.sign(np.sin(2 * np.pi * 0.4 * np.arange(n) * dt))
    remaining = np.convolve(rng.normal(0, 1, n), np.ones(200) / 200 ** 0.5, mode='same')
    return np.cumsum(reversals) * dt, np.cumsum(remaining) * dt, rng.normal(0, 0.002, n)


def test_a_candidate_removing_a_missing_force_predicts_significantly_better():
    missing, remaining, sensor = _drifts(0)
    t, dof = innovation_dm(_loop(), _fit(missing + remaining + sensor, 14000),
                           _fit(remaining + sensor, 14000))
    assert t > student.ppf(1.0 - HELDOUT_ALPHA, dof) and dof >= 30, (t, dof)


@pytest.mark.parametrize('seed', range(5))
def test_a_change_unrelated_to_the_drift_does_not_predict_significantly_better(seed):
    missing, remaining, sensor = _drifts(seed)
    other = _drifts(seed + 100)[1]
    t, dof = innovation_dm(_loop(), _fit(missing + remaining + sensor, 14000),
                           _fit(missing + remaining + 0.3 * other + sensor, 14000))
    assert t < student.ppf(1.0 - HELDOUT_ALPHA, max(dof, 1)), (t, dof)


def _mechanical_fit(residual, stop, current_noise, rng):
    """
    Return a stand-in mechanical-only fit (J 2e-3, b 1e-3) missing ``residual``.

    The measured position is the encoder's noise (2e-4 rad), the simulated one the residual
    (which the measurement's noise then joins); the logged current a sine with white noise of
    ``current_noise``.
    """
    n = residual.shape[0]
    current = np.sin(np.arange(n) * 1e-3) + rng.normal(0.0, current_noise, n)
    measured = rng.normal(0.0, 2e-4, n)
    record = SimpleNamespace(position=measured, current=current, time_s=np.arange(n) * 1e-3)
    return SimpleNamespace(stops=[stop], records=[record],
                           simulated=[{'position': residual}],
                           values={'J': 2e-3, 'b': 1e-3})


def test_the_position_s_error_model_is_the_input_noise_filter_where_it_describes_the_residual():
    from dcmotor_id.identification.discovery.judging import held_out_innovations
    from dcmotor_id.identification.error_model.criterion import noise_level

    rng = np.random.default_rng(4)
    # The input current's noise (0.02 A at a torque constant of 1) integrated twice.
    fit = _mechanical_fit(_input_noise_residual(rng, sensor=0.0), 4000, 0.02, rng)
    record, residual = fit.records[0], fit.simulated[0]['position'] - fit.records[0].position
    chosen = held_out_innovations(_loop(), fit, 'position')[0]
    filtered = input_noise_innovations(residual, 1e-3, 2e-3, 1e-3, noise_level(record.current),
                                       noise_level(record.position))
    assert np.allclose(chosen, filtered[4000:], rtol=1e-6, atol=0.0)


def test_a_missing_force_under_an_exact_input_is_left_to_the_autoregression():
    from dcmotor_id.identification.discovery.judging import held_out_innovations

    rng = np.random.default_rng(5)
    time = np.arange(6000) * 1e-3
    # A constant torque of 0.01 N m the model lacks: a parabola; the current is nearly exact.
    fit = _mechanical_fit(0.5 * 0.01 / 2e-3 * time ** 2, 4000, 1e-7, rng)
    residual = fit.simulated[0]['position'] - fit.records[0].position
    chosen = held_out_innovations(_loop(), fit, 'position')[0]
    model = fit_ar([(residual, 4000)])
    assert model.shape[0] >= 1
    assert np.array_equal(chosen, ar_innovations(residual, 4000, model))


def _scored(position, stop, train_cost):
    """Return a stand-in fit with its held-out and training costs."""
    fit = _fit(position, stop)
    fit.heldout_cost = float(np.mean(position[stop:] ** 2))
    fit.train_cost = train_cost
    fit.structure = ()
    fit.estimate = SimpleNamespace(initial_states=None)
    return fit


@pytest.mark.parametrize('restart_cost', [None, 0.5, 2.0])
def test_a_candidate_must_also_beat_the_current_structure_at_its_better_optimum(
        monkeypatch, restart_cost):
    # The base misses a force; the candidate has it.  When the base structure refitted from
    # the candidate's values is a better optimum (a lower training cost) that predicts as
    # well as the candidate, the gain is the optimiser's, not the effect's.
    from dcmotor_id.identification.discovery import bootstrap, judging

    missing, remaining, sensor = _drifts(0)
    current = _scored(missing + remaining + sensor, 14000, 1.0)
    fitted = _scored(remaining + sensor, 14000, 0.4)
    again = None if restart_cost is None else _scored(remaining + sensor, 14000, restart_cost)
    monkeypatch.setattr(judging, 'restarted', lambda loop, current, fitted: again)
    # (The bootstrap of a noisy input current, judged apart below, says nothing here.)
    monkeypatch.setattr(bootstrap, 'null_t', lambda loop, current, fitted, **options: [])
    candidate = SimpleNamespace(fitted=fitted, gain=1.0 - fitted.heldout_cost
                                / current.heldout_cost)
    doubt = judging.unearned_dm(_loop(), current, candidate)
    if restart_cost == 0.5:
        assert doubt is not None and 'refitted from its values' in doubt
    else:
        assert doubt is None


@pytest.mark.parametrize('spread', [0.2, 3.0])
def test_a_candidate_must_lie_beyond_the_t_its_structure_gets_on_replicas_of_the_null(
        monkeypatch, spread):
    # With a noisy input current the output-error fit is biased, and replicas of the current
    # structure give t values far from Student's: the candidate's t must exceed their
    # prediction bound.  Here its t is about 3.6: beyond replicas spread by 0.2 (a bound
    # near 0.8), within replicas spread by 3 (a bound near 12).
    from dcmotor_id.identification.discovery import bootstrap, judging

    missing, remaining, sensor = _drifts(0)
    current = _scored(missing + remaining + sensor, 14000, 1.0)
    fitted = _scored(remaining + sensor, 14000, 0.4)
    replicas = list(np.random.default_rng(6).normal(0.0, spread, 19))
    monkeypatch.setattr(judging, 'restarted', lambda loop, current, fitted: None)
    monkeypatch.setattr(bootstrap, 'null_t', lambda loop, current, fitted, **options: replicas)
    candidate = SimpleNamespace(fitted=fitted, gain=1.0 - fitted.heldout_cost
                                / current.heldout_cost)
    t = innovation_dm(_loop(), current, fitted)[0]
    assert 3.0 < t < 5.0, t
    doubt = judging.unearned_dm(_loop(), current, candidate)
    if spread == 0.2:
        assert doubt is None
    else:
        assert doubt is not None and 'replicas' in doubt


def test_innovation_t_null_asks_innovation_t_and_its_bootstrap(monkeypatch):
    # The rule innovation-t-null: innovation-t's test, and for a mechanical-only loop its t
    # beyond the bootstrap replicas' bound.
    from dcmotor_id.identification.discovery import bootstrap, judging
    from dcmotor_id.identification.discovery.judging import innovation_t

    missing, remaining, sensor = _drifts(0)
    current = _scored(missing + remaining + sensor, 14000, 1.0)
    fitted = _scored(remaining + sensor, 14000, 0.4)
    loop = DiscoveryLoop([], 1.0, criterion='position', weights={'position': 1.0},
                         min_gain=0.05, acceptance='innovation-t-null')
    t = innovation_t(loop, current, fitted)[0]
    candidate = SimpleNamespace(fitted=fitted, gain=1.0 - fitted.heldout_cost
                                / current.heldout_cost)
    seen = []

    def replicas(loop, current, fitted, statistic=None):
        seen.append(statistic)
        return list(np.random.default_rng(7).normal(0.0, spread, 19))
    monkeypatch.setattr(bootstrap, 'null_t', replicas)
    spread = 0.05 * t
    assert judging.unearned(loop, current, candidate) is None
    spread = 0.5 * t
    doubt = judging.unearned(loop, current, candidate)
    assert doubt is not None and 'innovation t' in doubt and 'replicas' in doubt
    assert seen == [innovation_t, innovation_t]


BENCH = os.path.join(os.path.dirname(__file__), '..', '..', 'bench')


def _benchmark_record(index):
    """Return the ``index``-th clean record of bench_discovery's mode with a noisy input."""
    sys.path.insert(0, BENCH)
    import bench_discovery  # noqa: I100

    rng = np.random.default_rng(7)
    for _ in range(index + 1):
        motor = bench_discovery.random_motor(rng)
        _, _, t, voltage = bench_discovery.random_excitation(rng)
        current, _, _ = bench_discovery.simulate_motor_effects(motor, voltage, 1e-3, [])
        _, angle = bench_discovery.mechanical_shaft(motor, current, [])
        records, torque_constant = bench_discovery.measured(
            'mechanical-input-noise', t, current, voltage, None, angle, 0.005, rng, motor)
    return records, torque_constant


@pytest.mark.parametrize('index', [0, 5])
def test_a_noisy_input_current_gets_no_effect_by_the_default_rule(index):
    # bench_discovery's clean records with 0.5 % noise on the input current (seed 7, the mode
    # alone): a PRBS at 94 V and a sine at 55 V.  The output-error fit of the position is
    # biased by the noise the shaft integrates and a load torque absorbs it (innovation-t adds
    # it); replicas of the base with the input's noise give the same t: the default rule
    # (innovation-t-null) adds nothing.
    from dcmotor_id.identification.discovery.state import DEFAULT_ACCEPTANCE
    from dcmotor_id.identification.identify import identify

    records, torque_constant = _benchmark_record(index)
    assert DEFAULT_ACCEPTANCE == 'innovation-t-null'
    assert identify(records, torque_constant=torque_constant).effects == []
    sys.path.insert(0, BENCH)
    from common import judged_by  # noqa: I100

    with judged_by('innovation-t'):
        found = identify(records, torque_constant=torque_constant)
    assert [effect['name'] for effect in found.effects] == ['load_torque']
