"""The final fit simulated once over its records, its simulation handed on (issue 29, speed)."""

import numpy as np

from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.records import Record
from dcmotor_id.identification.error_model.residuals import simulated
from dcmotor_id.identification.estimators import refined
from dcmotor_id.identification.estimators.refined import OutputErrorModel
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.simulation import simulate_motor
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

VALUES = PAPER_MOTORS['paper2'].as_dict(derived=False)


def _record(duration_s=6.0, dt=1e-3, seed=0):
    t, voltage = make_excitation('paper', duration_s, dt)
    current, speed = simulate_motor(PAPER_MOTORS['paper2'], voltage, dt)
    rng = np.random.default_rng(seed)
    return Record(t, add_sensor_noise(current, 0.01, rng), voltage,
                  add_sensor_noise(speed, 0.01, rng))


def test_a_carried_simulation_is_given_back_only_for_the_same_model_values_and_states():
    record = _record(1.0)
    states = [[0.0, 0.0]]
    model = OutputErrorModel([record])
    ran = simulated(model, VALUES, states)
    # Another model object on the same record objects simulates alike (its criterion aside).
    assert simulated(OutputErrorModel([record], criterion='speed'), dict(VALUES),
                     [np.array([0.0, 0.0])], ran) is ran
    for other, values, initial in (
            (OutputErrorModel([_record(1.0)]), VALUES, states),  # equal data, other record
            (OutputErrorModel([record], torque_constant=0.3), VALUES, [[0.0]]),
            (OutputErrorModel([record], quasi_static=True), VALUES, states),
            (model, {**VALUES, 'b': VALUES['b'] * (1 + 1e-15)}, states),
            (model, VALUES, [[0.0, 1e-12]])):
        fresh = simulated(other, values, initial, ran)
        assert fresh is not ran
        expected = other.simulate(values, 0, np.array(initial[0], dtype=float))
        for channel, out in fresh.outputs[0].items():
            np.testing.assert_array_equal(out, expected[channel])


def test_identify_simulates_the_final_fit_over_the_record_twice_not_eight_times(monkeypatch):
    calls = []
    own = refined.OutputErrorModel.simulate

    def counted(self, values, index, initial_state):
        calls.append((dict(values), tuple(np.asarray(initial_state, dtype=float))))
        return own(self, values, index, initial_state)
    monkeypatch.setattr(refined.OutputErrorModel, 'simulate', counted)
    result = identify(prepare_records([_record()]))
    final = {name: value for name, value in result.parameters.items() if name in VALUES}
    of_final = [values for values, _ in calls
                if all(values.get(name) == value for name, value in final.items())]
    # The base fit stage's simulation (its errors), handed on to the start checks, the final
    # fit and the held-out stage; the regression floor's comparison simulates it once more.
    # Before, each of them simulated it again: 8 in all.
    assert len(of_final) == 2
