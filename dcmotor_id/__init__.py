"""
Identify the physical parameters of a separately excited DC motor.

``Ra``, ``La``, ``CPhi``, ``J``, ``b``, ``Mc`` (and ``Ka = 1/Ra``, ``Ta = La/Ra``) from measured
voltage, current and speed (or position), offline from files and online in ROS 2.

The public surface is small and importable from here; each name lives in one module of the
layers below.  A first example, a simulated record identified exactly:

>>> import numpy as np
>>> import dcmotor_id as dm
>>> true = dm.PAPER_MOTORS['paper2']
>>> t = np.arange(0.0, 3.0, 1e-3)
>>> voltage = 60.0 * np.sign(np.sin(2 * np.pi * 1.5 * t)) + 20.0 * np.sin(2 * np.pi * 7 * t)
>>> current, speed = dm.simulate_motor(true, voltage, 1e-3)
>>> record = dm.Record(t, current=current, voltage=voltage, speed=speed)
>>> result = dm.identify([record], discover=False)
>>> errors = dm.relative_errors_pct(result.parameters, true)
>>> bool(max(abs(e) for e in errors.values()) < 1e-6)
True

Layers
------
The subpackages are the architecture, one floor per layer; a package imports only from its own
floor and the floors below (:data:`LAYERS`, bottom first; ``test/test_layers.py`` checks it).

1. :mod:`~dcmotor_id.core`: the model's names, units and admissibility; records; errors;
   progress and time budget.
2. :mod:`~dcmotor_id.signals.filters` (filters, derivatives) and :mod:`~dcmotor_id.simulation`
   (the exact ZOH motor simulation, its compiled kernels, excitations, scenarios).
3. :mod:`~dcmotor_id.formats`: every file format behind one reader, stream alignment, bag
   recording.
4. :mod:`~dcmotor_id.identification`: estimators, effects, residual analysis, discovery, the
   checks of the data and the answer, validation, and the :func:`identify` pipeline.
5. :mod:`~dcmotor_id.design`: experiments, the exciter's routines, controller design,
   export.
6. :mod:`~dcmotor_id.streaming`: windows, channel health, the fit worker, online estimators,
   monitoring, summaries.
7. :mod:`~dcmotor_id.fleet`: many motors' recordings on Dask, their history and trends.
8. :mod:`~dcmotor_id.reports`: the HTML reports.
9. :mod:`~dcmotor_id.cli.main`: the ``dcmotor-id`` command line, and beside it
   :mod:`~dcmotor_id.console`: what every program's command line shares (argument types, exit
   codes, the plan as a command; ``exciter --plan`` uses it too).
10. :mod:`~dcmotor_id.nodes`: the ROS 2 nodes (the only part that imports rclpy).
"""

from __future__ import annotations

from typing import Any

from dcmotor_id.core.lazy import bind, LazyNames

#: The layers, bottom first: a subpackage imports only from its own layer and those below.
LAYERS: tuple[tuple[str, ...], ...] = (
    ('core',), ('signals', 'simulation'), ('formats',), ('identification',), ('design',),
    ('streaming',), ('fleet',), ('reports',), ('cli', 'console'), ('nodes',))

#: Public name -> the module that defines it (imported on first use, PEP 562, so that the
#: command line does not pay for what it does not run).
_HOME = {
    'MotorParameters': 'core.model', 'PAPER_MOTORS': 'core.model',
    'PARAMETER_NAMES': 'core.model', 'relative_errors_pct': 'core.model',
    'Record': 'core.records',
    'DcMotorIdError': 'core.errors', 'InputDataError': 'core.errors',
    'NotIdentifiableError': 'core.errors', 'FitError': 'core.errors',
    'Progress': 'core.progress',
    'simulate_motor': 'simulation', 'simulate_motor_effects': 'simulation',
    'MotorStepper': 'simulation',
    'read_record': 'formats', 'read_records': 'formats', 'ReadOptions': 'formats',
    'identify': 'identification.identify',
    'IdentificationResult': 'identification.result',
    'make_effect': 'identification.effects', 'parse_effect': 'identification.effects',
    'load_model': 'identification.validate', 'validate': 'identification.validate',
    'design_controller': 'design.control',
    'make_estimator': 'streaming.online', 'OnlineEstimator': 'streaming.online',
}

_NAMES = LazyNames(__name__, _HOME)
# IdentificationResult.design hands the result to the controller design one floor up.
bind('design_controller', f'{__name__}.design.control:design_controller')
__all__ = _NAMES.names


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use."""
    return _NAMES.load(name)


def __dir__() -> list[str]:
    """List the public names."""
    return list(__all__)
