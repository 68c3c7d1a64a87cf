"""
Layer 9, beside :mod:`dcmotor_id.cli`: what every program's command line shares.

Two programs take options on a command line: ``dcmotor-id`` (:mod:`dcmotor_id.cli`) and the
exciter node's ``exciter --plan`` (:mod:`dcmotor_id.nodes.exciter`). They share the argument
types and the exit codes of failures (:mod:`~dcmotor_id.console.command_line`) and the plan as
a command (:mod:`~dcmotor_id.console.plan`); a node never imports the ``dcmotor-id`` program
itself.
"""
