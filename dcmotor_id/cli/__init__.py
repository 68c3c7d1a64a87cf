"""
Layer 9: the command line.

The command line ``dcmotor-id`` (:mod:`~dcmotor_id.cli.main`; what it shares with the
exciter's ``--plan`` is in :mod:`dcmotor_id.console`, beside it), its status lines on stderr
(:mod:`~dcmotor_id.cli.terminal`), its offline demo (:mod:`~dcmotor_id.cli.demo`) and the
set-up step that compiles the kernels (:mod:`~dcmotor_id.cli.warmup`).
"""
