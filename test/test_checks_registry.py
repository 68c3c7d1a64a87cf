"""The checks of the data and of the answer: one protocol, one registry, five homes (issue 28)."""

import importlib

import pytest

from dcmotor_id.core.checks import (Check, DataCheck, LOOKS_AT, register, registered,
                                    registered_check, WHEN)

#: The homes of the checks, each registering its own where they are written.
HOMES = ('dcmotor_id.core.records', 'dcmotor_id.formats.quality',
         'dcmotor_id.identification.prepare', 'dcmotor_id.identification.checks.dropouts',
         'dcmotor_id.identification.checks.identifiability',
         'dcmotor_id.identification.checks.start', 'dcmotor_id.identification.checks.units',
         'dcmotor_id.identification.checks.plausibility',
         'dcmotor_id.identification.checks.input_noise', 'dcmotor_id.streaming.input_health')


@pytest.fixture(scope='module')
def checks():
    """Every registered check, once all the homes are imported."""
    for home in HOMES:
        importlib.import_module(home)
    return registered()


def test_every_home_registers_its_checks_at_their_time(checks):
    assert {check.home for check in checks} >= set(HOMES)
    for check in checks:
        assert isinstance(check, DataCheck)
        assert check.when in WHEN and check.looks_at in LOOKS_AT and check.says
        assert getattr(importlib.import_module(check.home), check.run.__name__) is check.run
    # Each time has its checks, and the registry answers by time and subject.
    assert {check.when for check in checks} == set(WHEN)
    assert registered_check('excitation').when == 'before_fit'
    assert registered_check('pwm_sampled_current') in registered('read', 'record')
    assert registered_check('batch').home == 'dcmotor_id.streaming.input_health'
    assert registered_check('plausibility') in registered('after_fit')


def test_a_check_names_a_known_time_and_a_free_name(checks):
    with pytest.raises(ValueError, match='when'):
        Check('late', 'during_the_fit', 'fit', print, 'never')
    with pytest.raises(ValueError, match='looks at'):
        Check('odd', 'read', 'file', print, 'never')
    with pytest.raises(ValueError, match='already registered'):
        register(Check('excitation', 'before_fit', 'records', print, 'another'))
    again = registered_check('units')
    assert register(again) is again  # a module imported twice registers the same check
    with pytest.raises(KeyError, match='excitation'):
        registered_check('no such check')
