"""The install step's numba warm-up: every step runs on its synthetic data."""

from dcmotor_id.warmup import warm_up


def test_every_warm_up_step_runs(tmp_path):
    steps = [name for name, seconds in warm_up(str(tmp_path)) if seconds >= 0.0]
    assert steps[:2] == ['simulate', 'simulate with effects']
    assert {'identify with discovery', 'identify, mechanical mode', 'identify, paper method',
            'online estimator', 'sim_motor stepper'} <= set(steps)
    written = {path.name for path in tmp_path.iterdir()}
    assert written >= {'plain.csv', 'effects.csv', 'mechanical.csv', 'result.json'}
