"""What a fit gives, measured once: refused when non-physical, its errors carried (issue 28)."""

from types import SimpleNamespace

import numpy as np
import pytest

from dcmotor_id.core.errors import FitError
from dcmotor_id.core.records import Record, record_names
from dcmotor_id.identification.estimators.base import Estimate
from dcmotor_id.identification.pipeline import armature, fit_outcome
from dcmotor_id.identification.pipeline.state import Models

VALUES = {'Ra': 1.0, 'La': 1e-3, 'CPhi': 0.1, 'J': 1e-4, 'b': 1e-5, 'Mc': 1e-3}


def test_physical_errors_refuse_before_simulating_and_measure_once(monkeypatch):
    calls = []
    monkeypatch.setattr(fit_outcome, 'model_errors',
                        lambda *args, **kwargs: calls.append(args) or {'speed_nrmse_pct': 1.0})
    bad = Estimate('refined', {**VALUES, 'J': -1e-4}, {})
    with pytest.raises(FitError, match='non-physical'):
        fit_outcome.physical_errors(bad, None)
    assert not calls
    assert fit_outcome.physical_errors(Estimate('refined', VALUES, {}), None) == {
        'speed_nrmse_pct': 1.0}
    assert len(calls) == 1


def test_the_quasi_static_refit_gives_its_errors_with_it(monkeypatch):
    measured = []

    def errors(model, values, initial_states):
        measured.append((model, values))
        return {'current_nrmse_pct': 1.0, 'speed_nrmse_pct': 2.0}
    quasi = Estimate('refined', VALUES, {})
    monkeypatch.setattr(armature, 'model_errors', errors)
    monkeypatch.setattr(armature, 'RefinedEstimator',
                        lambda **options: SimpleNamespace(fit=lambda records: quasi))
    progress = SimpleNamespace(set_stage=lambda *args: None)
    models = Models([], None, True, 'speed')
    refit = armature.quasi_static_fit(quasi, models, 'estimate', progress)
    assert refit == (quasi, {'current_nrmse_pct': 1.0, 'speed_nrmse_pct': 2.0})
    # measured once on the run's quasi-static base model, carried to the stage's fit
    assert measured == [(models.measured, VALUES)]


def test_records_are_named_for_the_progress_line():
    t = np.arange(3) * 1e-3
    named = [Record(t, current=t, voltage=t, speed=t, source=name) for name in ('a', 'b')]
    assert record_names(named[:1]) == 'a'
    assert record_names(named) == '2 records'
    assert record_names([Record(t, current=t, voltage=t, speed=t)]) is None
