"""
Layer 1, the ground floor: what every other part of the package speaks.

:mod:`~dcmotor_id.core.model` (the parameters' names, units, derived values and
admissibility), :mod:`~dcmotor_id.core.records` (a measured record), the error classes
(:mod:`~dcmotor_id.core.errors`), the time budget and progress line
(:mod:`~dcmotor_id.core.progress`), the BLAS thread limit (:mod:`~dcmotor_id.core.blas`) and
what every command-line entry point shares (:mod:`~dcmotor_id.core.command_line`).
Imports nothing else of the package.
"""
