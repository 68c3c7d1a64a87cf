"""
The stages of :func:`~dcmotor_id.identification.identify.identify`, one module each.

In the order they run: the current-limited path
(:mod:`~dcmotor_id.identification.pipeline.current_limited`), the base fit and what a fit gives
(:mod:`~dcmotor_id.identification.pipeline.fit_outcome`), the armature
(:mod:`~dcmotor_id.identification.pipeline.armature`), the start check (further starts of the
base, :mod:`~dcmotor_id.identification.pipeline.further_starts`, and a second start,
:mod:`~dcmotor_id.identification.pipeline.second_start`), the choice of the position error's
model (:mod:`~dcmotor_id.identification.pipeline.position_error`) and the held-out errors
(:mod:`~dcmotor_id.identification.pipeline.heldout`).
"""
