"""
The error model, in one place: what a fit compares and how its errors are weighed.

The bottom layer of :mod:`dcmotor_id.identification` (every estimator, check and stage above
it reads it; it imports nothing of identification):

- :mod:`~dcmotor_id.identification.error_model.criterion`: the channels a fit compares
  (``speed``, ``position`` or ``both``), the sensor noise levels that weigh them, and the
  model of the position error (white or AR(1): :func:`~.criterion.position_ar`,
  :func:`~.criterion.whiten`);
- :mod:`~dcmotor_id.identification.error_model.residuals`: the residuals of a fit, their
  whitening and analysis (Ljung-Box whiteness, predictable share, correlations).

The one decision above it that chooses between the position error's models for a whole
identification (white first, AR(1) when the white run's base is far from the model-free
evidence) is a stage of the pipeline, since it compares two identifications:
:mod:`~dcmotor_id.identification.pipeline.position_error`.
"""
