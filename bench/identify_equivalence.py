"""
Same outputs before and after a restructuring: identify, validate and design on a corpus.

Three steps, each a sub-command::

    python bench/identify_equivalence.py data DATA_DIR          # write the corpus's records once
    python bench/identify_equivalence.py run DATA_DIR OUT_DIR   # run every case, one JSON each
    python bench/identify_equivalence.py compare OUT_A OUT_B    # name the cases that differ

``run`` uses the ``dcmotor_id`` on ``PYTHONPATH`` (run it once on the old tree, once on the
new one, against the same ``DATA_DIR``). Each case runs in a subprocess of its own under
``timeout``; its JSON is written with the wall-clock fields removed, or the refusal (exit code
and the last line of stderr) when the command refused.  ``--jobs N`` runs N cases at once.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
from pathlib import Path
import subprocess
import sys

#: Wall-clock and CPU-time fields, removed before comparing (they differ from run to run);
#: so are the keys that end in one of them (``starts_cpu_s``).
TIMING_KEYS = ('elapsed_s', 'elapsed', 'wall_s', 'cpu_s', 'time_used_s')
#: Seconds a case may take before it is stopped (then recorded as a timeout).
CASE_TIMEOUT_S = 300
#: The effects of the vocabulary, each simulated alone with the simulator's defaults (no
#: magnitude: the base model's data under the effect's name) ...
EFFECTS = ('load_torque', 'coulomb_asymmetry', 'stribeck', 'quadratic_drag', 'brush_drop',
           'current_offset', 'sensor_delay', 'resistance_drift', 'cogging',
           'viscous_asymmetry')
#: ... and with a magnitude the paper2 motor's data show (``strong_NAME``).
STRONG = {'load_torque': 'torque_Nm=0.5', 'coulomb_asymmetry': 'delta_Nm=0.3',
          'stribeck': 'excess_Nm=0.5,velocity_rad_s=2',
          'quadratic_drag': 'coefficient_Nm_s2=0.001', 'brush_drop': 'drop_V=1.5',
          'current_offset': 'offset_A=0.3',
          'sensor_delay': 'channel=current,samples=2', 'resistance_drift': 'rate_ohm_per_s=0.1',
          'cogging': 'amplitude_Nm=0.3,cycles_per_rev=4', 'viscous_asymmetry': 'delta_Nm_s=0.05'}
#: Laboratory scenarios of :mod:`dcmotor_id.simulation.lab_scenarios` written as CSV.
LAB = ('servo_torque_steps', 'small_motor_pwm_steps', 'hobby_motor_encoder',
       'directions_with_load', 'voltage_step_from_rest', 'coarse_speed_steps',
       'ball_screw_sine', 'axis_both_ways')
EMPS = '/work/shared/data/emps/DATA_EMPS.mat'
EMPS_ARGS = ['--column', 'current=vir', '--column', 'position=qm', '--position-unit', 'm',
             '--torque-constant', '35.15065188']


def _cli(*arguments: str) -> list[str]:
    """Return the command line of ``dcmotor-id`` with these arguments."""
    return [sys.executable, '-m', 'dcmotor_id.cli.main', *arguments]


def _simulations() -> dict[str, list[str]]:
    """Return the simulated records by file stem: the arguments of ``dcmotor-id simulate``."""
    short = ['--duration', '2', '--sample-period', '1e-3', '--noise', '0.01']
    runs = {f'effect_{name}': short + ['--effect', name] for name in EFFECTS}
    runs.update({f'strong_{name}': short + ['--effect', f'{name}:{values}']
                 for name, values in STRONG.items()})
    runs['effect_load_cogging'] = short + ['--effect', 'load_torque', '--effect', 'cogging']
    runs['effect_delay_drop'] = short + ['--effect', 'sensor_delay:channel=speed,samples=3',
                                         '--effect', 'brush_drop']
    for excitation in ('sine', 'sawtooth', 'prbs', 'chirp', 'multisine', 'paper'):
        runs[f'base_{excitation}'] = short + ['--excitation', excitation]
    runs['base_paper1'] = short + ['--motor', 'paper1']
    runs['base_noisefree'] = ['--duration', '2', '--sample-period', '1e-3']
    runs['base_quantised'] = short + ['--current-lsb', '0.01', '--speed-lsb', '0.05']
    return runs


def _cases(data: Path) -> dict[str, list[str]]:
    """Return the cases by name: the arguments of ``dcmotor-id identify`` (no ``--json``)."""
    cases = {name: [str(data / f'{name}.csv')] for name in _simulations()}
    for name in ('base_prbs', 'effect_load_torque', 'effect_cogging', 'strong_load_torque'):
        csv = str(data / f'{name}.csv')
        cases[f'{name}__paper'] = [csv, '--method', 'paper']
        cases[f'{name}__no_discover'] = [csv, '--no-discover']
        cases[f'{name}__mechanical'] = [csv, '--torque-constant', '0.7']
        cases[f'{name}__position_only'] = [str(data / f'{name}_position.csv')]
    cases['base_sine__measured'] = [str(data / 'base_sine.csv'), '--initial-state', 'measured']
    cases['base_chirp__criterion_both'] = [str(data / 'base_chirp.csv'), '--criterion', 'both']
    cases['effect_load_torque__criterion_position'] = [str(data / 'effect_load_torque.csv'),
                                                       '--criterion', 'position']
    cases['effect_viscous_asymmetry__extended'] = [str(data / 'effect_viscous_asymmetry.csv'),
                                                   '--extended-vocabulary']
    cases['two_records'] = [str(data / 'base_prbs.csv'), str(data / 'base_chirp.csv')]
    for name in LAB:
        csv = str(data / f'lab_{name}.csv')
        torque = data / f'lab_{name}.torque'
        cases[f'lab_{name}'] = [csv] + (['--torque-constant', torque.read_text().strip()]
                                        if torque.exists() else [])
    if Path(EMPS).exists():
        cases['emps__no_discover'] = [EMPS, *EMPS_ARGS, '--no-discover']
        cases['emps'] = [EMPS, *EMPS_ARGS, '--extended-vocabulary']
    return cases


def write_data(data: Path) -> None:
    """Write the corpus's records: simulated CSVs, position-only copies, lab scenarios."""
    data.mkdir(parents=True, exist_ok=True)
    for name, arguments in _simulations().items():
        if (data / f'{name}.csv').exists():
            continue
        subprocess.run(_cli('simulate', *arguments, '--out', str(data / f'{name}.csv')),
                       check=True, capture_output=True)
    for name in ('base_prbs', 'effect_load_torque', 'effect_cogging', 'strong_load_torque'):
        lines = (data / f'{name}.csv').read_text().splitlines()
        header = lines[0].split(',')
        if 'position' not in header:  # the simulator adds the angle with an effect only
            continue
        keep = [index for index, column in enumerate(header) if column != 'speed']
        (data / f'{name}_position.csv').write_text(
            '\n'.join(','.join(line.split(',')[i] for i in keep) for line in lines) + '\n')
    from dcmotor_id.formats.csv import write_csv
    from dcmotor_id.simulation.lab_scenarios import SCENARIOS
    for name in LAB:
        scenario = SCENARIOS[name](seed=0)
        write_csv(data / f'lab_{name}.csv', scenario.records[0])
        if scenario.torque_constant is not None:
            (data / f'lab_{name}.torque').write_text(repr(scenario.torque_constant))


def _without_timing(value):
    """Return ``value`` with the wall-clock fields removed, recursively."""
    if isinstance(value, dict):
        return {key: _without_timing(item) for key, item in value.items()
                if not key.endswith(TIMING_KEYS)}
    if isinstance(value, list):
        return [_without_timing(item) for item in value]
    return value


def _run_command(arguments: list[str], json_path: Path) -> dict:
    """Run one command writing ``json_path``; return its JSON or its refusal."""
    try:
        done = subprocess.run(['timeout', str(CASE_TIMEOUT_S), *arguments], capture_output=True,
                              text=True, timeout=CASE_TIMEOUT_S + 30)
    except subprocess.TimeoutExpired:
        return {'refused': 'timeout'}
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [''])[-1]
        return {'refused': done.returncode, 'message': last}
    return _without_timing(json.loads(json_path.read_text()))


def run_case(name: str, arguments: list[str], out: Path) -> str:
    """Run one case (and ``validate``/``design`` on its result); write ``out/name.json``."""
    work = out / 'work'
    result = work / f'{name}.json'
    entry = {'identify': _run_command(_cli('identify', *arguments, '--json', str(result),
                                           '--quiet'), result)}
    if 'refused' not in entry['identify'] and not name.startswith('emps'):
        records = [argument for argument in arguments[:2] if argument.endswith('.csv')]
        scores = work / f'{name}.validate.json'
        entry['validate'] = _run_command(_cli('validate', str(result), *records, '--json',
                                              str(scores)), scores)
        design = work / f'{name}.design.json'
        entry['design'] = _run_command(_cli('design', str(result), '--json', str(design)),
                                       design)
    (out / f'{name}.json').write_text(json.dumps(entry, indent=1, sort_keys=True) + '\n')
    return name


def run_all(data: Path, out: Path, jobs: int, only: list[str]) -> None:
    """Run every case (or those named in ``only``) into ``out``."""
    (out / 'work').mkdir(parents=True, exist_ok=True)
    cases = {name: arguments for name, arguments in _cases(data).items()
             if not only or name in only}
    print(f'{len(cases)} cases', flush=True)
    with concurrent.futures.ThreadPoolExecutor(jobs) as pool:
        futures = [pool.submit(run_case, name, arguments, out)
                   for name, arguments in cases.items()]
        for future in concurrent.futures.as_completed(futures):
            print('done', future.result(), flush=True)


def compare(first: Path, second: Path) -> int:
    """
    Print the cases whose outputs differ or are missing; return their count.

    The output directories' own paths (in the design's ``source``) are not a difference.
    """
    names = sorted({path.name for path in first.glob('*.json')}
                   | {path.name for path in second.glob('*.json')})
    differing = 0
    for name in names:
        a, b = first / name, second / name
        if not a.exists() or not b.exists():
            print(f'{name}: only in {first if a.exists() else second}')
            differing += 1
        elif _normalised(a, first) != _normalised(b, second):
            print(f'{name}: differs')
            differing += 1
    print(f'{len(names)} cases, {differing} differ')
    return differing


def _normalised(path: Path, out: Path) -> str:
    """Return a case's JSON without timing fields, its output directory's path replaced."""
    entry = _without_timing(json.loads(path.read_text()))
    return json.dumps(entry, indent=1, sort_keys=True).replace(str(out), '<out>')


def main(argv: list[str] | None = None) -> int:
    """Run the sub-command named on the command line."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    commands = parser.add_subparsers(dest='command', required=True)
    commands.add_parser('data').add_argument('data', type=Path)
    runner = commands.add_parser('run')
    runner.add_argument('data', type=Path)
    runner.add_argument('out', type=Path)
    runner.add_argument('--jobs', type=int, default=max(1, (os.cpu_count() or 1) // 2))
    runner.add_argument('--only', nargs='*', default=[])
    comparer = commands.add_parser('compare')
    comparer.add_argument('first', type=Path)
    comparer.add_argument('second', type=Path)
    args = parser.parse_args(argv)
    if args.command == 'data':
        write_data(args.data)
    elif args.command == 'run':
        run_all(args.data, args.out, args.jobs, args.only)
    else:
        return 1 if compare(args.first, args.second) else 0
    return 0


if __name__ == '__main__':
    sys.exit(main())
