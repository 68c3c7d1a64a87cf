"""Excitation routines and the exciter's safety state machine (dcmotor_id.design.routines)."""

import numpy as np
import pytest

from dcmotor_id.design.routines import (command_profile, ExcitationSession, hold, Limits, Routine,
                                        routine_voltage, ROUTINES)

LIMITS = Limits(voltage_v=24.0, current_a=5.0, speed_rad_s=50.0)


@pytest.mark.parametrize('kind', ROUTINES)
def test_every_routine_has_its_length_peak_and_direction(kind):
    routine = Routine(kind=kind, amplitude_v=10.0, duration_s=4.0, frequency_hz=2.0,
                      max_frequency_hz=20.0 if kind in ('multisine', 'chirp') else 0.0)
    t, forward = routine_voltage(routine, 1e-2)
    _, backward = routine_voltage(routine.replace(direction='backward'), 1e-2)
    assert len(t) == 400 and t[1] == pytest.approx(1e-2)
    assert np.max(np.abs(forward)) == pytest.approx(10.0, rel=0.02)
    np.testing.assert_allclose(backward, -forward)


def test_quasistatic_ramps_and_dynamic_steps():
    _, ramp = routine_voltage(Routine('quasistatic', 6.0, 3.0), 1e-2)
    assert ramp[0] == 0.0 and np.all(np.diff(ramp) > 0) and ramp[-1] < 6.0
    _, step = routine_voltage(Routine('dynamic', 6.0, 3.0), 1e-2)
    assert np.all(step == 6.0)
    _, steps = routine_voltage(Routine('dynamic', 6.0, 2.0, frequency_hz=1.0), 1e-2)
    assert set(np.unique(steps)) == {0.0, 6.0} and steps[0] == 6.0 and steps[60] == 0.0


def test_ramp_in_and_hold_at_the_drive_period():
    t, profile = command_profile(Routine('dynamic', 10.0, 2.0), 100.0, 0.5)
    assert profile[0] == 0.0 and profile[25] == pytest.approx(5.0)
    assert np.all(profile[50:] == 10.0)
    held = hold(profile, 100.0, 1e-3)
    assert len(held) == 2000 and np.all(held[250:260] == profile[25])


def test_bad_routines_are_refused():
    for bad in ({'kind': 'sine'}, {'direction': 'up'}, {'duration_s': 0.0},
                {'amplitude_v': -1.0}, {'frequency_hz': -2.0}):
        with pytest.raises(ValueError):
            Routine(**bad)
    with pytest.raises(ValueError):
        Limits(current_a=0.0)
    assert Routine.from_dict({**Routine().as_dict(), 'other': 1}) == Routine()


def running(routine=Routine('dynamic', 12.0, 2.0), ramp_in_s=0.5):
    session = ExcitationSession(LIMITS, rate_hz=100.0, ramp_in_s=ramp_in_s,
                                stale_timeout_s=0.2)
    session.observe(0.0, current=[0.0], speed=[0.0])
    ok, message = session.start(routine, 0.0)
    assert ok, message
    return session


def test_a_routine_ramps_in_runs_and_ends_at_zero():
    session = running()
    session.observe(0.2)
    assert session.state == 'ramping-in' and session.command(0.25) == pytest.approx(6.0)
    for now in np.arange(0.3, 2.0, 0.1):
        session.observe(now, current=[1.0], speed=[1.0])
        value = session.command(now)
    assert session.state == 'running' and value == 12.0
    assert session.progress == pytest.approx(0.95, abs=0.02)
    session.observe(2.05)
    assert session.command(2.05) == 0.0 and session.state == 'done'
    assert session.command(2.1) is None and session.status()['state'] == 'done'


@pytest.mark.parametrize('channel, value, word', [('current', 5.5, 'current'),
                                                  ('speed', -60.0, 'speed'),
                                                  ('voltage', 30.0, 'voltage'),
                                                  ('current', np.nan, 'not finite')])
def test_a_limit_stops_at_once(channel, value, word):
    session = running()
    session.command(0.1)
    assert session.observe(0.11, **{channel: [0.0, value]})
    assert session.state == 'stopped-by-limit' and word in session.reason
    assert session.last_command_v == 0.0 and session.command(0.12) is None


def test_stale_measurements_stop_the_routine():
    session = running()
    session.observe(0.1, current=[0.1])
    assert session.command(0.25) is not None
    assert session.command(0.31) == 0.0
    assert session.state == 'stale' and 'no measurement' in session.reason


def test_start_is_refused_blind_beyond_the_voltage_limit_and_twice():
    session = ExcitationSession(LIMITS, stale_timeout_s=0.2)
    ok, message = session.start(Routine(), 0.0)
    assert not ok and 'no measurement' in message and session.state == 'idle'
    session.observe(1.0)
    ok, message = session.start(Routine(amplitude_v=30.0), 1.1)
    assert not ok and 'voltage limit' in message
    assert session.start(Routine(amplitude_v=20.0), 1.1)[0]
    ok, message = session.start(Routine(), 1.1)
    assert not ok and 'running' in message
    assert session.stop() == 0.0 and session.state == 'stopped'
    session.observe(1.2)
    assert session.start(Routine(amplitude_v=20.0), 1.2)[0]  # a stopped session re-arms


def watching(channels=('current', 'speed')):
    session = ExcitationSession(LIMITS, rate_hz=100.0, ramp_in_s=0.0, stale_timeout_s=0.2,
                                watch=channels)
    session.observe(0.0, current=[0.0])
    ok, message = session.start(Routine('dynamic', 12.0, 10.0), 0.0)
    assert not ok and 'no measurement on speed' in message  # one channel is not enough
    session.observe(0.0, speed=[0.0])
    assert session.start(Routine('dynamic', 12.0, 10.0), 0.0)[0]
    return session


def test_one_stale_channel_stops_the_routine_while_the_other_keeps_coming():
    """Issue 21: speed stopped, current kept arriving: 0 V at the first tick past the timeout."""
    session = watching()
    for now in np.arange(0.01, 1.0, 0.01):  # 100 Hz ticks; speed stops at 0.5 s
        session.observe(now, current=[1.0], **({'speed': [1.0]} if now < 0.5 else {}))
        value = session.command(now)
        if now - 0.49 > 0.2 + 1e-9:
            assert value in (0.0, None), now
    assert session.state == 'stale'
    assert 'no measurement on speed' in session.reason and 'current' not in session.reason


@pytest.mark.parametrize('bad', [np.nan, np.inf])
def test_a_non_finite_channel_stops_at_once_and_blocks_a_start(bad):
    session = watching()
    assert session.observe(0.1, speed=[bad]) and session.state == 'stopped-by-limit'
    assert 'speed is not finite' in session.reason
    session.observe(0.15, current=[0.0])
    ok, message = session.start(Routine('dynamic', 1.0, 1.0), 0.15)
    assert not ok and 'speed is not finite' in message
    assert session.status()['not_finite'] == 'speed'
    session.observe(0.16, speed=[0.0])  # a finite sample clears it
    assert session.start(Routine('dynamic', 1.0, 1.0), 0.16)[0]


def test_a_routine_with_non_finite_voltages_is_refused():
    session = watching()
    session.stop()
    ok, message = session.start(Routine('dynamic', 1.0, 1.0, offset_v=float('nan')), 0.01)
    assert not ok and 'NaN or infinite voltages' in message
    with pytest.raises(ValueError, match='cannot watch'):
        ExcitationSession(LIMITS, watch=('torque',))


def test_start_takes_a_profile_computed_beforehand_and_checks_it():
    """A node computes the commands before it takes the start's time (exciter ~/start)."""
    session = ExcitationSession(LIMITS, rate_hz=100.0, ramp_in_s=0.0, stale_timeout_s=0.2)
    routine = Routine('dynamic', 12.0, 1.0)
    profile = session.profile_of(routine)
    assert np.array_equal(profile, command_profile(routine, 100.0, 0.0)[1])
    session.observe(30.0)
    ok, message = session.start(routine, 30.0, np.full(profile.size, 100.0))
    assert not ok and 'voltage limit' in message
    ok, message = session.start(routine, 30.0, np.full(profile.size, np.nan))
    assert not ok and 'NaN' in message
    assert session.start(routine, 30.0, profile)[0] and session.started_s == 30.0
    assert session.command(30.0) == 12.0 and session.state == 'running'
