"""
The experiment plan as a command: ``dcmotor-id plan`` and ``exciter --plan`` (no ROS).

Both take the same options (:func:`add_plan_arguments`) and run :func:`run_plan`: the prior
and the output checked before the work, the memory the simulation asks for checked against
the budget, the D-optimal plan of :func:`dcmotor_id.design.experiment.design_experiment`
printed and, with ``--json``, written for the exciter's ``plan_file``.  Failures raise
:class:`~dcmotor_id.core.errors.InputDataError` (the caller's
:func:`~dcmotor_id.console.command_line.run_reporting` makes them a message, exit code 2).
"""

from __future__ import annotations

import argparse
import os
from typing import TYPE_CHECKING

from dcmotor_id.console.command_line import add_memory_budget, non_negative, positive
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.formats.budget import check_budget, set_memory_budget
from dcmotor_id.formats.json_file import STDOUT, write_result_json
from dcmotor_id.formats.paths import check_input_path, check_output_path

if TYPE_CHECKING:
    from dcmotor_id.design.experiment import Plan

__all__ = ['add_plan_arguments', 'make_plan', 'PLAN_BYTES_PER_SAMPLE', 'plan_parser',
           'run_plan']

#: Peak memory of ``plan`` per simulated sample [bytes] (measured: 190 B, rounded up).
PLAN_BYTES_PER_SAMPLE = 200.0
#: Peak memory of ``plan`` per command of the routine [bytes] (its profile and hold index).
PLAN_BYTES_PER_COMMAND = 64.0


def add_plan_arguments(plan: argparse.ArgumentParser) -> None:
    """Add the options of the plan (the CLI contract of ``dcmotor-id plan``) to a parser."""
    plan.add_argument('--prior', default='paper2', metavar='SOURCE',
                      help='prior parameters: paper1, paper2, a result JSON or a datasheet '
                           'JSON/YAML with Ra, La, CPhi, J, b, Mc (default paper2)')
    for name, default, unit in (('voltage-limit', 48.0, 'V'), ('current-limit', 10.0, 'A'),
                                ('speed-limit', 100.0, 'RAD_S'), ('duration', 10.0, 'S'),
                                ('rate', 200.0, 'HZ'), ('sample-period', 1e-3, 'S')):
        plan.add_argument(f'--{name}', type=positive, default=default, metavar=unit)
    plan.add_argument('--ramp-in', type=non_negative, default=1.0, metavar='S')
    plan.add_argument('--noise-current', type=positive, metavar='A',
                      help='current noise std (default: from a result file, else 0.01)')
    plan.add_argument('--noise-speed', type=positive, metavar='RAD_S',
                      help='speed noise std (default: from a result file, else 0.02)')
    plan.add_argument('--parameters', default='Ra,La,CPhi,J,b,Mc',
                      help='parameters of the D-criterion, comma-separated')
    plan.add_argument('--kinds', default='prbs,multisine', help='prbs and/or multisine')
    plan.add_argument('--margin', type=positive, default=0.9,
                      help='share of the current/speed limits the simulation may reach')
    plan.add_argument('--seed', type=int, default=0)
    plan.add_argument('--json', metavar='OUT',
                      help='write the plan here (exciter plan_file; - : on stdout)')
    add_memory_budget(plan)


def plan_parser() -> argparse.ArgumentParser:
    """Return a parser of the plan's options alone (``exciter --plan``)."""
    parser = argparse.ArgumentParser(prog='dcmotor-id plan')
    add_plan_arguments(parser)
    return parser


def make_plan(args: argparse.Namespace) -> Plan:
    """
    Return the plan of the parsed options, after checking the prior, the output and memory.

    Raises
    ------
    InputDataError
        A prior or output path that cannot be used, a plan beyond the memory budget, or
        options the design refuses (naming the option and what to do).

    """
    from dcmotor_id.design.experiment import DEFAULT_NOISE, design_experiment, load_prior
    from dcmotor_id.design.routines import Limits
    if os.path.exists(args.prior) or os.path.islink(args.prior):
        check_input_path(args.prior, '--prior ')
    if args.json and args.json != STDOUT:
        check_output_path(args.json, '--json', inputs=[args.prior])
    set_memory_budget(args.memory_budget * 1e9)
    samples = args.duration / args.sample_period
    check_budget(PLAN_BYTES_PER_SAMPLE * samples, f'--duration {args.duration:g}',
                 f'{samples:.3g} samples at --sample-period {args.sample_period:g} s',
                 'else give a shorter --duration or a longer --sample-period')
    commands = args.duration * args.rate
    check_budget(PLAN_BYTES_PER_COMMAND * commands, f'--rate {args.rate:g}',
                 f'{commands:.3g} commands over --duration {args.duration:g} s',
                 'else give a lower --rate (a drive takes 100 Hz to 10 kHz)')
    if args.ramp_in >= args.duration:
        raise InputDataError(f'--ramp-in {args.ramp_in:g} s is not shorter than --duration '
                             f'{args.duration:g} s: the routine would never reach its '
                             'amplitude; give a ramp-in of a tenth of the duration or less')
    prior, noise = load_prior(args.prior)
    noise = dict(noise or DEFAULT_NOISE)
    noise.update({key: value for key, value in (('current', args.noise_current),
                                                ('speed', args.noise_speed)) if value})
    try:
        return design_experiment(
            prior, Limits(args.voltage_limit, args.current_limit, args.speed_limit), noise,
            args.duration, args.kinds.split(','), args.parameters.split(','), args.rate,
            args.ramp_in, args.sample_period, args.margin, args.seed)
    except ValueError as error:
        raise InputDataError(str(error)) from None


def run_plan(args: argparse.Namespace) -> int:
    """Print the plan of the parsed options, write it to ``--json`` if given; return 0."""
    plan = make_plan(args)
    print(plan.describe())
    if args.json:
        # (``-``: on the real stdout the command line kept; the rest goes to stderr)
        write_result_json(args.json, plan.as_dict(), getattr(args, 'json_stream', None))
        if args.json != STDOUT:
            print(f'plan written to {args.json} (exciter -p plan_file:={args.json})')
    return 0
