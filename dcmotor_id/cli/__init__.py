"""
Layer 9: the command line.

The command line ``dcmotor-id`` (:mod:`~dcmotor_id.cli.main`), its offline demo
(:mod:`~dcmotor_id.cli.demo`) and the set-up step that compiles the kernels
(:mod:`~dcmotor_id.cli.warmup`).
"""
