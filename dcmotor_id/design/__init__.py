"""
Layer 5: designing experiments and controllers from an identified model (no ROS).

:mod:`~dcmotor_id.design.experiment` (plans an excitation for a target accuracy; as a
command in :mod:`dcmotor_id.console.plan`), :mod:`~dcmotor_id.design.routines` (the
exciter's safe routines), :mod:`~dcmotor_id.design.control` (cascaded current and speed PI
design with python-control, from :mod:`~dcmotor_id.design.plant` through
:mod:`~dcmotor_id.design.loops`) and :mod:`~dcmotor_id.design.export` (the gains as files for
drives).
"""
