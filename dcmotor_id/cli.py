"""
The ``dcmotor-id`` command line: offline identification and simulation.

Exit codes: 0 success, 2 bad input or data that cannot identify the motor (with a message
saying what is wrong and what to do), 1 an unexpected failure.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Mapping, Sequence

import numpy as np

from dcmotor_id.effects import EFFECTS, EXTENDED_VOCABULARY, parse_effect
from dcmotor_id.errors import DcMotorIdError, InputDataError
from dcmotor_id.excitation import add_sensor_noise, EXCITATION_KINDS, make_excitation, quantise
from dcmotor_id.formats import read_records
from dcmotor_id.formats.bag import BAG_TOPICS
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.identify import (DEFAULT_MAX_TIME_S, identify, INITIAL_STATES, METHODS,
                                 prepare_records)
from dcmotor_id.model import PAPER_MOTORS
from dcmotor_id.progress import terminal_progress
from dcmotor_id.records import Record
from dcmotor_id.simulation import simulate_motor, simulate_motor_effects
from dcmotor_id.summary import format_table


def load_records(paths: Sequence[str],
                 topics: Mapping[str, str] | None = None) -> list[Record]:
    """Read every input path (CSV files, rosbag2 directories, .mcap or .db3 files)."""
    return read_records(paths, topics=topics)


def _json_safe(value):
    """Replace non-finite floats by None (JSON has no NaN), recursively."""
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def write_json(path: str, result: Mapping[str, Any]) -> None:
    """Write the result as strict JSON, atomically (a temporary file renamed into place)."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    temporary = f'{path}.partial'
    with open(temporary, 'w', encoding='utf-8') as stream:
        json.dump(_json_safe(result), stream, indent=2, allow_nan=False)
    os.replace(temporary, path)


def _cmd_identify(args):
    topics = {'voltage': args.voltage_topic, 'current': args.current_topic,
              'speed': args.speed_topic, 'samples': args.samples_topic}
    records = prepare_records(load_records(args.files, topics), args.torque_constant,
                              args.resample, args.speed_cutoff)
    vocabulary = EXTENDED_VOCABULARY if args.extended_vocabulary else None
    progress = terminal_progress(args.max_time, quiet=args.quiet)
    try:
        identified = identify(records, method=args.method,
                              torque_constant=args.torque_constant,
                              discover=not args.no_discover, vocabulary=vocabulary,
                              progress=progress, initial_state=args.initial_state)
    finally:
        progress.close()
    result = identified.as_dict()
    if args.report:
        from dcmotor_id.report import write_report
        page = write_report(args.report, result, identified.discovery_result, records)
        print(f'report: {page}')
    if args.json:
        write_json(args.json, result)
    print(format_table(result))
    return 0


def _cmd_simulate(args):
    params = PAPER_MOTORS[args.motor]
    t, voltage = make_excitation(args.excitation, args.duration, args.sample_period,
                                 amplitude_v=args.amplitude, frequency_hz=args.frequency,
                                 seed=args.seed)
    position = None
    if args.effect:
        try:
            effects = [parse_effect(text) for text in args.effect]
        except ValueError as error:
            raise InputDataError(f'--effect: {error}') from None
        current, speed, position = simulate_motor_effects(params, voltage, args.sample_period,
                                                          effects)
    else:
        current, speed = simulate_motor(params, voltage, args.sample_period)
    rng = np.random.default_rng(args.seed)
    current = quantise(add_sensor_noise(current, args.noise, rng), args.current_lsb)
    speed = quantise(add_sensor_noise(speed, args.noise, rng), args.speed_lsb)
    write_csv(args.out, Record(t, current=current, voltage=voltage, speed=speed,
                               position=position))
    with_effects = f", effects {', '.join(args.effect)}" if args.effect else ''
    print(f'wrote {len(t)} samples of motor {args.motor} ({args.excitation}, '
          f'dt {args.sample_period:g} s, noise {args.noise:g} of std{with_effects}) to '
          f'{args.out}')
    return 0


def _cmd_demo(args):
    from dcmotor_id.demo import run_demo
    return run_demo()


def _positive(text):
    value = float(text)
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text}')
    return value


def _non_negative(text):
    value = float(text)
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f'must be zero or a positive number, got {text}')
    return value


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser (the CLI contract)."""
    parser = argparse.ArgumentParser(
        prog='dcmotor-id', description='Identify DC motor parameters (Ra, La, CPhi, J, b, Mc).')
    commands = parser.add_subparsers(dest='command', required=True)

    ident = commands.add_parser('identify', help='identify the motor from CSV files or bags')
    ident.add_argument('files', nargs='+', metavar='FILE',
                       help='CSV with columns t, voltage, current, speed (position optional), '
                            'rosbag2 directory (MCAP or sqlite3), or .mcap file')
    ident.add_argument('--json', metavar='OUT', help='write the result as JSON here')
    ident.add_argument('--method', choices=sorted(METHODS), default='refined',
                       help='refined (default: exact output error) or paper (the baseline)')
    ident.add_argument('--torque-constant', type=_positive, metavar='K',
                       help='mechanical-only mode: identify J, b, Mc with torque K*current '
                            '[N m/A]')
    ident.add_argument('--no-discover', action='store_true',
                       help='skip the residual analysis and effect discovery')
    ident.add_argument('--report', metavar='DIR',
                       help='write an HTML report with plots (measured vs model before and '
                            'after, residual whiteness, parameters, effects) to DIR')
    ident.add_argument('--extended-vocabulary', action='store_true',
                       help='let the discovery loop also try the effects beyond the standard '
                            'vocabulary (viscous_asymmetry)')
    ident.add_argument('--resample', action='store_true',
                       help='interpolate irregularly sampled data onto a uniform grid')
    ident.add_argument('--speed-cutoff', type=_positive, metavar='HZ',
                       help='cut-off of the filter deriving speed from position [Hz]')
    for channel, kind in (('voltage', 'Float64'), ('current', 'Float64'),
                          ('speed', 'Float64'), ('samples', 'batched Float64MultiArray')):
        ident.add_argument(f'--{channel}-topic', default=BAG_TOPICS[channel], metavar='TOPIC',
                           help=f'bags: {kind} topic of the {channel} (default '
                                f'{BAG_TOPICS[channel]!r}, any namespace)')
    ident.add_argument('--max-time', type=_positive, default=DEFAULT_MAX_TIME_S, metavar='S',
                       help='time budget [s]: past it the best result so far is returned with '
                            f'a warning (default {DEFAULT_MAX_TIME_S:g})')
    ident.add_argument('--quiet', action='store_true',
                       help='no progress line on stderr (it only shows on a terminal anyway)')
    ident.add_argument('--initial-state', choices=INITIAL_STATES, default='estimate',
                       help='estimate (default) the initial current and speed of every record, '
                            'or pin them to the first measured samples (measured)')
    ident.set_defaults(handler=_cmd_identify)

    sim = commands.add_parser('simulate', help='simulate a motor of the paper to CSV')
    sim.add_argument('--motor', choices=sorted(PAPER_MOTORS), default='paper2')
    sim.add_argument('--excitation', choices=EXCITATION_KINDS, default='paper')
    sim.add_argument('--duration', type=_positive, default=8.0, metavar='S')
    sim.add_argument('--sample-period', type=_positive, default=1e-4, metavar='S')
    sim.add_argument('--noise', type=_non_negative, default=0.0, metavar='REL',
                     help='white noise on current and speed, relative to their std')
    sim.add_argument('--amplitude', type=_positive, metavar='V')
    sim.add_argument('--frequency', type=_positive, metavar='HZ')
    sim.add_argument('--current-lsb', type=_non_negative, default=0.0, metavar='A',
                     help='quantisation step of the current sensor')
    sim.add_argument('--speed-lsb', type=_non_negative, default=0.0, metavar='RAD_S',
                     help='quantisation step of the speed sensor')
    sim.add_argument('--seed', type=int, default=0)
    sim.add_argument('--effect', action='append', metavar='NAME[:param=value,...]',
                     help='simulate with a true effect, e.g. load_torque:torque_Nm=0.5 or '
                          'sensor_delay:channel=speed,samples=3 (repeatable; names: '
                          + ', '.join(EFFECTS) + '); adds the shaft angle as position')
    sim.add_argument('--out', required=True, metavar='FILE.csv')
    sim.set_defaults(handler=_cmd_simulate)

    demo = commands.add_parser('demo', help='simulate motor 2 and identify it with both methods')
    demo.set_defaults(handler=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except DcMotorIdError as error:
        print(f'dcmotor-id: error: {error}', file=sys.stderr)
        return 2
    except OSError as error:
        print(f'dcmotor-id: error: {error}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
