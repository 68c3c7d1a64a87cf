"""The identifier's online_method offers every online estimator of the table (issue 28)."""

import dataclasses
import runpy

from dcmotor_id.nodes import settings
from dcmotor_id.streaming.online import base


def _choices(settings_class):
    fields = {field.name: field for field in dataclasses.fields(settings_class)}
    return fields['online_method'].metadata['choices']


def test_a_new_online_estimator_is_one_module_and_one_table_line(monkeypatch):
    assert _choices(settings.IdentifierSettings) == base.METHODS == ('window', 'rls')
    monkeypatch.setitem(base.ESTIMATORS, 'slow_rls', ('slow_rls', 'SlowRlsEstimator'))
    monkeypatch.setattr(base, 'METHODS', tuple(base.ESTIMATORS))
    # The settings module run again (apart from the imported one): the node takes the new
    # estimator with no third file to edit.
    fresh = runpy.run_path(settings.__file__)
    assert 'slow_rls' in _choices(fresh['IdentifierSettings'])
