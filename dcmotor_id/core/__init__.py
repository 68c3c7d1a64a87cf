"""
Layer 1, the ground floor: what every other part of the package speaks.

:mod:`~dcmotor_id.core.model` (the parameters' names, units, derived values and
admissibility), :mod:`~dcmotor_id.core.records` (a measured record), the error classes
(:mod:`~dcmotor_id.core.errors`), the time budget and progress report
(:mod:`~dcmotor_id.core.progress`), the registry of the checks of the data and the answer
(:mod:`~dcmotor_id.core.checks`, where every layer registers its own) and the BLAS thread
limit (:mod:`~dcmotor_id.core.blas`).
Imports nothing else of the package; what only the command lines need (argument types, exit
codes, the terminal's status lines) is in :mod:`dcmotor_id.console` and :mod:`dcmotor_id.cli`.
"""
