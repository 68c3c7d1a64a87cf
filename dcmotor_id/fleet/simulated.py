"""
A simulated fleet for tests and the benchmark: motors of several sizes, some of them aging.

Every motor is one of three types (the paper's two motors and a small 24 V motor) with its
parameters drawn within about 15 % of the type's, recorded several times (``recordings``,
one day apart) as real MCAP bags by the project's writer
(:func:`dcmotor_id.formats.bag.write_bag`), its topics in the motor's namespace
(``/<motor>/voltage``, ``current``, ``speed``). An aging motor's armature resistance rises
(+30 % at its last recording), its friction rises (b +60 %, Mc +40 %) and a load torque
(a third of its original Coulomb friction) appears from the middle recording on; the healthy
ones stay as they are. The simulation is the exact one (:func:`~dcmotor_id.simulation.
simulate_motor`), with white sensor noise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import os
from typing import Optional

import numpy as np

from dcmotor_id.core.model import MotorParameters, PAPER_MOTORS
from dcmotor_id.simulation.excitation import add_sensor_noise, make_excitation

#: A small 24 V permanent-magnet motor (about 50 W).
SMALL_24V = MotorParameters(Ra=1.2, La=1.5e-3, CPhi=0.05, J=2e-5, b=1e-5, Mc=0.01)
#: Motor types: parameters and the excitation amplitude [V].
TYPES = {'paper1': (PAPER_MOTORS['paper1'], 40.0), 'paper2': (PAPER_MOTORS['paper2'], 60.0),
         'small24v': (SMALL_24V, 12.0)}
#: Aging at the last recording: relative rise of Ra, b and Mc.
AGING = {'Ra': 0.30, 'b': 0.60, 'Mc': 0.40}
#: Load torque of an aging motor from its middle recording on, in units of its original Mc.
AGING_LOAD = 1.0 / 3.0
#: First recording's time [ns] (2025-01-01 UTC), recordings one day apart.
EPOCH_NS = 1_735_689_600_000_000_000
DAY_NS = 86_400_000_000_000


@dataclass(frozen=True)
class SimulatedMotor:
    """
    One motor of the simulated fleet.

    Attributes
    ----------
    motor_id : str
        Its name (the namespace of its topics).
    kind : str
        Its type (a key of :data:`TYPES`).
    params : MotorParameters
        Its parameters when new.
    amplitude_v : float
        Excitation amplitude [V].
    aging : bool
        Whether it ages over its recordings.

    """

    motor_id: str
    kind: str
    params: MotorParameters
    amplitude_v: float
    aging: bool

    def at(self, recording: int, recordings: int) -> tuple[MotorParameters, float]:
        """Return its parameters and the load torque [N m] at a recording (0, 1, ...)."""
        if not self.aging or recordings < 2:
            return self.params, 0.0
        share = recording / (recordings - 1)
        params = replace(self.params, **{name: getattr(self.params, name) * (1 + rise * share)
                                         for name, rise in AGING.items()})
        load = AGING_LOAD * self.params.Mc if recording >= recordings // 2 else 0.0
        return params, load


def make_fleet(motors: int, aging_share: float = 0.1, seed: int = 0) -> list[SimulatedMotor]:
    """Draw ``motors`` motors, every ``1/aging_share``-th of them aging (spread over types)."""
    rng = np.random.default_rng(seed)
    kinds = sorted(TYPES)
    step = int(round(1.0 / aging_share)) if aging_share > 0 else 0
    fleet = []
    for number in range(motors):
        kind = kinds[number % len(kinds)]
        base, amplitude = TYPES[kind]
        factors = np.exp(rng.normal(0.0, 0.08, size=6).clip(-0.15, 0.15))
        params = MotorParameters(*(value * factor for value, factor in zip(
            (base.Ra, base.La, base.CPhi, base.J, base.b, base.Mc), factors)))
        aging = bool(step) and number % step == step // 2
        fleet.append(SimulatedMotor(f'm{number:03d}', kind, params, amplitude, aging))
    return fleet


def write_recording(directory: str, motor: SimulatedMotor, recording: int, recordings: int,
                    duration_s: float = 60.0, sample_period_s: float = 1e-3,
                    noise: float = 0.005, seed: Optional[int] = None) -> str:
    """
    Simulate one recording of a motor and write it as an MCAP bag; return the bag's path.

    The bag is ``<directory>/<motor>/rec_<recording>`` with the topics ``/<motor>/voltage``,
    ``/<motor>/current`` and ``/<motor>/speed``, stamped from ``EPOCH_NS`` plus a day per
    recording. The excitation is a multisine (0.2-20 Hz) whose phases change per recording.
    """
    from dcmotor_id.formats.bag import write_bag
    from dcmotor_id.simulation import simulate_motor

    params, load = motor.at(recording, recordings)
    rng = np.random.default_rng(seed if seed is not None else
                                hash((motor.motor_id, recording)) % 2 ** 32)
    _, voltage = make_excitation('multisine', duration_s, sample_period_s,
                                 amplitude_v=motor.amplitude_v,
                                 frequency_hz=0.2 * (1 + 0.1 * rng.random()),
                                 max_frequency_hz=20.0)
    torque = np.full(voltage.size, -load) if load else None
    current, speed = simulate_motor(params, voltage, sample_period_s, extra_torque=torque)
    current = add_sensor_noise(current, noise, rng)
    speed = add_sensor_noise(speed, noise, rng)
    stamps = EPOCH_NS + recording * DAY_NS + \
        np.arange(voltage.size, dtype=np.int64) * int(round(sample_period_s * 1e9))
    path = os.path.join(directory, motor.motor_id, f'rec_{recording:02d}')
    namespace = f'/{motor.motor_id}'
    write_bag(path, stamps, {'voltage': voltage, 'current': current, 'speed': speed},
              topics={channel: f'{namespace}/{channel}'
                      for channel in ('voltage', 'current', 'speed')})
    return path
