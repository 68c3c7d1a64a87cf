"""The install step's numba warm-up: every step runs on its synthetic data."""

import pytest

from dcmotor_id.cli.warmup import warm_up


def test_every_warm_up_step_runs(tmp_path):
    steps = [name for name, seconds in warm_up(str(tmp_path)) if seconds >= 0.0]
    assert steps[:3] == ['ahead-of-time kernels', 'simulate', 'simulate with effects']
    assert {'identify with discovery', 'identify, mechanical mode', 'identify on the position',
            'identify, paper method', 'online estimator', 'sim_motor stepper'} <= set(steps)
    written = {path.name for path in tmp_path.iterdir()}
    assert written >= {'plain.csv', 'effects.csv', 'mechanical.csv', 'position.csv',
                       'result.json'}


def test_ahead_of_time_kernels_equal_the_jit_ones(monkeypatch):
    import numpy as np

    from dcmotor_id.core.model import PAPER_MOTORS
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.identify import identify, prepare_records
    from dcmotor_id.simulation import compiled, simulate_motor
    if compiled.built_path() is None:
        pytest.skip('no ahead-of-time module (the warm-up builds it)')
    rng = np.random.default_rng(5)
    dt = 1e-3
    t = np.arange(3000) * dt
    voltage = 60.0 * np.sign(np.sin(2.0 * np.pi * 1.3 * t)) + 10.0 * rng.standard_normal(t.size)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, dt)
    record = Record(t, current + 0.02 * rng.standard_normal(t.size), voltage,
                    speed + 0.05 * rng.standard_normal(t.size))
    results = []
    for jit_only in ('', '1'):
        monkeypatch.setenv('DCMOTOR_ID_JIT_ONLY', jit_only)
        monkeypatch.setattr(compiled, '_loaded', {})
        assert ('CPUDispatcher' in type(compiled.kernel('normal_kernel')).__name__) == \
            bool(jit_only)
        result = identify(prepare_records([record]))
        results.append((result.parameters, result.stderr))
    assert results[0] == results[1]
