"""A notebook-friendly result (issue 31): ``plot()`` gives matplotlib Figures, ``_repr_html_``."""

from matplotlib.figure import Figure
import numpy as np
import pytest

import dcmotor_id as dm

DT = 1e-3


@pytest.fixture(scope='module')
def signals():
    """Return time, voltage, current and speed of paper motor 2 (3 s, exact)."""
    t = np.arange(0.0, 3.0, DT)
    voltage = 60.0 * np.sign(np.sin(2 * np.pi * 1.5 * t)) + 20.0 * np.sin(2 * np.pi * 7 * t)
    current, speed = dm.simulate_motor(dm.PAPER_MOTORS['paper2'], voltage, DT)
    return t, voltage, current, speed


def test_plot_draws_measured_and_simulated_channels(signals):
    t, voltage, current, speed = signals
    result = dm.identify([dm.Record(t, current, voltage, speed, source='run <1>')],
                         discover=False)
    figures = result.plot()
    assert len(figures) == 2 and all(isinstance(figure, Figure) for figure in figures)
    fit, residual = figures
    assert len(fit.axes) == 2 and len(residual.axes) == 2  # current and speed
    for axes, measured in zip(fit.axes, (current, speed)):
        drawn_measured, drawn_model = axes.get_lines()
        np.testing.assert_array_equal(drawn_measured.get_ydata(), measured)
        np.testing.assert_allclose(drawn_model.get_ydata(), measured, atol=1e-6)
    for axes in residual.axes:
        assert np.max(np.abs(axes.get_lines()[0].get_ydata())) < 1e-6
    page = result._repr_html_()
    assert '<table>' in page and '<td>CPhi</td>' in page and '<td>0.7</td>' in page


def test_plot_of_a_voltage_speed_result(signals):
    t, voltage, _, speed = signals
    noisy = speed + 0.01 * np.random.default_rng(0).standard_normal(speed.size)
    result = dm.identify([dm.Record(t, voltage=voltage, speed=noisy)])
    fit, residual = result.plot()  # the fitted model, armature lag included
    assert len(fit.axes) == 1 and 'first-order' not in fit.get_suptitle()
    drawn = fit.axes[0].get_lines()[1].get_ydata()
    assert np.sqrt(np.mean((drawn - speed) ** 2)) < 0.001 * np.std(speed)
    from dcmotor_id.identification.figures import result_figures
    from_json, _ = result_figures(result.as_dict(), result.input_records)
    # from the JSON alone: the model block carries the armature lag, simulated with it
    again = from_json.axes[0].get_lines()[1].get_ydata()
    assert result.as_dict()['model']['armature_lag'] is not None
    assert np.sqrt(np.mean((again - speed) ** 2)) < 0.002 * np.std(speed)
    page = result._repr_html_()
    assert '<td>kA</td>' in page and 'not separable without the current' in page


def test_html_escapes_text():
    result = {'method': 'refined', 'mode': 'full', 'n_samples': 1,
              'parameters': {'Ra': 1.0}, 'stderr': {'Ra': None}, 'units': {'Ra': 'Ohm'},
              'warnings': ['<script>'], 'effects': [], 'not_identifiable': {}}
    from dcmotor_id.identification.figures import result_html
    page = result_html(result)
    assert '<script>' not in page and '&lt;script&gt;' in page and 'n/a' in page
