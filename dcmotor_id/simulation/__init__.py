"""
Exact simulation of the DC motor with the voltage held over each sample (ZOH), with effects.

The package splits by concept: :mod:`~dcmotor_id.simulation.kernels` (the numba hybrid ZOH
kernels), :mod:`~dcmotor_id.simulation.motor` (motor- and shaft-level simulation, the
real-time stepper), :mod:`~dcmotor_id.simulation.coefficients` (:class:`MotorEffects`, the
typed coefficients of the effects and how they combine) and
:mod:`~dcmotor_id.simulation.scenarios` (standard simulated experiments);
:mod:`~dcmotor_id.simulation.compiled` hands the kernels to their callers (ahead-of-time machine
code when the set-up built it, else numba's JIT).  Every public name is
importable from here.
"""

from dcmotor_id.simulation.coefficients import (ADD, combine_contributions, combine_effects,
                                                EXACT_FIELDS, MotorEffects, REPLACE, SENSOR_FIELDS,
                                                set_fields)
from dcmotor_id.simulation.motor import (held_input, HybridSystem, motor_forcing, motor_system,
                                         MotorStepper, simulate_mechanical,
                                         simulate_mechanical_effects,
                                         simulate_motor, simulate_motor_effects, zoh_matrices)

__all__ = [
    'ADD', 'combine_contributions', 'combine_effects', 'EXACT_FIELDS', 'held_input',
    'HybridSystem', 'motor_forcing', 'motor_system', 'MotorEffects', 'MotorStepper', 'REPLACE',
    'SENSOR_FIELDS', 'set_fields', 'simulate_mechanical', 'simulate_mechanical_effects',
    'simulate_motor', 'simulate_motor_effects', 'zoh_matrices',
]
