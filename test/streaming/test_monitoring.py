"""Change detection on the online estimates: alarms on each change, quiet when stationary."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.model import PAPER_MOTORS, PARAMETER_NAMES
from dcmotor_id.nodes.settings import IdentifierSettings
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation
from dcmotor_id.streaming.monitoring import (alarm_key_values, Baseline,
                                             baseline_from_observations, baseline_from_result,
                                             ChangeDetector, meaning, monitor_from_settings,
                                             nominal_baseline, OnlineMonitor)
from dcmotor_id.streaming.online import (LOAD_TORQUE, OnlineEstimate, parse_schedule, RlsEstimator,
                                         simulate_scheduled, WindowEstimator)

TRUTH = PAPER_MOTORS['paper2'].as_dict()
REL_STDERR = 0.002


def estimate(time_s, changes=None, load=0.0, rel_stderr=REL_STDERR, noise=None,
             window_s=20.0, converged=True):
    """Return an OnlineEstimate of motor 2 with some parameters changed (relative changes)."""
    values = dict(TRUTH)
    for name, change in (changes or {}).items():
        values[name] = TRUTH[name] * (1 + change)
    stderr = {name: abs(value) * rel_stderr for name, value in values.items()}
    if noise is not None:
        values = {name: value + noise.normal() * stderr[name] for name, value in values.items()}
    return OnlineEstimate(values, stderr, converged, {}, 0, 'window', time_s, window_s,
                          {LOAD_TORQUE: load, LOAD_TORQUE + '_stderr': 0.002})


def test_meanings_say_what_physics_allows_and_no_more():
    assert meaning('Ra', 0.18) == 'winding temperature about +46 K (copper)'
    assert 'K' in meaning('Ra', -0.04) and '-10 K' in meaning('Ra', -0.04)
    assert meaning('La', 0.3) == ''
    assert 'viscous' in meaning('b', 0.5) and 'inertia' in meaning('J', 0.1)


def test_the_first_full_converged_estimate_becomes_the_baseline():
    detector = ChangeDetector(min_baseline_window_s=20.0)
    detector.update(estimate(5.0, window_s=5.0))
    assert detector.baseline is None
    detector.update(estimate(20.0, converged=False))
    assert detector.baseline is None
    detector.update(estimate(22.0))
    assert detector.baseline.source == 'online' and detector.baseline.time_s == 22.0


def test_a_step_raises_an_alarm_with_percent_sigmas_since_and_meaning():
    detector = ChangeDetector(baseline=nominal_baseline(TRUTH))
    assert detector.update(estimate(10.0)) == []
    assert detector.update(estimate(10.0, {'Ra': 0.5})) == []  # the same fit again: ignored
    alarms = detector.update(estimate(12.0, {'Ra': 0.18}))
    alarm, = alarms
    assert (alarm.name, alarm.level) == ('Ra', 'ERROR')
    assert alarm.change_pct == pytest.approx(18.0)
    assert alarm.sigmas == pytest.approx(0.18 / (1.18 * REL_STDERR))
    assert alarm.since_s == 12.0
    assert alarm.text() == ('Ra +18.0 % (+76 sigma) since 12.0 s: winding temperature about '
                            '+46 K (copper)')
    alarms = detector.update(estimate(14.0, {'Ra': 0.08}))
    assert alarms[0].level == 'WARN' and alarms[0].since_s == 12.0
    pairs = dict(alarm_key_values(alarms, detector.baseline, clock=(1000.0, 14.0)))
    assert pairs['alarm_level'] == 'WARN' and pairs['baseline'] == 'nominal'
    assert float(pairs['alarm.Ra.change_pct']) == pytest.approx(8.0)
    assert pairs['alarm.Ra.since'] == '1970-01-01T00:16:38+00:00'  # 1000 s - 2 s
    # back to normal: clears (hysteresis at half the thresholds)
    assert detector.update(estimate(16.0, {'Ra': 0.01})) == []


def test_small_or_insignificant_changes_stay_quiet():
    detector = ChangeDetector(baseline=nominal_baseline(TRUTH))
    assert detector.update(estimate(2.0, {'b': 0.03})) == []  # 15 sigma but only 3 %
    assert detector.update(estimate(4.0, {'b': 0.30}, rel_stderr=0.1)) == []  # 30 %, 2 sigma


def test_a_load_torque_is_reported_against_the_coulomb_friction():
    detector = ChangeDetector(baseline=nominal_baseline(TRUTH))
    alarm, = detector.update(estimate(2.0, load=0.5))
    assert alarm.name == LOAD_TORQUE and alarm.change_pct == pytest.approx(50.0)
    assert alarm.text().startswith('load torque 0.5 N m (+50.0 % of the Coulomb friction')


def test_stationary_estimates_give_no_alarm_in_ten_minutes():
    """Honest estimates (Gaussian, correlated as overlapping windows are) never alarm."""
    rng = np.random.default_rng(0)
    detector = ChangeDetector(min_baseline_window_s=20.0)
    fired = 0
    shared = [rng.normal(size=8) for _ in range(10)]
    for k in range(300):  # an estimate every 2 s for 10 minutes
        shared = shared[1:] + [rng.normal(size=8)]  # a window holds 10 refit intervals
        z = np.sum(shared, axis=0) / math.sqrt(len(shared))
        noisy = estimate(2.0 * k + 20.0, rel_stderr=0.005)
        values = {name: value + z[i] * noisy.stderr[name]
                  for i, (name, value) in enumerate(noisy.parameters.items())}
        fired += len(detector.update(OnlineEstimate(values, noisy.stderr, True, {}, 0,
                                                    'window', noisy.time_s, 20.0,
                                                    noisy.effects)))
    assert fired == 0


def test_baselines_from_identify_and_nominal_values():
    result = {'parameters': TRUTH, 'stderr': dict.fromkeys(TRUTH, 0.01)}
    baseline = baseline_from_result(result)
    assert baseline.source == 'identify' and baseline.error('Ra') == 0.01
    assert baseline.value(LOAD_TORQUE) == 0.0
    assert nominal_baseline({'Ra': 1.0}) is None
    assert nominal_baseline(TRUTH).source == 'nominal'


def test_online_monitor_follows_the_baseline_policy_and_never_raises():
    estimator = WindowEstimator(1e-3)
    monitor = OnlineMonitor(estimator, ChangeDetector(), 'auto', None)
    assert monitor.identified({'parameters': TRUTH, 'stderr': TRUTH})
    assert monitor.detector.baseline.source == 'identify'
    assert not monitor.identified({'parameters': {}})
    assert 'online update failed' in monitor.update([1.0], [1.0, 2.0], [3.0])
    level, message, _ = monitor.condition([])
    assert level == 'OK' and 'identify baseline' in message
    nominal = OnlineMonitor(estimator, ChangeDetector(), 'auto', nominal_baseline(TRUTH))
    assert not nominal.identified({'parameters': TRUTH, 'stderr': TRUTH})
    assert nominal.detector.baseline.source == 'nominal'
    waiting = OnlineMonitor(estimator, ChangeDetector(), 'identify')
    assert waiting.snapshot()[1] == []
    assert OnlineMonitor(estimator, None).condition([])[1] == 'monitoring off'


def test_monitor_from_the_node_settings():
    settings = IdentifierSettings(online_in_subprocess=False, nominal_Ra=1.6, nominal_La=0.016,
                                  nominal_CPhi=0.7, nominal_J=0.0315, nominal_b=0.3,
                                  nominal_Mc=1.0)
    monitor = monitor_from_settings(settings, 1000.0)
    assert isinstance(monitor.estimator, WindowEstimator) and monitor.estimator.submit is None
    assert monitor.detector.baseline.source == 'nominal'
    rls = monitor_from_settings(IdentifierSettings(online_method='rls', monitor=False), 1000.0)
    assert rls.detector is None and isinstance(rls.estimator, RlsEstimator)
    with pytest.raises(ValueError, match='nominal'):
        monitor_from_settings(IdentifierSettings(monitor_baseline='nominal',
                                                 online_in_subprocess=False), 1000.0)


def run_schedule(text, duration_s, seed=0, interval_s=2.0):
    """Simulate motor 2 under ``text`` at 1 % noise; return [(time, alarms)] of the monitor."""
    params = PAPER_MOTORS['paper2']
    _, voltage = make_excitation('paper', duration_s, 1e-3)
    current, speed = simulate_scheduled(params, parse_schedule(text), voltage, 1e-3)
    rng = np.random.default_rng(seed)
    current, speed = add_sensor_noise(current, 0.01, rng), add_sensor_noise(speed, 0.01, rng)
    estimator = WindowEstimator(1e-3, window_s=20.0, refit_interval_s=interval_s,
                                cpu_budget=1.0)
    monitor = OnlineMonitor(estimator, ChangeDetector(min_baseline_window_s=20.0))
    history = []
    for start in range(0, voltage.size, 500):
        part = slice(start, start + 500)
        assert monitor.update(voltage[part], current[part], speed[part]) == ''
        snapshot, alarms = monitor.snapshot()
        history.append((snapshot.time_s, alarms))
    return history, monitor


def first_alarm(history, name):
    for time_s, alarms in history:
        for alarm in alarms:
            if alarm.name == name:
                return time_s, alarm
    return None, None


def test_alarms_fire_on_heating_wear_and_a_load_and_not_before():
    """The three changes of issue 12 in one run of the real estimator at 1 % noise."""
    history, monitor = run_schedule('Ra:+25%:ramp:24:54;b:+50%:step:70;'
                                    'load_torque:+0.5:step:100', 124.0)
    assert monitor.detector.baseline.source == 'online'
    before = [alarms for time_s, alarms in history if time_s < 24.0]
    assert not any(before)
    time_s, alarm = first_alarm(history, 'Ra')
    assert alarm is not None and 24.0 < time_s < 60.0 and alarm.change_pct > 5.0
    assert 'winding temperature' in alarm.meaning
    time_s, alarm = first_alarm(history, 'b')
    assert alarm is not None and 70.0 < time_s < 85.0 and alarm.level == 'ERROR'
    time_s, alarm = first_alarm(history, LOAD_TORQUE)
    assert alarm is not None and 100.0 < time_s < 115.0
    final = {alarm.name: alarm for alarm in history[-1][1]}
    assert final['Ra'].change_pct == pytest.approx(25.0, abs=2.0)
    assert final['b'].change_pct == pytest.approx(50.0, abs=3.0)
    assert final[LOAD_TORQUE].value == pytest.approx(0.5, rel=0.05)
    # only the parameters that changed: a window mixing before and after a step does not
    # raise alarms on the others
    fired = {alarm.name for _, alarms in history for alarm in alarms}
    assert fired == {'Ra', 'b', LOAD_TORQUE}


def test_a_stationary_motor_raises_no_alarm():
    history, monitor = run_schedule('', 90.0, seed=3)
    assert monitor.detector.baseline is not None
    assert not any(alarms for _, alarms in history)


@pytest.mark.slow
def test_a_stationary_motor_raises_no_alarm_in_ten_minutes():
    history, monitor = run_schedule('', 600.0, seed=5)
    assert not any(alarms for _, alarms in history)


def test_baseline_helpers_take_a_simple_namespace_estimate():
    detector = ChangeDetector(baseline=Baseline(dict(TRUTH), {}, 'nominal'))
    rls_like = SimpleNamespace(parameters=dict(TRUTH), stderr=dict.fromkeys(TRUTH, 1e-3),
                               converged=True, time_s=1.0, window_s=10.0, effects={})
    assert detector.update(rls_like) == []
    assert all(name in PARAMETER_NAMES for name in detector._stats if name != LOAD_TORQUE)


def test_separate_windows_learn_the_baseline_and_confirm_an_alarm():
    # the fleet's options: baseline from the first 3 observations, 2 consecutive to alarm
    detector = ChangeDetector(confirm=2, baseline_count=3)
    for time_s, value in enumerate((1.0, 1.002, 0.998)):
        assert detector.observe('Ra', value, 0.001, float(time_s)) is None
    assert detector.baseline.source == 'observations'
    assert detector.baseline.value('Ra') == pytest.approx(1.0)
    assert detector.baseline.factor('Ra') == pytest.approx(2.0)  # scatter twice the stderr
    assert detector.observe('Ra', 1.2, 0.001, 3.0) is None  # one window: not yet
    alarm = detector.observe('Ra', 1.2, 0.001, 4.0)
    assert (alarm.level, alarm.since_s) == ('ERROR', 3.0)
    assert alarm.change_pct == pytest.approx(20.0)
    learned = baseline_from_observations({'b': [(0.3, 0.01), (0.3, 0.01)]})
    assert learned.factor('b') == 1.0 and learned.error('b') == pytest.approx(0.01 / 2 ** 0.5)
