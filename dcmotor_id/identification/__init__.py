"""
Layer 4: identifying the motor from records (no ROS).

:mod:`~dcmotor_id.identification.identify` runs the pipeline as named stages (listed in its
docstring; the details of each stage in a module of its own, e.g.
:mod:`~dcmotor_id.identification.second_start`, its result in
:mod:`~dcmotor_id.identification.result`): the checks of the data, an estimator of
:mod:`~dcmotor_id.identification.estimators` (all behind one ``Estimator`` interface), the
checks of the answer (the checks in one place, :mod:`~dcmotor_id.identification.checks`, which
says which runs when), the residual analysis
(:mod:`~dcmotor_id.identification.residuals`) and the effect discovery loop
(:mod:`~dcmotor_id.identification.discovery`) over the effect vocabulary
(:mod:`~dcmotor_id.identification.effects`, one module per effect).
:mod:`~dcmotor_id.identification.validate` simulates a model on records it was not fitted on.
"""
