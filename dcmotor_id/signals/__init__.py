"""
Layer 2: signal processing of measured channels (no ROS, no model).

:mod:`~dcmotor_id.signals.filters`: zero-phase Butterworth filters, noise levels, numerical
derivatives and integrals, speed from an encoder position.
"""
