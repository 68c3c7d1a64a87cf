"""
Layer 6: identification while samples arrive (no ROS here; the nodes adapt it).

:mod:`~dcmotor_id.streaming.windowing` cuts aligned samples into windows,
:mod:`~dcmotor_id.streaming.input_health` watches the channels,
:mod:`~dcmotor_id.streaming.worker` fits windows off the executor thread,
:mod:`~dcmotor_id.streaming.online` holds the online estimators,
:mod:`~dcmotor_id.streaming.monitoring` turns estimates into alarms and
:mod:`~dcmotor_id.streaming.summary` formats results for people and diagnostics.
"""
