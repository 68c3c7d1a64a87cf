"""
Fleet mode: identify many recordings on a Dask cluster into a per-motor Parquet history.

:func:`run_fleet` (``dcmotor-id fleet``) finds the recordings (:mod:`.sources`), cuts every
motor's streams into windows (:mod:`.windows`), identifies each window as one Dask task
(:mod:`.tasks`, :mod:`.job`) and appends one row per window to the history
(:mod:`.history`). :func:`dcmotor_id.reports.fleet.write_fleet_report`
(``dcmotor-id fleet-report``) turns the history into trends, change alarms
(:mod:`.trends`) and a fleet overview.
"""

from dcmotor_id.fleet.history import known_sources, read_history, SCHEMA
from dcmotor_id.fleet.job import FleetSummary, run_fleet, start_client
from dcmotor_id.fleet.sources import find_sources, motor_streams, namespace_of, Source
from dcmotor_id.fleet.tasks import FleetOptions

__all__ = ['find_sources', 'FleetOptions', 'FleetSummary', 'known_sources', 'motor_streams',
           'namespace_of', 'read_history', 'run_fleet', 'SCHEMA', 'Source', 'start_client']
