"""
The ``dcmotor-id`` command line: offline identification and simulation.

Exit codes: 0 success, 2 bad input or data that cannot identify the motor (with a message
saying what is wrong and what to do), 1 an unexpected failure.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any, Mapping, Sequence
import warnings

import numpy as np

from dcmotor_id.cli.output import emit_json, json_on_stdout, STDOUT, VersionAction
from dcmotor_id.cli.terminal import terminal_progress
from dcmotor_id.console.command_line import (add_memory_budget, non_negative, positive,
                                             run_reporting)
from dcmotor_id.console.plan import add_plan_arguments, run_plan
from dcmotor_id.core.errors import InputDataError
from dcmotor_id.core.model import PAPER_MOTORS
from dcmotor_id.core.progress import TimeBudgetExceeded
from dcmotor_id.core.records import Record
from dcmotor_id.formats import read_records
from dcmotor_id.formats.bag import BAG_TOPICS, DamagedBagWarning, TruncatedBagWarning
from dcmotor_id.formats.budget import check_budget, set_memory_budget
from dcmotor_id.formats.csv import write_csv
from dcmotor_id.formats.json_file import with_schema_version, write_json
from dcmotor_id.formats.mapping import (CURRENT_SIGN_SOURCES, CURRENT_UNITS, output_shaft,
                                        parse_assignments,
                                        POSITION_UNITS, ReadingNote, ReadOptions,
                                        SIGNED_CHANNELS, SPEED_UNITS, TIME_UNITS)
from dcmotor_id.formats.paths import check_input_path, check_output_path, is_bag_dir
from dcmotor_id.identification.checks.dropouts import repair_all
from dcmotor_id.identification.effects import EFFECTS, EXTENDED_VOCABULARY, parse_effect
from dcmotor_id.identification.error_model.criterion import CRITERIA
from dcmotor_id.identification.identify import (DEFAULT_MAX_TIME_S, identify, INITIAL_STATES,
                                                METHODS, prepare_records)
from dcmotor_id.simulation import simulate_motor, simulate_motor_effects
from dcmotor_id.simulation.excitation import (add_sensor_noise, EXCITATION_KINDS, make_excitation,
                                              quantise)
from dcmotor_id.streaming.summary import format_table

#: Peak memory of ``simulate`` per sample [bytes]: the signals, noise and CSV rows (measured
#: about 150 B at 1e7 samples, rounded up).
SIMULATE_BYTES_PER_SAMPLE = 200.0
#: What a report writes into its directory (shell patterns): never over an input.
REPORT_FILES = ('*.html', '*.png')
#: What ``design --export`` writes into its directory (:func:`write_exports`).
EXPORT_FILES = ('model_statespace.json', 'sim_motor.yaml', 'urdf_dynamics.xml')


def whole_number_at_least_one(text: str) -> int:
    """Return ``text`` as a whole number of 1 or more (an ``argparse`` type)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a whole number, got {text}') from None
    if value < 1:
        raise argparse.ArgumentTypeError(f'must be 1 or more, got {text}')
    return value


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


def _write_result(args: argparse.Namespace, result: Mapping[str, Any]) -> None:
    """Write a result with its schema version to ``--json``: the file, or stdout for ``-``."""
    if args.json == STDOUT:
        emit_json(args, result)
    else:
        write_json(args.json, with_schema_version(result))


def _check_outputs(args: argparse.Namespace, inputs: Sequence[str]) -> None:
    """Check ``--json`` and ``--report`` against the inputs, before any work."""
    if args.json and args.json != STDOUT:
        check_output_path(args.json, '--json', inputs=inputs)
    if args.report:
        check_output_path(args.report, '--report', directory=True, inputs=inputs,
                          writes=REPORT_FILES)


def _check_segments(args: argparse.Namespace, records: Sequence[Record]) -> None:
    """Refuse a ``--segment-column`` that a file's format did not carry (bags, DataLogs)."""
    if not args.segment_column:
        return
    for path, record in zip(args.files, records):
        if record.segment is None:
            raise InputDataError(
                f"{path}: --segment-column {args.segment_column}: this file's format carries "
                'no such column (the segment column is read from CSV, .mat and Parquet '
                'files); drop the option, or export the record with its segment column')


def _cmd_identify(args):
    # Every output place is checked first: a fit of minutes is never lost to a typo.
    _check_outputs(args, args.files)
    topics = {'voltage': args.voltage_topic, 'current': args.current_topic,
              'speed': args.speed_topic, 'samples': args.samples_topic}
    options = reading_options(args)
    loaded, loss = load_records_reporting_loss(args.files, topics, options,
                                               args.torque_constant is not None)
    _check_segments(args, loaded)
    records, repairs = repair_all(prepare_records(loaded, args.torque_constant, args.resample,
                                                  args.speed_cutoff))
    for note in repairs + ignored_flags(args, records):
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
    repairs += ignored_flags(args, records) + _unit_flag_warnings(
        options, result.get('parameters') or {}, records)
    if loss or repairs:
        result['warnings'] = loss + repairs + list(result.get('warnings') or [])
    if loss:
        result['data_loss'] = loss
    result['input_units'] = options.input_units()
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
            _write_result(args, result)
        except OSError as error:
            failures.append(f'--json {args.json}: not written: {error.strerror or error}')
    print(format_table(result))
    if 'output_shaft' in result:
        print(f'at the output shaft (gear ratio {options.gear_ratio:g}): ' + ', '.join(
            f'{name} = {value:.6g}' for name, value in result['output_shaft'].items()))
    for failure in failures:
        print(f'dcmotor-id: error: {failure} (the result is printed above)', file=sys.stderr)
    return 2 if failures else 0


def ignored_flags(args: argparse.Namespace, records: Sequence[Record]) -> list[str]:
    """Name the options given without the partner they act through (so they did nothing)."""
    found = []
    if args.speed_cutoff is not None and not any(record.speed_derived for record in records):
        found.append(f'--speed-cutoff {args.speed_cutoff:g} Hz ignored: it filters a speed '
                     'derived from a position column, and every record has its own speed '
                     'column')
    if args.duty_full_scale != 1.0 and args.voltage_from_duty is None:
        found.append(f'--duty-full-scale {args.duty_full_scale:g} ignored: it scales a duty '
                     'column read with --voltage-from-duty BUS_V, which is not given')
    return found


#: No-load speeds of DC motors [rad/s] (about 290 to 29,000 rpm): a unit flag that puts the
#: answer outside while the column as given lies inside looks given on SI data.
NO_LOAD_SPEED_RAD_S = (30.0, 3000.0)


def _unit_flag_warnings(options: ReadOptions, parameters: Mapping[str, Any],
                        records: Sequence[Record] = ()) -> list[str]:
    """
    Warn when a unit flag looks given on data already in SI units, by the answer's physics.

    ``--current-unit mA`` giving an armature of kilo-ohms; ``--speed-unit`` (or
    ``--position-unit``) giving a no-load speed ``peak voltage / CPhi`` outside what DC
    motors turn at, where the column read as rad/s (rad) gives one inside.
    """
    found = []
    ra, cphi = parameters.get('Ra'), parameters.get('CPhi')
    if options.current_unit == 'mA' and isinstance(ra, float) and ra > 100.0:
        found.append(f'--current-unit mA gives Ra = {ra:.4g} Ohm, an armature of kilo-ohms: '
                     'the current column looks already in amperes; drop --current-unit mA if '
                     'so')
    peaks = [float(np.max(np.abs(rec.voltage))) for rec in records if rec.voltage is not None
             and len(rec.voltage)]
    if not (peaks and isinstance(cphi, float) and cphi > 0):
        return found
    low, high = NO_LOAD_SPEED_RAD_S
    no_load = max(peaks) / cphi
    for option, unit, factor in (
            ('--speed-unit', options.speed_unit, SPEED_UNITS.get(options.speed_unit, 1.0)),
            ('--position-unit', options.position_unit,
             POSITION_UNITS.get(options.position_unit, 1.0))):
        as_given = no_load / factor
        if factor != 1.0 and not low <= no_load <= high and low <= as_given <= high:
            found.append(
                f'{option} {unit} gives CPhi = {cphi:.4g} V s, a motor turning at '
                f'{no_load * 30 / np.pi:.4g} rpm without load at {max(peaks):.4g} V, where DC '
                f'motors turn at {low * 30 / np.pi:.0f} to {high * 30 / np.pi:.0f} rpm; read '
                f'in SI units it turns at {as_given * 30 / np.pi:.4g} rpm: the column looks '
                f'already in rad/s (rad); drop {option} {unit} if so, else CPhi, J, b and Mc '
                'are off')
    return found


def reading_options(args: argparse.Namespace) -> ReadOptions:
    """Return the :class:`ReadOptions` of the reading options (identify, validate)."""
    set_memory_budget(args.memory_budget * 1e9)
    columns = parse_assignments(args.column, '--column')
    if getattr(args, 'segment_column', None):
        columns['segment'] = args.segment_column
    return ReadOptions(
        columns=columns, time_unit=args.time_unit, current_unit=args.current_unit,
        speed_unit=args.speed_unit, speed_counts_per_rev=args.speed_counts_per_rev,
        position_unit=args.position_unit, position_counts_per_rev=args.position_counts_per_rev,
        gear_ratio=args.gear_ratio, bus_voltage=args.voltage_from_duty,
        duty_full_scale=args.duty_full_scale, negated=tuple(args.negate or ()),
        current_sign_from=args.current_sign_from, joint=args.joint,
        interfaces=parse_assignments(args.interface, '--interface'),
        sample_period_s=args.sample_period)


def _add_reading_options(command: argparse.ArgumentParser) -> None:
    """Add the options that say how to read the files (mapping, units, duty, gear, bags)."""
    group = command.add_argument_group('reading recordings as they come')
    group.add_argument('--column', action='append', metavar='CHANNEL=NAME',
                       help='take a channel (t, voltage, current, speed, position, duty, '
                            'direction) from the column NAME (.mat: VARIABLE, VARIABLE:COLUMN '
                            '1-based, or STRUCT.FIELD[:COLUMN]); repeatable')
    group.add_argument('--sample-period', type=positive, metavar='S',
                       help='the samples are S seconds apart: time = k*S (.mat, CSV without '
                            'or with broken time stamps; a time column is then not used); for '
                            'bags the grid step')
    group.add_argument('--time-unit', choices=list(TIME_UNITS), default='s',
                       help='unit of the time column (a logger stamping in ms, us or ns); '
                            'CSV, MATLAB and Parquet files')
    group.add_argument('--current-unit', choices=sorted(CURRENT_UNITS), default='A')
    group.add_argument('--speed-unit', choices=sorted(SPEED_UNITS), default='rad/s')
    group.add_argument('--speed-counts-per-rev', type=positive, metavar='N',
                       help='the speed column holds encoder pulses per sample, N per rev')
    group.add_argument('--position-unit', choices=sorted(POSITION_UNITS), default='rad')
    group.add_argument('--position-counts-per-rev', type=positive, metavar='N',
                       help='the position column holds encoder counts, N per revolution')
    group.add_argument('--gear-ratio', type=positive, default=1.0, metavar='N',
                       help='speed and position measured at the output shaft of an N:1 gear; '
                            'parameters at the motor shaft, output-shaft values alongside')
    group.add_argument('--voltage-from-duty', type=positive, metavar='BUS_V',
                       help='voltage = duty column in [-1, 1] (or 0..1 with a direction '
                            'column) times the bus voltage BUS_V')
    group.add_argument('--duty-full-scale', type=positive, default=1.0, metavar='N',
                       help='the duty column at full duty: 100 for percent, 255 for an 8-bit '
                            'PWM value (default 1: a fraction)')
    group.add_argument('--negate', action='append', choices=SIGNED_CHANNELS,
                       metavar='CHANNEL',
                       help='flip the sign of a channel (voltage, current, speed, position): '
                            'an encoder counting the other way, a current sensor mounted '
                            'reversed; repeatable')
    group.add_argument('--current-sign-from', choices=CURRENT_SIGN_SOURCES, metavar='CHANNEL',
                       help='the current column is a magnitude (the output current of a motor '
                            'controller): give it the sign of the voltage (a drive that brakes '
                            'with 0 V logged) or of the speed (a drive that never brakes)')
    group.add_argument('--joint', metavar='NAME',
                       help='bags with control_msgs/msg/DynamicJointState or '
                            'sensor_msgs/msg/JointState: the joint (default: the only one); '
                            'SysId drivetrain JSON files: left (default) or right')
    group.add_argument('--interface', action='append', metavar='CHANNEL=NAME',
                       help='bags with DynamicJointState: the interface of a channel (default '
                            'voltage, current, velocity as speed, position); with JointState: '
                            'its field (position, velocity, effort; default velocity as speed, '
                            'position; the current from effort only with current=effort), the '
                            'other channels from their Float64 topics; repeatable')
    add_memory_budget(group)


def _cmd_validate(args):
    from dcmotor_id.identification.validate import format_validation, load_model, validate
    check_input_path(args.model, 'model ')
    _check_outputs(args, [args.model, *args.files])
    model = load_model(args.model)
    options = reading_options(args)
    records = []
    loaded, loss = load_records_reporting_loss(args.files, options=options,
                                               mechanical_only=model.mechanical_only)
    for record in loaded:
        mechanical = model.torque_constant if model.mechanical_only else None
        records += prepare_records([record], mechanical, args.resample, args.speed_cutoff)
    for note in ignored_flags(args, records):
        print(f'dcmotor-id: warning: {note}', file=sys.stderr)
    validation = validate(model, records, args.init_samples, options.position_factor)
    result = validation.as_dict()
    result['input_units'] = options.input_units()
    notes = [note for record in records for note in record.notes]
    if loss or notes:
        result['warnings'] = loss + notes + list(result.get('warnings') or [])
    if loss:
        result['data_loss'] = loss
    if args.json:
        _write_result(args, result)
    if args.report:
        from dcmotor_id.reports.identification import write_validation_report
        page = write_validation_report(args.report, validation,
                                       input_units=result['input_units'])
        print(f'report: {page}')
    print(format_validation(result))
    return 0


def _cmd_simulate(args):
    check_output_path(args.out, '--out')
    set_memory_budget(args.memory_budget * 1e9)
    samples = args.duration / args.sample_period
    check_budget(SIMULATE_BYTES_PER_SAMPLE * samples, f'--duration {args.duration:g}',
                 f'{samples:.3g} samples at --sample-period {args.sample_period:g} s',
                 'else give a shorter --duration or a longer --sample-period')
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
    from dcmotor_id.design.loops import add_gravity, gravity_feedforward
    from dcmotor_id.design.plant import (armature_lag_note, DesignOptions, load_result,
                                         motor_from_result)
    check_input_path(args.result, 'RESULT.json ')
    if args.json and args.json != STDOUT:
        check_output_path(args.json, '--json', inputs=[args.result])
    for option, place, writes in (('--report', args.report, REPORT_FILES),
                                  ('--export', args.export, EXPORT_FILES)):
        if place:
            check_output_path(place, option, directory=True, inputs=[args.result],
                              writes=writes)
    result = load_result(args.result)
    motor = motor_from_result(result, args.gear_ratio, args.output_shaft)
    options = DesignOptions(args.current_bandwidth, args.speed_bandwidth, args.phase_margin,
                            args.sample_period)
    notes = bandwidth_notes(result, args)
    design, gains = control_design.design(motor, options)
    design['notes'] += armature_lag_note(result, design['nominal']['speed']['bandwidth_hz'])
    if args.gravity_load:
        add_gravity(design['feedforward'], gravity_feedforward(motor))
    design['source'] = args.result
    if notes:
        design['warnings'] = notes + list(design.get('warnings') or [])
    for note in notes:
        print(f'dcmotor-id: warning: {note}', file=sys.stderr)
    if args.export:
        motor_shaft = motor_from_result(result, args.gear_ratio).values
        design['export'] = write_exports(args.export, motor, motor_shaft)
        print(f'exported: {args.export}')
    if args.report:
        from dcmotor_id.reports.design import write_design_report
        print(f'report: {write_design_report(args.report, design, motor, gains)}')
    if args.json:
        _write_result(args, design)
    print(control_design.format_design(design))
    return 0


def bandwidth_notes(result: Mapping[str, Any], args: argparse.Namespace) -> list[str]:
    """
    Return warnings for bandwidths beyond a twentieth of the sampling rate (the help's limit).

    The rate is ``--sample-period``'s, else the one the model was identified at; a bandwidth
    at or above its Nyquist frequency is refused (InputDataError).
    """
    dt = args.sample_period or result.get('sample_period_s')
    if not isinstance(dt, (int, float)) or isinstance(dt, bool) or not 0 < dt < float('inf'):
        return []
    where = ('--sample-period' if args.sample_period else 'the sampling rate the model was '
             'identified at')
    notes = []
    for label, value in (('--current-bandwidth', args.current_bandwidth),
                         ('--speed-bandwidth', args.speed_bandwidth)):
        if value is None:
            continue
        if value >= 0.5 / dt:
            raise InputDataError(f'{label} {value:g} Hz is at or above the Nyquist frequency '
                                 f'{0.5 / dt:g} Hz of {where} ({1 / dt:g} Hz): no digital loop '
                                 'reaches it; give at most a twentieth of the sampling rate '
                                 f'({1 / (20 * dt):g} Hz)')
        if value > 1.0 / (20.0 * dt):
            notes.append(f'{label} {value:g} Hz is above a twentieth of {where} '
                         f'({1 / (20 * dt):g} Hz): a drive sampled at {1 / dt:g} Hz will not '
                         'reach the designed response; lower it or sample faster')
    return notes


def _cmd_demo(args):
    from dcmotor_id.cli.demo import run_demo
    return run_demo()


def _cmd_fleet(args):
    from dcmotor_id.fleet import FleetOptions, run_fleet
    from dcmotor_id.cli.terminal import FleetProgressBar
    for path in args.paths:
        check_input_path(path, 'fleet input ', directory=True)
    check_output_path(args.history, '--history', directory=True,
                      inputs=[path for path in args.paths if is_bag_dir(path)])
    options = FleetOptions(args.motor_from, args.torque_constant, not args.no_discover,
                           args.window_s, args.min_window_s)
    summary = run_fleet(args.paths, args.history, options, scheduler=args.scheduler,
                        workers=args.workers, force=args.force,
                        retry_errors=not args.no_retry_errors,
                        progress=None if args.quiet else FleetProgressBar())
    print(summary.text())
    return 0


def _cmd_fleet_report(args):
    from dcmotor_id.reports.fleet import write_fleet_report
    check_input_path(args.history, 'HISTORY_DIR ', directory=True)
    check_output_path(args.out, '--out', directory=True, inputs=[args.history],
                      writes=REPORT_FILES)
    print(f'report: {write_fleet_report(args.history, args.out)}')
    return 0


def _add_fleet_commands(commands):
    """Add ``fleet`` and ``fleet-report`` (issue 14: dcmotor_id/fleet/)."""
    fleet = commands.add_parser('fleet', help='identify many recordings on a Dask cluster into '
                                'a per-motor Parquet history')
    fleet.add_argument('paths', nargs='+', metavar='BAG_OR_DIR',
                       help='bags, .mcap/.db3, CSV, .mat or .parquet files, or directories '
                            'searched recursively')
    fleet.add_argument('--history', required=True, metavar='HISTORY_DIR',
                       help='Parquet dataset the rows are appended to (one per window)')
    fleet.add_argument('--scheduler', metavar='ADDRESS',
                       help='address of a running Dask scheduler (default: a local cluster)')
    fleet.add_argument('--workers', type=whole_number_at_least_one, metavar='N',
                       help='worker processes of the local cluster, 1 or more (default: one '
                            'per core)')
    fleet.add_argument('--motor-from', default='namespace', metavar='namespace|path|PATTERN',
                       help="name motors by the topics' namespace (default), the directory "
                            'of the recording, or a regular expression on its path')
    fleet.add_argument('--torque-constant', type=positive, metavar='K',
                       help='mechanical-only mode: identify J, b, Mc [N m/A]')
    fleet.add_argument('--no-discover', action='store_true', help='skip effect discovery')
    fleet.add_argument('--force', action='store_true',
                       help='identify recordings already in the history again')
    fleet.add_argument('--no-retry-errors', action='store_true',
                       help='skip recordings whose rows in the history are errors (default: '
                            'identify them again, they may have been repaired)')
    fleet.add_argument('--window-s', type=positive, default=10.0, metavar='S',
                       help='window length [s] (default 10, as the identifier node)')
    fleet.add_argument('--min-window-s', type=positive, metavar='S',
                       help='shortest last window kept [s] (default half a window)')
    fleet.add_argument('--quiet', action='store_true', help='no progress bar on stderr')
    fleet.set_defaults(handler=_cmd_fleet)
    report = commands.add_parser('fleet-report', help='HTML page of a fleet history: trends, '
                                 'effects, change alarms, fleet overview')
    report.add_argument('history', metavar='HISTORY_DIR')
    report.add_argument('--out', required=True, metavar='DIR')
    report.set_defaults(handler=_cmd_fleet_report)


def _resamples(text):
    from dcmotor_id.identification.structure_uncertainty import check_resamples, MAX_RESAMPLES

    try:
        return check_resamples(int(text))
    except (ValueError, InputDataError):
        raise argparse.ArgumentTypeError(
            f'give a whole number of resamples from 2 to {MAX_RESAMPLES} (20 is a good start), '
            f'or 0 to leave the structure choice out; got {text}') from None


def _add_identify_command(commands: Any) -> None:
    """Add the ``identify`` subcommand and its arguments."""
    ident = commands.add_parser('identify', help='identify the motor from CSV files or bags')
    ident.add_argument('files', nargs='+', metavar='FILE',
                       help='CSV with columns t, voltage, current, speed (position optional), '
                            'rosbag2 directory (MCAP or sqlite3), or .mcap file')
    ident.add_argument('--json', metavar='OUT',
                       help='write the result as JSON here (- : on stdout, everything else '
                            'on stderr)')
    ident.add_argument('--method', choices=sorted(METHODS), default='refined',
                       help='refined (default: exact output error) or paper (the baseline)')
    ident.add_argument('--torque-constant', type=positive, metavar='K',
                       help='mechanical-only mode: identify J, b, Mc with torque K*current '
                            '[N m/A]')
    ident.add_argument('--no-discover', action='store_true',
                       help='skip the residual analysis and effect discovery')
    ident.add_argument('--report', metavar='DIR',
                       help='write an HTML report with plots (measured vs model before and '
                            'after, residual whiteness, parameters, effects) to DIR')
    ident.add_argument('--extended-vocabulary', action='store_true',
                       help='let the discovery loop also try the effects beyond the standard '
                            'vocabulary (none at present: viscous_asymmetry joined the '
                            'standard one)')
    ident.add_argument('--resample', action='store_true',
                       help='interpolate irregularly sampled data onto a uniform grid')
    ident.add_argument('--speed-cutoff', type=positive, metavar='HZ',
                       help='cut-off of the filter deriving speed from position [Hz]')
    ident.add_argument('--segment-column', metavar='NAME',
                       help='the column NAME marks the tests of a record (values > 0: a '
                            'test, a change of value the next one; 0: between tests): each '
                            'test is fitted as a record of its own, named in the output '
                            '(default: idle or braked stretches are found from the data)')
    for channel, kind in (('voltage', 'Float64'), ('current', 'Float64'),
                          ('speed', 'Float64'), ('samples', 'batched Float64MultiArray')):
        ident.add_argument(f'--{channel}-topic', default=BAG_TOPICS[channel], metavar='TOPIC',
                           help=f'bags: {kind} topic of the {channel} (default '
                                f'{BAG_TOPICS[channel]!r}, any namespace)')
    _add_reading_options(ident)
    ident.add_argument('--max-time', type=positive, default=DEFAULT_MAX_TIME_S, metavar='S',
                       help='time budget [s of CPU time of the process, so that other work '
                            'on the machine does not cut it short]: past it the best result '
                            f'so far is returned with a warning (default {DEFAULT_MAX_TIME_S:g})')
    ident.add_argument('--quiet', action='store_true',
                       help='no progress on stderr (on a terminal a line redrawn in place; '
                            'in a pipe or a log a line every few seconds)')
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


def _add_validate_command(commands: Any) -> None:
    """Add the ``validate`` subcommand and its arguments."""
    val = commands.add_parser('validate', help='simulate an identified model on new records '
                                               'and score it (NRMSE, fit %%, position RMSE)')
    val.add_argument('model', metavar='MODEL.json', help='the JSON identify --json wrote')
    val.add_argument('files', nargs='+', metavar='FILE', help='records, as for identify')
    val.add_argument('--json', metavar='OUT', help='write the scores as JSON here (- : on stdout)')
    val.add_argument('--report', metavar='DIR',
                     help='write measured vs simulated, residuals and fit figures to DIR')
    val.add_argument('--init-samples', type=int, default=20, metavar='N',
                     help='samples at the start for the initial state, not scored (20)')
    val.add_argument('--resample', action='store_true',
                     help='interpolate irregularly sampled data onto a uniform grid')
    val.add_argument('--speed-cutoff', type=positive, metavar='HZ',
                     help='cut-off of the filter deriving speed from position [Hz]')
    _add_reading_options(val)
    val.set_defaults(handler=_cmd_validate)


def _add_simulate_command(commands: Any) -> None:
    """Add the ``simulate`` subcommand and its arguments."""
    sim = commands.add_parser('simulate', help='simulate a motor of the paper to CSV')
    sim.add_argument('--motor', choices=sorted(PAPER_MOTORS), default='paper2')
    sim.add_argument('--excitation', choices=EXCITATION_KINDS, default='paper')
    sim.add_argument('--duration', type=positive, default=8.0, metavar='S')
    sim.add_argument('--sample-period', type=positive, default=1e-4, metavar='S')
    sim.add_argument('--noise', type=non_negative, default=0.0, metavar='REL',
                     help='white noise on current and speed, relative to their std')
    sim.add_argument('--amplitude', type=positive, metavar='V')
    sim.add_argument('--frequency', type=positive, metavar='HZ')
    sim.add_argument('--current-lsb', type=non_negative, default=0.0, metavar='A',
                     help='quantisation step of the current sensor')
    sim.add_argument('--speed-lsb', type=non_negative, default=0.0, metavar='RAD_S',
                     help='quantisation step of the speed sensor')
    sim.add_argument('--seed', type=int, default=0)
    sim.add_argument('--effect', action='append', metavar='NAME[:param=value,...]',
                     help='simulate with a true effect, e.g. load_torque:torque_Nm=0.5 or '
                          'sensor_delay:channel=speed,samples=3 (repeatable; names: '
                          + ', '.join(EFFECTS) + '); adds the shaft angle as position')
    sim.add_argument('--out', required=True, metavar='FILE.csv')
    add_memory_budget(sim)
    sim.set_defaults(handler=_cmd_simulate)


def _add_design_command(commands: Any) -> None:
    """Add the ``design`` subcommand and its arguments."""
    ctl = commands.add_parser('design', help='controller gains and model export from an '
                              'identify result (python-control)')
    ctl.add_argument('result', metavar='RESULT.json', help='JSON of `dcmotor-id identify --json`')
    ctl.add_argument('--current-bandwidth', type=positive, metavar='HZ',
                     help='closed current-loop bandwidth (default 200 Hz, at most a 20th of '
                          'the sampling rate; mechanical mode: default an ideal torque loop)')
    ctl.add_argument('--speed-bandwidth', type=positive, metavar='HZ',
                     help='closed speed-loop -3 dB bandwidth (default a 10th of the current '
                          'bandwidth)')
    ctl.add_argument('--phase-margin', type=positive, default=60.0, metavar='DEG',
                     help='phase margin of the speed loop (default 60)')
    ctl.add_argument('--sample-period', type=positive, metavar='S',
                     help='discrete gains (Tustin) for this controller period [s]; default '
                          'continuous')
    ctl.add_argument('--gear-ratio', type=positive, default=1.0, metavar='N',
                     help='motor speed / output speed (default 1)')
    ctl.add_argument('--output-shaft', action='store_true',
                     help='express speeds, gains and the model on the output shaft')
    ctl.add_argument('--gravity-load', action='store_true',
                     help='take the load_torque effect the identification found as gravity on '
                          'an elevator: kG of the feedforward (WPILib ElevatorFeedforward)')
    ctl.add_argument('--json', metavar='OUT', help='write the design as JSON here (- : on stdout)')
    ctl.add_argument('--report', metavar='DIR', help='write design.html with step responses '
                     'and Bode plots to DIR')
    ctl.add_argument('--export', metavar='DIR', help='write model_statespace.json, '
                     'sim_motor.yaml and urdf_dynamics.xml to DIR')
    ctl.set_defaults(handler=_cmd_design)


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser (the CLI contract)."""
    parser = argparse.ArgumentParser(
        prog='dcmotor-id', description='Identify DC motor parameters (Ra, La, CPhi, J, b, Mc).')
    parser.add_argument('--version', action=VersionAction)
    commands = parser.add_subparsers(dest='command', required=True)
    _add_identify_command(commands)
    _add_validate_command(commands)
    _add_simulate_command(commands)
    _add_design_command(commands)
    plan = commands.add_parser('plan', help='design a D-optimal PRBS/multisine for the exciter '
                               'within limits; print it and the expected standard errors')
    add_plan_arguments(plan)
    plan.set_defaults(handler=run_plan)

    demo = commands.add_parser('demo', help='simulate motor 2 and identify it with both methods')
    demo.set_defaults(handler=_cmd_demo)
    _add_fleet_commands(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """
    Run the command line; return the exit code.

    Every failure ends as a message, never as a traceback: 2 for bad input, data that cannot
    identify the motor and what the machine refuses (a path, memory), with what to do; 1 for
    anything else, with a short report (a bug); 130 when interrupted.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    with json_on_stdout(args):
        return run_reporting(args.handler, args)


if __name__ == '__main__':
    sys.exit(main())
