"""
The ``dcmotor-id`` command line: offline identification and simulation.

Exit codes: 0 success, 2 bad input or data that cannot identify the motor (with a message
saying what is wrong and what to do), 1 an unexpected failure.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import os
import platform
import stat
import sys
import tempfile
import traceback
from typing import Any, Mapping, Sequence
import warnings

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError, InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.progress import terminal_progress, TimeBudgetExceeded
from dcmotor_id.core.records import Record
from dcmotor_id.formats import read_records
from dcmotor_id.formats.bag import BAG_TOPICS, DamagedBagWarning, TruncatedBagWarning
from dcmotor_id.formats.budget import check_budget, DEFAULT_BUDGET_BYTES, set_memory_budget
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.formats.mapping import (CURRENT_UNITS, output_shaft, parse_assignments,
                                        POSITION_UNITS, ReadingNote, ReadOptions, SPEED_UNITS)
from dcmotor_id.formats.paths import check_input_path, kind_of, same_file
from dcmotor_id.identification.criterion import CRITERIA
from dcmotor_id.identification.dropouts import repair_all
from dcmotor_id.identification.effects import EFFECTS, EXTENDED_VOCABULARY, parse_effect
from dcmotor_id.identification.identify import (DEFAULT_MAX_TIME_S, identify, INITIAL_STATES,
                                                METHODS, prepare_records)
from dcmotor_id.simulation import simulate_motor, simulate_motor_effects
from dcmotor_id.simulation.excitation import (add_sensor_noise, EXCITATION_KINDS, make_excitation,
                                              quantise)
from dcmotor_id.streaming.summary import format_table


def load_records(paths: Sequence[str], topics: Mapping[str, str] | None = None,
                 options: ReadOptions | None = None,
                 mechanical_only: bool = False) -> list[Record]:
    """
    Read every input path (CSV, .mat, rosbag2 directories, .mcap or .db3 files).

    How a file was read when it was not as expected (a matrix transposed, a semicolon
    dialect) is printed as a note on stderr.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', ReadingNote)
        records = read_records(paths, topics=topics, options=options or ReadOptions(),
                               mechanical_only=mechanical_only)
    shown = set()
    for item in caught:
        if issubclass(item.category, ReadingNote):
            if str(item.message) not in shown:
                print(f'dcmotor-id: note: {item.message}', file=sys.stderr)
            shown.add(str(item.message))
        else:
            warnings.warn_explicit(item.message, item.category, item.filename, item.lineno)
    return records


def load_records_reporting_loss(paths: Sequence[str], topics: Mapping[str, str] | None = None,
                                options: ReadOptions | None = None,
                                mechanical_only: bool = False
                                ) -> tuple[list[Record], list[str]]:
    """
    Read the inputs as :func:`load_records`; return them and what was lost reading them.

    A truncated or damaged bag is read as far as it can be; each loss (samples or messages,
    of which topic, where) is printed as a warning on stderr and returned, for the result's
    ``warnings`` and ``data_loss``.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always', TruncatedBagWarning)
        warnings.simplefilter('always', DamagedBagWarning)
        records = load_records(paths, topics, options, mechanical_only)
    loss = []
    for item in caught:
        if issubclass(item.category, (TruncatedBagWarning, DamagedBagWarning)):
            loss.append(str(item.message))
            print(f'dcmotor-id: warning: {item.message}', file=sys.stderr)
        else:
            warnings.showwarning(item.message, item.category, item.filename, item.lineno)
    return records, list(dict.fromkeys(loss))


def _json_safe(value):
    """Replace non-finite floats by None (JSON has no NaN), recursively."""
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _nearest_existing(path: str) -> str:
    """Return ``path`` or its nearest ancestor that exists."""
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return path


def check_output_path(path: str, option: str, directory: bool = False,
                      inputs: Sequence[str] = ()) -> None:
    """
    Refuse an output path that cannot be written, before any work is done.

    A file option (``--json``) must not name a directory, and may only replace a regular file
    that is not one of the ``inputs`` (never a symlink, a device, a FIFO nor a recording);
    for both kinds, the nearest existing ancestor must be a directory in which a file can be
    created (tried with a temporary file, which also catches read-only file systems and
    running as root).

    Raises
    ------
    InputDataError
        Naming the option, the path and what is wrong.

    """
    target = os.path.abspath(path)
    if not directory:
        _check_replaceable(path, option, inputs)
    if not directory and (os.path.isdir(target) or path.endswith(os.sep)):
        raise InputDataError(f'{option} {path}: is a directory; give a file name, e.g. '
                             f'{os.path.join(path, "result.json")}')
    if directory and os.path.exists(target) and not os.path.isdir(target):
        raise InputDataError(f'{option} {path}: exists and is not a directory; give a '
                             'directory for the report')
    where = target if directory and os.path.isdir(target) else os.path.dirname(target)
    existing = _nearest_existing(where)
    if not os.path.isdir(existing):
        raise InputDataError(f'{option} {path}: {existing} is a file, not a directory; choose '
                             'another place')
    try:
        handle, probe = tempfile.mkstemp(dir=existing, prefix='.dcmotor_id_probe_')
        os.close(handle)
        os.unlink(probe)
    except OSError as error:
        raise InputDataError(f'{option} {path}: cannot write in {existing} '
                             f'({error.strerror or error}); choose a writable place') from None


def _check_replaceable(path: str, option: str, inputs: Sequence[str] = ()) -> None:
    """Refuse an output file that exists and is not a regular file, or is an input."""
    try:
        mode = os.lstat(path).st_mode
    except OSError:
        return
    if stat.S_ISLNK(mode):
        raise InputDataError(f'{option} {path}: is a symbolic link (to '
                             f'{os.readlink(path)}); it is not replaced: give the path of a '
                             'new or regular file')
    if stat.S_ISDIR(mode):
        return  # refused as a directory by the caller
    if not stat.S_ISREG(mode):
        raise InputDataError(f'{option} {path}: is {kind_of(mode)}, not a regular file; it is '
                             'not replaced: give the path of a new or regular file')
    twin = same_file(path, inputs)
    if twin is not None:
        raise InputDataError(f'{option} {path}: is the input {twin}; writing there would '
                             'destroy the recording: give another file name')


def write_json(path: str, result: Mapping[str, Any]) -> None:
    """
    Write the result as strict JSON, atomically.

    The text goes to a temporary file of a unique name in the target directory (so concurrent
    runs never share one), then is renamed into place: a reader sees the old file or the whole
    new one, never a torn one.
    """
    _check_replaceable(path, 'the output')
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=directory, suffix='.partial',
                                         prefix=f'.{os.path.basename(path)}.')
    try:
        with os.fdopen(handle, 'w', encoding='utf-8') as stream:
            json.dump(_json_safe(result), stream, indent=2, allow_nan=False)
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise


def _cmd_identify(args):
    # Every output place is checked first: a fit of minutes is never lost to a typo.
    if args.json:
        check_output_path(args.json, '--json', inputs=args.files)
    if args.report:
        check_output_path(args.report, '--report', directory=True)
    topics = {'voltage': args.voltage_topic, 'current': args.current_topic,
              'speed': args.speed_topic, 'samples': args.samples_topic}
    options = reading_options(args)
    loaded, loss = load_records_reporting_loss(args.files, topics, options,
                                               args.torque_constant is not None)
    records, repairs = repair_all(prepare_records(loaded, args.torque_constant, args.resample,
                                                  args.speed_cutoff))
    for note in repairs:
        print(f'dcmotor-id: warning: {note}', file=sys.stderr)
    vocabulary = EXTENDED_VOCABULARY if args.extended_vocabulary else None
    progress = terminal_progress(args.max_time, quiet=args.quiet)
    try:
        identified = identify(records, method=args.method,
                              torque_constant=args.torque_constant,
                              discover=not args.no_discover, vocabulary=vocabulary,
                              progress=progress, initial_state=args.initial_state,
                              criterion=args.criterion, max_time_s=args.max_time,
                              structure_bootstrap=args.structure_bootstrap)
    except TimeBudgetExceeded:
        raise InputDataError(f'--max-time {args.max_time:g}: no fit finished within the time '
                             'budget; give more time (e.g. --max-time 60), or shorten or '
                             'decimate the records') from None
    finally:
        progress.close()
    result = identified.as_dict()
    repairs += _unit_flag_warnings(options, result.get('parameters') or {})
    if loss or repairs:
        result['warnings'] = loss + repairs + list(result.get('warnings') or [])
    if loss:
        result['data_loss'] = loss
    if options.gear_ratio != 1.0:
        result['gear_ratio'] = options.gear_ratio
        result['output_shaft'] = output_shaft(result['parameters'], options.gear_ratio)
    failures = []
    if args.report:
        try:
            from dcmotor_id.reports.identification import write_report
            page = write_report(args.report, result, identified.discovery_result, records)
            print(f'report: {page}')
        except OSError as error:
            failures.append(f'--report {args.report}: not written: {error.strerror or error}')
    if args.json:
        try:
            write_json(args.json, result)
        except OSError as error:
            failures.append(f'--json {args.json}: not written: {error.strerror or error}')
    print(format_table(result))
    if 'output_shaft' in result:
        print(f'at the output shaft (gear ratio {options.gear_ratio:g}): ' + ', '.join(
            f'{name} = {value:.6g}' for name, value in result['output_shaft'].items()))
    for failure in failures:
        print(f'dcmotor-id: error: {failure} (the result is printed above)', file=sys.stderr)
    return 2 if failures else 0


def _unit_flag_warnings(options: ReadOptions, parameters: Mapping[str, Any]) -> list[str]:
    """Warn when ``--current-unit mA`` looks given on data already in amperes."""
    ra = parameters.get('Ra')
    if options.current_unit == 'mA' and isinstance(ra, float) and ra > 100.0:
        return [f'--current-unit mA gives Ra = {ra:.4g} Ohm, an armature of kilo-ohms: the '
                'current column looks already in amperes; drop --current-unit mA if so']
    return []


def reading_options(args: argparse.Namespace) -> ReadOptions:
    """Return the :class:`ReadOptions` of the reading options (identify, validate)."""
    set_memory_budget(args.memory_budget * 1e9)
    return ReadOptions(
        columns=parse_assignments(args.column, '--column'), current_unit=args.current_unit,
        speed_unit=args.speed_unit, speed_counts_per_rev=args.speed_counts_per_rev,
        position_unit=args.position_unit, position_counts_per_rev=args.position_counts_per_rev,
        gear_ratio=args.gear_ratio, bus_voltage=args.voltage_from_duty, joint=args.joint,
        interfaces=parse_assignments(args.interface, '--interface'),
        sample_period_s=args.sample_period)


def _add_reading_options(command: argparse.ArgumentParser) -> None:
    """Add the options that say how to read the files (mapping, units, duty, gear, bags)."""
    group = command.add_argument_group('reading recordings as they come')
    group.add_argument('--column', action='append', metavar='CHANNEL=NAME',
                       help='take a channel (t, voltage, current, speed, position, duty, '
                            'direction) from the column NAME (.mat: VARIABLE, VARIABLE:COLUMN '
                            '1-based, or STRUCT.FIELD[:COLUMN]); repeatable')
    group.add_argument('--sample-period', type=_positive, metavar='S',
                       help='the samples are S seconds apart: time = k*S (.mat, CSV without '
                            'or with broken time stamps; a time column is then not used); for '
                            'bags the grid step')
    group.add_argument('--current-unit', choices=sorted(CURRENT_UNITS), default='A')
    group.add_argument('--speed-unit', choices=sorted(SPEED_UNITS), default='rad/s')
    group.add_argument('--speed-counts-per-rev', type=_positive, metavar='N',
                       help='the speed column holds encoder pulses per sample, N per rev')
    group.add_argument('--position-unit', choices=sorted(POSITION_UNITS), default='rad')
    group.add_argument('--position-counts-per-rev', type=_positive, metavar='N',
                       help='the position column holds encoder counts, N per revolution')
    group.add_argument('--gear-ratio', type=_positive, default=1.0, metavar='N',
                       help='speed and position measured at the output shaft of an N:1 gear; '
                            'parameters at the motor shaft, output-shaft values alongside')
    group.add_argument('--voltage-from-duty', type=_positive, metavar='BUS_V',
                       help='voltage = duty column in [-1, 1] (or 0..1 with a direction '
                            'column) times the bus voltage BUS_V')
    group.add_argument('--joint', metavar='NAME',
                       help='bags with control_msgs/msg/DynamicJointState or '
                            'sensor_msgs/msg/JointState: the joint (default: the only one)')
    group.add_argument('--interface', action='append', metavar='CHANNEL=NAME',
                       help='bags with DynamicJointState: the interface of a channel (default '
                            'voltage, current, velocity as speed, position); with JointState: '
                            'its field (position, velocity, effort; default velocity as speed, '
                            'position; the current from effort only with current=effort), the '
                            'other channels from their Float64 topics; repeatable')
    _add_memory_budget(group)


def _add_memory_budget(group: Any) -> None:
    group.add_argument('--memory-budget', type=_positive, default=DEFAULT_BUDGET_BYTES / 1e9,
                       metavar='GB', help='largest allocation a file may ask for, estimated '
                       'before reading (default %(default)g GB); larger files are refused')


def _cmd_validate(args):
    from dcmotor_id.identification.validate import format_validation, load_model, validate
    check_input_path(args.model, 'model ')
    if args.json:
        check_output_path(args.json, '--json', inputs=[args.model, *args.files])
    if args.report:
        check_output_path(args.report, '--report', directory=True)
    model = load_model(args.model)
    options = reading_options(args)
    records = []
    loaded, loss = load_records_reporting_loss(args.files, options=options,
                                               mechanical_only=model.mechanical_only)
    for record in loaded:
        mechanical = model.torque_constant if model.mechanical_only else None
        records += prepare_records([record], mechanical, args.resample, args.speed_cutoff)
    validation = validate(model, records, args.init_samples, options.position_factor)
    result = validation.as_dict()
    if loss:
        result['warnings'] = loss + list(result.get('warnings') or [])
        result['data_loss'] = loss
    if args.json:
        write_json(args.json, result)
    if args.report:
        from dcmotor_id.reports.identification import write_validation_report
        print(f'report: {write_validation_report(args.report, validation)}')
    print(format_validation(result))
    return 0


def _cmd_simulate(args):
    check_output_path(args.out, '--out')
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


def _cmd_design(args):
    from dcmotor_id.design import control as control_design
    from dcmotor_id.design.export import write_exports
    check_input_path(args.result, 'RESULT.json ')
    if args.json:
        check_output_path(args.json, '--json', inputs=[args.result])
    for option, place in (('--report', args.report), ('--export', args.export)):
        if place:
            check_output_path(place, option, directory=True)
    result = control_design.load_result(args.result)
    motor = control_design.motor_from_result(result, args.gear_ratio, args.output_shaft)
    options = control_design.DesignOptions(args.current_bandwidth, args.speed_bandwidth,
                                           args.phase_margin, args.sample_period)
    design, gains = control_design.design(motor, options)
    design['source'] = args.result
    if args.export:
        motor_shaft = control_design.motor_from_result(result, args.gear_ratio).values
        design['export'] = write_exports(args.export, motor, motor_shaft)
        print(f'exported: {args.export}')
    if args.report:
        from dcmotor_id.reports.design import write_design_report
        print(f'report: {write_design_report(args.report, design, motor, gains)}')
    if args.json:
        write_json(args.json, design)
    print(control_design.format_design(design))
    return 0


def _cmd_demo(args):
    from dcmotor_id.cli.demo import run_demo
    return run_demo()


def _cmd_plan(args):
    from dcmotor_id.design.experiment import DEFAULT_NOISE, design_experiment, load_prior
    from dcmotor_id.design.routines import Limits
    if os.path.exists(args.prior) or os.path.islink(args.prior):
        check_input_path(args.prior, '--prior ')
    if args.json:
        check_output_path(args.json, '--json', inputs=[args.prior])
    set_memory_budget(args.memory_budget * 1e9)
    samples = args.duration / args.sample_period
    check_budget(PLAN_BYTES_PER_SAMPLE * samples, f'--duration {args.duration:g}',
                 f'{samples:.3g} samples at --sample-period {args.sample_period:g} s',
                 'else give a shorter --duration or a longer --sample-period')
    prior, noise = load_prior(args.prior)
    noise = dict(noise or DEFAULT_NOISE)
    noise.update({key: value for key, value in (('current', args.noise_current),
                                                ('speed', args.noise_speed)) if value})
    try:
        plan = design_experiment(
            prior, Limits(args.voltage_limit, args.current_limit, args.speed_limit), noise,
            args.duration, args.kinds.split(','), args.parameters.split(','), args.rate,
            args.ramp_in, args.sample_period, args.margin, args.seed)
    except ValueError as error:
        raise InputDataError(str(error)) from None
    print(plan.describe())
    if args.json:
        write_json(args.json, plan.as_dict())
        print(f'plan written to {args.json} (exciter -p plan_file:={args.json})')
    return 0


#: Peak memory of ``plan`` per simulated sample [bytes] (measured: 190 B, rounded up).
PLAN_BYTES_PER_SAMPLE = 200.0


def _cmd_fleet(args):
    from dcmotor_id.fleet import FleetOptions, run_fleet
    from dcmotor_id.fleet.progress import Progress
    for path in args.paths:
        check_input_path(path, 'fleet input ', directory=True)
    check_output_path(args.history, '--history', directory=True)
    options = FleetOptions(args.motor_from, args.torque_constant, not args.no_discover,
                           args.window_s, args.min_window_s)
    summary = run_fleet(args.paths, args.history, options, scheduler=args.scheduler,
                        workers=args.workers, force=args.force,
                        retry_errors=not args.no_retry_errors,
                        progress=None if args.quiet else Progress())
    print(summary.text())
    return 0


def _cmd_fleet_report(args):
    from dcmotor_id.reports.fleet import write_fleet_report
    check_input_path(args.history, 'HISTORY_DIR ', directory=True)
    check_output_path(args.out, '--out', directory=True)
    print(f'report: {write_fleet_report(args.history, args.out)}')
    return 0


def _add_fleet_commands(commands):
    """Add ``fleet`` and ``fleet-report`` (issue 14: dcmotor_id/fleet/)."""
    fleet = commands.add_parser('fleet', help='identify many recordings on a Dask cluster into '
                                'a per-motor Parquet history')
    fleet.add_argument('paths', nargs='+', metavar='BAG_OR_DIR',
                       help='bags, .mcap/.db3/CSV files, or directories searched recursively')
    fleet.add_argument('--history', required=True, metavar='HISTORY_DIR',
                       help='Parquet dataset the rows are appended to (one per window)')
    fleet.add_argument('--scheduler', metavar='ADDRESS',
                       help='address of a running Dask scheduler (default: a local cluster)')
    fleet.add_argument('--workers', type=int, metavar='N',
                       help='worker processes of the local cluster (default: one per core)')
    fleet.add_argument('--motor-from', default='namespace', metavar='namespace|path|PATTERN',
                       help="name motors by the topics' namespace (default), the directory "
                            'of the recording, or a regular expression on its path')
    fleet.add_argument('--torque-constant', type=_positive, metavar='K',
                       help='mechanical-only mode: identify J, b, Mc [N m/A]')
    fleet.add_argument('--no-discover', action='store_true', help='skip effect discovery')
    fleet.add_argument('--force', action='store_true',
                       help='identify recordings already in the history again')
    fleet.add_argument('--no-retry-errors', action='store_true',
                       help='skip recordings whose rows in the history are errors (default: '
                            'identify them again, they may have been repaired)')
    fleet.add_argument('--window-s', type=_positive, default=10.0, metavar='S',
                       help='window length [s] (default 10, as the identifier node)')
    fleet.add_argument('--min-window-s', type=_positive, metavar='S',
                       help='shortest last window kept [s] (default half a window)')
    fleet.add_argument('--quiet', action='store_true', help='no progress bar on stderr')
    fleet.set_defaults(handler=_cmd_fleet)
    report = commands.add_parser('fleet-report', help='HTML page of a fleet history: trends, '
                                 'effects, change alarms, fleet overview')
    report.add_argument('history', metavar='HISTORY_DIR')
    report.add_argument('--out', required=True, metavar='DIR')
    report.set_defaults(handler=_cmd_fleet_report)


def _positive(text):
    value = float(text)
    if not (np.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text}')
    return value


def _resamples(text):
    from dcmotor_id.identification.structure_uncertainty import check_resamples, MAX_RESAMPLES

    try:
        return check_resamples(int(text))
    except (ValueError, InputDataError):
        raise argparse.ArgumentTypeError(
            f'give a whole number of resamples from 2 to {MAX_RESAMPLES} (20 is a good start), '
            f'or 0 to leave the structure choice out; got {text}') from None


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
    _add_reading_options(ident)
    ident.add_argument('--max-time', type=_positive, default=DEFAULT_MAX_TIME_S, metavar='S',
                       help='time budget [s]: past it the best result so far is returned with '
                            f'a warning (default {DEFAULT_MAX_TIME_S:g})')
    ident.add_argument('--quiet', action='store_true',
                       help='no progress line on stderr (it only shows on a terminal anyway)')
    ident.add_argument('--initial-state', choices=INITIAL_STATES, default='estimate',
                       help='estimate (default) the initial current and speed of every record, '
                            'or pin them to the first measured samples (measured)')
    ident.add_argument('--criterion', choices=CRITERIA, default='auto',
                       help='channels the fit compares: speed (and current), position (the '
                            'integral of the simulated speed, and current), both; auto '
                            '(default): position when the speed was derived from it, else '
                            'speed')
    ident.add_argument('--structure-bootstrap', type=_resamples, default=0, metavar='N',
                       help='rerun the identification, discovery included, on N noise '
                            'resamples so that the standard errors cover the choice of '
                            'structure (JSON structure_uncertainty; N more fits; default 0: '
                            'off)')
    ident.set_defaults(handler=_cmd_identify)

    val = commands.add_parser('validate', help='simulate an identified model on new records '
                                               'and score it (NRMSE, fit %%, position RMSE)')
    val.add_argument('model', metavar='MODEL.json', help='the JSON identify --json wrote')
    val.add_argument('files', nargs='+', metavar='FILE', help='records, as for identify')
    val.add_argument('--json', metavar='OUT', help='write the scores as JSON here')
    val.add_argument('--report', metavar='DIR',
                     help='write measured vs simulated, residuals and fit figures to DIR')
    val.add_argument('--init-samples', type=int, default=20, metavar='N',
                     help='samples at the start for the initial state, not scored (20)')
    val.add_argument('--resample', action='store_true',
                     help='interpolate irregularly sampled data onto a uniform grid')
    val.add_argument('--speed-cutoff', type=_positive, metavar='HZ',
                     help='cut-off of the filter deriving speed from position [Hz]')
    _add_reading_options(val)
    val.set_defaults(handler=_cmd_validate)

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

    ctl = commands.add_parser('design', help='controller gains and model export from an '
                              'identify result (python-control)')
    ctl.add_argument('result', metavar='RESULT.json', help='JSON of `dcmotor-id identify --json`')
    ctl.add_argument('--current-bandwidth', type=_positive, metavar='HZ',
                     help='closed current-loop bandwidth (default 200 Hz, at most a 20th of '
                          'the sampling rate; mechanical mode: default an ideal torque loop)')
    ctl.add_argument('--speed-bandwidth', type=_positive, metavar='HZ',
                     help='closed speed-loop -3 dB bandwidth (default a 10th of the current '
                          'bandwidth)')
    ctl.add_argument('--phase-margin', type=_positive, default=60.0, metavar='DEG',
                     help='phase margin of the speed loop (default 60)')
    ctl.add_argument('--sample-period', type=_positive, metavar='S',
                     help='discrete gains (Tustin) for this controller period [s]; default '
                          'continuous')
    ctl.add_argument('--gear-ratio', type=_positive, default=1.0, metavar='N',
                     help='motor speed / output speed (default 1)')
    ctl.add_argument('--output-shaft', action='store_true',
                     help='express speeds, gains and the model on the output shaft')
    ctl.add_argument('--json', metavar='OUT', help='write the design as JSON here')
    ctl.add_argument('--report', metavar='DIR', help='write design.html with step responses '
                     'and Bode plots to DIR')
    ctl.add_argument('--export', metavar='DIR', help='write model_statespace.json, '
                     'sim_motor.yaml and urdf_dynamics.xml to DIR')
    ctl.set_defaults(handler=_cmd_design)
    plan = commands.add_parser('plan', help='design a D-optimal PRBS/multisine for the exciter '
                               'within limits; print it and the expected standard errors')
    plan.add_argument('--prior', default='paper2', metavar='SOURCE',
                      help='prior parameters: paper1, paper2, a result JSON or a datasheet '
                           'JSON/YAML with Ra, La, CPhi, J, b, Mc (default paper2)')
    for name, default, unit in (('voltage-limit', 48.0, 'V'), ('current-limit', 10.0, 'A'),
                                ('speed-limit', 100.0, 'RAD_S'), ('duration', 10.0, 'S'),
                                ('rate', 200.0, 'HZ'), ('sample-period', 1e-3, 'S')):
        plan.add_argument(f'--{name}', type=_positive, default=default, metavar=unit)
    plan.add_argument('--ramp-in', type=_non_negative, default=1.0, metavar='S')
    plan.add_argument('--noise-current', type=_positive, metavar='A',
                      help='current noise std (default: from a result file, else 0.01)')
    plan.add_argument('--noise-speed', type=_positive, metavar='RAD_S',
                      help='speed noise std (default: from a result file, else 0.02)')
    plan.add_argument('--parameters', default='Ra,La,CPhi,J,b,Mc',
                      help='parameters of the D-criterion, comma-separated')
    plan.add_argument('--kinds', default='prbs,multisine', help='prbs and/or multisine')
    plan.add_argument('--margin', type=_positive, default=0.9,
                      help='share of the current/speed limits the simulation may reach')
    plan.add_argument('--seed', type=int, default=0)
    plan.add_argument('--json', metavar='OUT', help='write the plan here (exciter plan_file)')
    _add_memory_budget(plan)
    plan.set_defaults(handler=_cmd_plan)

    demo = commands.add_parser('demo', help='simulate motor 2 and identify it with both methods')
    demo.set_defaults(handler=_cmd_demo)
    _add_fleet_commands(commands)
    return parser


#: Unexpected exceptions that come from the data or the machine, not from a bug: exit 2.
_ENVIRONMENT_HINTS = (
    (MemoryError, 'not enough memory for these data; identify a shorter record or fewer '
                  'files at a time, or free memory'),
    (UnicodeError, 'the input is not text in UTF-8; save it as a UTF-8 CSV'),
    (np.linalg.LinAlgError, 'the numbers do not fit a DC motor model; check that the columns '
                            'are what their names say (current in A, speed in rad/s, not '
                            'swapped) and that the data come from one drive'),
    (FloatingPointError, 'the numbers overflow the computation; check the units of the '
                         'columns'),
    (OverflowError, 'the numbers overflow the computation; check the units of the columns'),
)


#: What to do about an error of the operating system, by errno.
_OS_HINTS = {
    errno.EACCES: 'permission denied: make it readable/writable for this user (chmod) or '
                  'choose another place',
    errno.EPERM: 'operation not permitted: choose another place or run as its owner',
    errno.EEXIST: 'already exists and is in the way: remove it or choose another name',
    errno.ENOENT: 'no such file or directory: check the path',
    errno.ENOSPC: 'no space left on the device: free space or write elsewhere',
    errno.EROFS: 'the file system is read-only: write elsewhere',
    errno.ENOTDIR: 'a part of the path is a file, not a directory: check the path',
    errno.EISDIR: 'is a directory: give a file',
    errno.ELOOP: 'a symbolic link loop: give the real path',
    errno.ENAMETOOLONG: 'the name is too long: choose a shorter path',
}


def os_error_message(error: OSError) -> str:
    """Return an error of the operating system as a sentence naming the path and the fix."""
    where = error.filename if error.filename is not None else ''
    if error.filename2 is not None:
        where = f'{where} -> {error.filename2}'
    hint = _OS_HINTS.get(error.errno or 0)
    if hint is None:
        hint = f'{error.strerror or error}: check the path and the machine'
    return f'{where}: {hint}' if where else hint


def _bug_report(error: BaseException) -> str:
    """Return a short report of an unexpected exception: where it happened and versions."""
    frames = traceback.extract_tb(error.__traceback__)
    where = ', '.join(f'{os.path.basename(frame.filename)}:{frame.lineno} {frame.name}'
                      for frame in frames[-3:])
    return (f'dcmotor-id: internal error: {type(error).__name__}: {error}\n'
            f'  at {where or "?"}\n'
            f'  python {platform.python_version()}, numpy {np.__version__}, '
            f'{platform.system()} {platform.machine()}\n'
            '  This is a bug of dcmotor-id: please report it with this text, the command line '
            'and, if you can, the input files.')


def main(argv: Sequence[str] | None = None) -> int:
    """
    Run the command line; return the exit code.

    Every failure ends as a message, never as a traceback: 2 for bad input, data that cannot
    identify the motor and what the machine refuses (a path, memory), with what to do; 1 for
    anything else, with a short report (a bug); 130 when interrupted.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except DcMotorIdError as error:
        print(f'dcmotor-id: error: {error}', file=sys.stderr)
        return 2
    except OSError as error:
        print(f'dcmotor-id: error: {os_error_message(error)}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('dcmotor-id: interrupted', file=sys.stderr)
        return 130
    except Exception as error:  # noqa: BLE001  (the top-level handler: a message, not a trace)
        for kind, hint in _ENVIRONMENT_HINTS:
            if isinstance(error, kind):
                print(f'dcmotor-id: error: {type(error).__name__}: {error}: {hint}',
                      file=sys.stderr)
                return 2
        print(_bug_report(error), file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
