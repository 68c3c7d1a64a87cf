"""
Layer 4: identifying the motor from records (no ROS).

:mod:`~dcmotor_id.identification.identify` runs the pipeline as named stages (listed in its
docstring; the details of each stage in a module of its own, e.g.
:mod:`~dcmotor_id.identification.pipeline.second_start`, its result in
:mod:`~dcmotor_id.identification.result`): the checks of the data, an estimator of
:mod:`~dcmotor_id.identification.estimators` (all behind one ``Estimator`` interface), the
checks of the answer (the checks in one place, :mod:`~dcmotor_id.identification.checks`, which
says which runs when), the residual analysis
(:mod:`~dcmotor_id.identification.error_model.residuals`, the error model's home) and the effect
discovery loop
(:mod:`~dcmotor_id.identification.discovery`) over the effect vocabulary
(:mod:`~dcmotor_id.identification.effects`, one module per effect).
:mod:`~dcmotor_id.identification.validate` simulates a model on records it was not fitted on.
"""

#: The layers inside, bottom first: a module imports only from its own layer and those below
#: (``test/test_layers.py``).  The error model
#: (:mod:`~dcmotor_id.identification.error_model`: the criterion, the sensor noise, residuals
#: and their analysis); the estimators; the effect vocabulary; the checks of the data and of the
#: answer, the preparation of records and the validation; the discovery loop; the stages of
#: the pipeline (:mod:`~dcmotor_id.identification.pipeline`) and the result;
#: :func:`~dcmotor_id.identification.identify.identify`, which runs them.
LAYERS: tuple[tuple[str, ...], ...] = (
    ('error_model',),
    ('estimators',),
    ('effects',),
    ('checks', 'prepare', 'validate'),
    ('discovery',),
    ('figures', 'result', 'structure_uncertainty'),
    ('pipeline',),
    ('identify',),
)
