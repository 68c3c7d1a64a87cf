"""
Standard simulated experiments: the paper's training sets (used by tests, benchmarks, demos).

The paper trained its neuron N1 on a 0.5 Hz 110 V sine and N2 on a 1 Hz 43 V sawtooth
(:data:`~dcmotor_id.simulation.excitation.PAPER_SINE`,
:data:`~dcmotor_id.simulation.excitation.PAPER_SAWTOOTH`);
:func:`paper_records` simulates both with the exact simulator and adds sensor noise.
"""

from __future__ import annotations

import numpy as np

from dcmotor_id.core.model import MotorParameters
from dcmotor_id.core.records import Record
from dcmotor_id.simulation.excitation import (add_sensor_noise, make_excitation, PAPER_SAWTOOTH,
                                              PAPER_SINE)
from dcmotor_id.simulation.motor import simulate_motor

#: Sample period of the paper's experiments [s].
SAMPLE_PERIOD_S = 1e-4
#: Length of each training set [s].
DURATION_S = 4.0


def paper_records(params: MotorParameters, noise: float, seed: int = 0,
                  sample_period_s: float = SAMPLE_PERIOD_S,
                  duration_s: float = DURATION_S) -> list[Record]:
    """
    Simulate the paper's two training sets (sine for N1, sawtooth for N2) with noise.

    Parameters
    ----------
    params : MotorParameters
        The motor.
    noise : float
        White sensor noise on current and speed, relative to each signal's standard deviation.
    seed : int
        Seed of the noise generator.
    sample_period_s, duration_s : float
        Sample period and length of each record [s].

    Returns
    -------
    list of Record
        The sine record, then the sawtooth record.

    """
    rng = np.random.default_rng(seed)
    records = []
    for spec in (PAPER_SINE, PAPER_SAWTOOTH):
        t, voltage = make_excitation(spec['kind'], duration_s, sample_period_s,
                                     amplitude_v=spec['amplitude_v'],
                                     frequency_hz=spec['frequency_hz'])
        current, speed = simulate_motor(params, voltage, sample_period_s)
        records.append(Record(t, add_sensor_noise(current, noise, rng), voltage,
                              add_sensor_noise(speed, noise, rng), source=spec['kind']))
    return records
