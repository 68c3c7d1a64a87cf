"""Standard errors that cover a difference between records (issue 19: disjoint-subset z)."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.records import Record
from dcmotor_id.identification.checks.identifiability import loose
from dcmotor_id.identification.estimators.uncertainty import (between_record_warnings,
                                                              between_records, block_scores,
                                                              METHOD, robust_covariance,
                                                              t_quantile_95)
from dcmotor_id.identification.identify import identify
from dcmotor_id.simulation.lab_scenarios import SERVO_MOTOR, simulate_drive, step_levels

N_RECORDS = 6
LENGTH = 1500


def _fit(records_x, records_y):
    """Pooled least squares over records; its robust covariance dict."""
    x, y = np.vstack(records_x), np.concatenate(records_y)
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    residual = y - x @ beta
    info = {'normal_matrix': x.T @ x, 'chain': np.ones(x.shape[1]), 'names': ['a', 'c'],
            'residual_rms_weighted': float(np.sqrt(residual @ residual / (len(y) - 2))),
            **block_scores(residual, x, [len(v) for v in records_y], 1)}
    return beta, robust_covariance(info)


def _monte_carlo(slope_spread, seed=5, runs=200):
    """Estimates, stated stderr and within-record stderr of records with AR(1) noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(LENGTH)
    estimates, stated, within = [], [], []
    for _ in range(runs):
        xs, ys = [], []
        for record in range(N_RECORDS):
            x = np.column_stack([np.sin(2 * np.pi * t / 500 + record), np.ones(LENGTH)])
            noise = np.zeros(LENGTH)
            white = rng.normal(size=LENGTH)
            for k in range(1, LENGTH):
                noise[k] = 0.8 * noise[k - 1] + white[k]
            slope = 1.0 + slope_spread * rng.normal()  # a friction of its own per record
            xs.append(x)
            ys.append(x @ [slope, 2.0] + noise)
        beta, robust = _fit(xs, ys)
        estimates.append(beta)
        stated.append(robust['stderr'])
        within.append(robust['stderr_within'])
    spread = np.std(estimates, axis=0)
    return np.median(stated, axis=0) / spread, np.median(within, axis=0) / spread


def test_record_level_stderr_covers_a_parameter_that_differs_record_to_record():
    stated, within = _monte_carlo(slope_spread=1.0)
    # Blocks within a record cannot see the records' own slopes: the old figure undercovers.
    assert within[0] < 0.4, within
    assert 0.6 < stated[0] < 1.8, stated


def test_record_level_stderr_stays_near_the_old_figure_when_records_share_parameters():
    stated, within = _monte_carlo(slope_spread=0.0)
    assert np.all((within > 0.6) & (within < 1.8)), within
    # The record-level figure adds little when the records agree (5 degrees of freedom).
    assert np.all(stated / within < 1.25), stated / within
    assert np.all((stated > 0.6) & (stated < 1.8)), stated


def test_one_record_has_no_record_level_figure():
    rng = np.random.default_rng(0)
    x = np.column_stack([np.linspace(-1, 1, 800), np.ones(800)])
    _, robust = _fit([x], [x @ [1.0, 2.0] + rng.normal(size=800)])
    assert robust['stderr_records'] is None and robust['method'] == METHOD
    assert np.array_equal(robust['stderr'], robust['stderr_within'])
    assert between_records(['a', 'c'], robust) is None
    assert between_record_warnings(None) == []


def _servo_records(count, spread, rng, dt=2e-3):
    """
    Simulate torque-step records of the servo like the HSM150 runs.

    Both ways in turn, a steady tail after each step, a quantised speed, each record with its
    own viscous and Coulomb friction (relative standard deviation ``spread``).
    """
    records = []
    for index in range(count):
        factor = 1.0 + spread * rng.normal(size=2)
        truth = replace(SERVO_MOTOR, b=SERVO_MOTOR.b * factor[0], Mc=SERVO_MOTOR.Mc * factor[1])
        sign = 1.0 if index % 2 == 0 else -1.0
        command = sign * step_levels([1.0, 1.4 + 0.03 * index, 1.15], 5.0, dt)
        out = simulate_drive(truth, command, dt, torque_input=True)
        t = np.arange(command.shape[0]) * dt
        records.append(Record(t, current=out['current'] + rng.normal(0.0, 0.05, len(t)),
                              speed=np.round(out['speed'] / 0.1) * 0.1,
                              source=f'servo_{index}'))
    return records


def _halves_z(spread, seeds=12):
    """Return the RMS z of J, b, Mc between disjoint 4-record halves (stated, within-record)."""
    stated, within, accounts = [], [], []
    for seed in range(seeds):
        records = _servo_records(8, spread, np.random.default_rng(1000 + seed))
        a, b = (identify(records[part * 4:(part + 1) * 4], torque_constant=SERVO_MOTOR.CPhi,
                         discover=False) for part in (0, 1))
        old = [(r.between_records['stderr_within'], r.between_records) for r in (a, b)]
        stated.append([abs(a.parameters[k] - b.parameters[k])
                       / np.hypot(a.stderr[k], b.stderr[k]) for k in ('J', 'b', 'Mc')])
        within.append([abs(a.parameters[k] - b.parameters[k])
                       / np.hypot(old[0][0][k], old[1][0][k]) for k in ('J', 'b', 'Mc')])
        accounts += [a.between_records, b.between_records]
    rms = [np.sqrt(np.mean(np.square(z), axis=0)) for z in (stated, within)]
    return rms[0], rms[1], accounts


def test_records_with_a_friction_of_their_own_are_covered_by_the_jackknife_over_records():
    stated, within, accounts = _halves_z(spread=0.1)
    # b and Mc differ record to record: blocks within a record do not see it (RMS z ~ 3).
    assert np.all(within[1:] > 2.5), within
    # The jackknife over records does (RMS z of a t with 3 degrees of freedom is 1.7).
    assert np.all(stated < 1.8), stated
    assert all(account['records'] == 4 and account['dof'] == 3 for account in accounts)
    # A half whose one record carries 99 % of a parameter falls back to the cluster sandwich.
    estimators = [account['estimator'] for account in accounts]
    assert estimators.count('jackknife') >= 0.75 * len(estimators), estimators


def test_records_sharing_their_parameters_keep_about_the_within_record_figure():
    stated, within, accounts = _halves_z(spread=0.0)
    assert np.all(stated < 1.3), stated
    ratios = [account['stderr_records'][k] / account['stderr_within'][k]
              for account in accounts for k in ('J', 'b', 'Mc')]
    assert np.median(ratios) < 1.5, ratios


def test_identify_names_the_record_level_method_and_warns_when_records_disagree():
    frictions = SERVO_MOTOR.b * np.array([0.6, 1.4, 0.8, 1.2])
    varied = []
    rng = np.random.default_rng(7)
    for index, b in enumerate(frictions):
        truth = replace(SERVO_MOTOR, b=float(b))
        command = (1.0 if index % 2 == 0 else -1.0) * step_levels([1.0, 1.5, 1.15], 5.0, 2e-3)
        out = simulate_drive(truth, command, 2e-3, torque_input=True)
        t = np.arange(command.shape[0]) * 2e-3
        varied.append(Record(t, current=out['current'] + rng.normal(0.0, 0.01, len(t)),
                             speed=out['speed'] + rng.normal(0.0, 0.01, len(t))))
    result = identify(varied, torque_constant=SERVO_MOTOR.CPhi, discover=False).as_dict()
    account = result['between_records']
    assert 'delete-one-record jackknife' in result['uncertainty_method']
    assert 'b' in account['dominant']
    assert result['stderr']['b'] == account['stderr_records']['b']
    assert any(text.startswith('the records disagree far beyond their noise')
               and '3 degree(s) of freedom' in text for text in result['warnings'])


def test_records_that_disagree_do_not_make_a_parameter_undetermined():
    # The HSM150 run 1 class: J's record-level stderr is 68 % of J, its within-record one 12 %.
    estimate = SimpleNamespace(
        parameters={'J': 1.755e-4}, stderr={'J': 1.2e-4},
        info={'between_records': {'stderr_within': {'J': 2.1e-5}}})
    assert loose(estimate, ['J']) == {}
    alone = SimpleNamespace(parameters={'J': 1.755e-4}, stderr={'J': 1.2e-4}, info={})
    assert 'J' in loose(alone, ['J'])


def _named_fit(xs, ys, names):
    """Pooled least squares over records with named columns; estimate and robust dict."""
    x, y = np.vstack(xs), np.concatenate(ys)
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    residual = y - x @ beta
    info = {'normal_matrix': x.T @ x, 'chain': np.ones(x.shape[1]), 'names': list(names),
            'residual_rms_weighted': float(np.sqrt(residual @ residual / (len(y) - len(names)))),
            **block_scores(residual, x, [len(v) for v in ys], 1)}
    return beta, robust_covariance(info)


def _two_records(rng, lengths=(3600, 400), slope_spread=1.0):
    """Two records of unequal length (weight), each with a slope of its own, white noise."""
    xs, ys = [], []
    for length in lengths:
        x = np.column_stack([np.sin(np.linspace(0, 12 * np.pi, length)), np.ones(length)])
        xs.append(x)
        ys.append(x @ [1.0 + slope_spread * rng.normal(), 2.0] + 0.1 * rng.normal(size=length))
    return xs, ys


def test_two_records_get_the_jackknife_centred_at_the_fit():
    xs, ys = _two_records(np.random.default_rng(3))
    beta, robust = _named_fit(xs, ys, ['a', 'c'])
    alone = [np.linalg.lstsq(x, y, rcond=None)[0] for x, y in zip(xs, ys)]
    # CV3: half the sum of squares of the one-record fits about the fit of both (exact here).
    cv3 = np.sqrt(0.5 * sum((theta - beta) ** 2 for theta in alone))
    assert robust['record_estimator'] == 'jackknife'
    np.testing.assert_allclose(robust['stderr_records'], cv3, rtol=1e-6)


def test_two_records_of_unequal_weight_are_not_understated():
    # The cluster sandwich of two records of weights 0.9 / 0.1 has about 8 % of the variance
    # of the fit's spread (the record-level variance is 0.82 of one record's); CV3 has it all.
    rng = np.random.default_rng(11)
    estimates, variances = [], []
    for _ in range(400):
        beta, robust = _named_fit(*_two_records(rng), ['a', 'c'])
        estimates.append(beta[0] - 1.0)
        variances.append(robust['stderr'][0] ** 2)
    ratio = np.sqrt(np.mean(variances) / np.mean(np.square(estimates)))
    assert 0.75 < ratio < 1.35, ratio


def test_interval_of_two_records_is_a_t_interval_with_one_degree_of_freedom():
    # Normal quantiles on a 1-degree-of-freedom error cover about 70 %; t_1's 12.7 covers 95 %.
    rng = np.random.default_rng(12)
    normal, student, accounts = [], [], []
    for _ in range(400):
        xs, ys = _two_records(rng, lengths=(2000, 2000))
        beta, robust = _named_fit(xs, ys, ['a', 'c'])
        account = between_records(['a', 'c'], robust, {'a': beta[0], 'c': beta[1]})
        low, high = account['interval_95']['a']
        student.append(low <= 1.0 <= high)
        normal.append(abs(beta[0] - 1.0) <= 1.959964 * robust['stderr'][0])
        accounts.append(account)
    assert np.mean(normal) < 0.8, np.mean(normal)
    assert 0.92 < np.mean(student) < 0.99, np.mean(student)
    assert all(account['t_95']['a'] == (12.7062 if 'a' in account['dominant'] else 1.959964)
               for account in accounts)
    assert sum('a' in account['dominant'] for account in accounts) > 360
    # The intercept is shared exactly: its figure is the within-record one, normal quantiles.
    assert sum(account['t_95']['c'] == 1.959964 for account in accounts) > 300


def test_a_parameter_one_record_cannot_determine_keeps_the_cluster_sandwich():
    # One record per direction: Coulomb friction (sign) and a torque offset (1) are one column
    # within a record; the slope is determined by each record alone.
    rng = np.random.default_rng(4)
    xs, ys = [], []
    for sign, slope in ((1.0, 1.3), (-1.0, 0.8)):
        t = np.linspace(0, 8 * np.pi, 2000)
        x = np.column_stack([np.sin(t), np.full_like(t, sign), np.ones_like(t)])
        xs.append(x)
        ys.append(x @ [slope, 0.5, 0.2] + 0.1 * rng.normal(size=len(t)))
    beta, robust = _named_fit(xs, ys, ['a', 'Mc', 'T'])
    alone = [np.linalg.lstsq(x[:, [0, 2]], y, rcond=None)[0][0] for x, y in zip(xs, ys)]
    assert robust['record_estimator'] == 'jackknife' and robust['record_cluster'] == ['Mc', 'T']
    np.testing.assert_allclose(robust['stderr_records'][0],
                               np.sqrt(0.5 * sum((v - beta[0]) ** 2 for v in alone)), rtol=1e-6)
    account = between_records(['a', 'Mc', 'T'], robust)
    assert account['note'].startswith('Mc, T: one record alone does not determine them')
    assert 'interval_95' not in account and account['t_95']['a'] == 12.7062


def test_t_quantiles_are_student_ones():
    from scipy.stats import t as student
    for dof in (1, 2, 3, 7, 30, 31, 45, 200):
        assert abs(t_quantile_95(dof) - student.ppf(0.975, dof)) < 1e-4, dof
    assert t_quantile_95(np.inf) == 1.959964
    with pytest.raises(ValueError, match='whole number'):
        t_quantile_95(1.5)


def test_identify_of_an_opposite_pair_states_the_jackknife_and_a_t_interval():
    rng = np.random.default_rng(3)
    records = []
    for sign, factor in ((1.0, 1.0), (-1.0, 1.3)):  # the second record's viscous friction
        truth = replace(SERVO_MOTOR, b=factor * SERVO_MOTOR.b)
        command = sign * step_levels([1.0, 1.4, 1.15], 5.0, 2e-3)
        out = simulate_drive(truth, command, 2e-3, torque_input=True)
        t = np.arange(command.shape[0]) * 2e-3
        records.append(Record(t, current=out['current'] + rng.normal(0.0, 0.05, len(t)),
                              speed=np.round(out['speed'] / 0.1) * 0.1))
    result = identify(records, torque_constant=SERVO_MOTOR.CPhi, discover=False).as_dict()
    account = result['between_records']
    assert account['estimator'] == 'jackknife' and account['dof'] == 1
    assert 'b' in account['dominant'] and account['t_95']['b'] == 12.7062
    low, high = account['interval_95']['b']
    assert np.isclose(high - low, 2 * 12.7062 * result['stderr']['b'])
