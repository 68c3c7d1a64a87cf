"""
Layer 8: the HTML reports with their plots (matplotlib).

:mod:`~dcmotor_id.reports.identification` (``dcmotor-id identify --report``; its figures
in :mod:`~dcmotor_id.reports.identification_plots`),
:mod:`~dcmotor_id.reports.design` (``dcmotor-id design --report``) and
:mod:`~dcmotor_id.reports.fleet` (``dcmotor-id fleet-report``).
"""
