"""
Re-run the attack classes of reliability rounds 3 and 4 (issues 21 and 30), one case a class.

Every case runs ``dcmotor-id`` (or a node) as a process in a scratch directory, with a time
limit, and is judged by what a hostile user would see:

- lost/corrupt: a file the case must not touch (an input, a recording) changed;
- hang: the process did not end within its limit;
- internal error: exit 1, a traceback, or "internal error";
- silent wrong: exit 0 without the warning the case needs;
- unclear: another exit code, or the message lacks what it must name.

Usage (from the repository root, with the package importable)::

    python bench/attack_round4.py [--out bench/attack_round4_results.md]

Prints one line per case and the counts; exits 1 when any case is not clean.  The node cases
need rclpy (they run in their own ROS_DOMAIN_ID, on localhost).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import hashlib
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import textwrap
import time
from typing import Optional

import numpy as np

PYTHON = sys.executable
CLASSES = ('lost/corrupt', 'hang', 'silent wrong', 'internal error', 'unclear')


@dataclass
class Case:
    """One attack: the command, what must come out, what must stay untouched."""

    item: str
    name: str
    argv: list
    codes: tuple = (2,)
    phrases: tuple = ()
    timeout_s: float = 120.0
    untouched: tuple = ()
    max_s: Optional[float] = None
    env: dict = field(default_factory=dict)


def digest(path: str) -> str:
    """Return a digest of a file or of every file of a directory."""
    hasher = hashlib.sha256()
    names = [path] if os.path.isfile(path) else sorted(
        os.path.join(root, name) for root, _, files in os.walk(path) for name in files)
    for name in names:
        hasher.update(name.encode())
        with open(name, 'rb') as stream:
            hasher.update(stream.read())
    return hasher.hexdigest()


def cli(*args: str) -> list:
    """Return the argv of ``dcmotor-id ARGS``."""
    return [PYTHON, '-m', 'dcmotor_id.cli.main', *args]


def node(name: str, *parameters: str) -> list:
    """Return the argv of a node with ``-p`` parameters."""
    argv = [PYTHON, '-m', f'dcmotor_id.nodes.{name}', '--ros-args']
    for parameter in parameters:
        argv += ['-p', parameter]
    return argv


def judge(case: Case, work: str) -> tuple[str, str]:
    """Run a case; return its class ('clean' or one of CLASSES) and a short reason."""
    before = {path: digest(os.path.join(work, path)) for path in case.untouched}
    started = time.monotonic()
    try:
        done = subprocess.run(case.argv, cwd=work, capture_output=True, text=True,
                              timeout=case.timeout_s, env={**os.environ, **case.env})
    except subprocess.TimeoutExpired:
        return 'hang', f'still running after {case.timeout_s:g} s'
    elapsed = time.monotonic() - started
    text = done.stdout + done.stderr
    for path, value in before.items():
        if not os.path.exists(os.path.join(work, path)) or \
                digest(os.path.join(work, path)) != value:
            return 'lost/corrupt', f'{path} changed'
    if done.returncode == 1 or 'Traceback' in text or 'internal error' in text:
        return 'internal error', text.strip().splitlines()[-1][:160] if text.strip() else ''
    if case.max_s is not None and elapsed > case.max_s:
        return 'hang', f'took {elapsed:.0f} s (limit {case.max_s:g} s)'
    missing = [phrase for phrase in case.phrases if phrase not in text]
    if done.returncode not in case.codes or missing:
        kind = 'silent wrong' if done.returncode == 0 else 'unclear'
        return kind, f'exit {done.returncode}, missing {missing}: {text.strip()[-160:]}'
    return 'clean', f'exit {done.returncode} in {elapsed:.1f} s'


def make_inputs(work: str) -> None:
    """Write base.csv, its bag, model.json and the hostile files of the cases into ``work``."""
    def run(*args: str) -> None:
        subprocess.run(cli(*args), cwd=work, check=True, capture_output=True, timeout=300)

    run('simulate', '--duration', '3', '--sample-period', '1e-4', '--noise', '0.01', '--seed',
        '4', '--out', 'base.csv')
    run('identify', 'base.csv', '--no-discover', '--json', 'model.json')
    table = np.loadtxt(os.path.join(work, 'base.csv'), delimiter=',', skiprows=1)
    from dcmotor_id.formats.bag import write_bag
    stamps = 1_700_000_000_000_000_000 + np.arange(20000, dtype=np.int64) * 100_000
    write_bag(os.path.join(work, 'bag'), stamps, {'voltage': table[:20000, 1],
                                                  'current': table[:20000, 2],
                                                  'speed': table[:20000, 3]})
    shutil.copy(os.path.join(work, 'base.csv'), os.path.join(work, 'copy.csv'))
    os.makedirs(os.path.join(work, 'X'))
    shutil.copy(os.path.join(work, 'model.json'), os.path.join(work, 'X',
                                                               'model_statespace.json'))
    model = json.load(open(os.path.join(work, 'model.json')))
    model['parameters']['J'] *= 10
    json.dump(model, open(os.path.join(work, 'edited.json'), 'w'))
    with open(os.path.join(work, 'deep.json'), 'w') as stream:
        stream.write('[' * 100_000 + ']' * 100_000)
    with open(os.path.join(work, 'list.json'), 'w') as stream:
        stream.write('{"parameters": [1, 2, 3]}')
    with open(os.path.join(work, 'tag.yaml'), 'w') as stream:
        stream.write('parameters: !!python/object/apply:os.system ["echo hi"]\n')
    with open(os.path.join(work, 'longname.csv'), 'w') as stream:
        stream.write('t,voltage,current,' + 's' * 2_000_000 + '\n0,1,1,1\n')
    from scipy.io import savemat
    savemat(os.path.join(work, 'complex.mat'), {
        't': table[:, 0], 'voltage': table[:, 1], 'current': table[:, 2] + 0.5j,
        'speed': table[:, 3]})
    os.mkfifo(os.path.join(work, 'pipe.csv'))
    with open(os.path.join(work, 'padded.csv'), 'w') as stream:
        stream.write(open(os.path.join(work, 'base.csv')).read())
    os.truncate(os.path.join(work, 'padded.csv'), 2 * 10 ** 9)
    _bags(work)
    _absurd_history(work)


def _bags(work: str) -> None:
    """Write a bag with a 31-year gap and one whose payloads do not decode."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    for name, payload, gap in (('gap_bag', True, True), ('undecodable_bag', False, False)):
        writer = Writer(os.path.join(work, name), version=9, storage_plugin=StoragePlugin.MCAP)
        writer.open()
        connection = writer.add_connection('/voltage', 'std_msgs/msg/Float64',
                                           msgdef='float64 data',
                                           rihs01='RIHS01_' + '0' * 64)
        for k in range(6):
            stamp = 10 ** 9 + k * 10 ** 6 + (31 * 365 * 86400 * 10 ** 9 if gap and k >= 3
                                             else 0)
            data = b'\x00\x01\x00\x00' + struct.pack('<d', float(k)) if payload else \
                b'\x00\x01\x00'
            writer.write(connection, stamp, data)
        writer.close()


def _absurd_history(work: str) -> None:
    """Write a fleet history of one sane and one absurd motor."""
    from dcmotor_id.fleet.history import result_row, write_rows
    rows, day = [], 86_400 * 10 ** 9
    for motor, values in (('good', {'Ra': 1.6, 'La': 0.016, 'CPhi': 0.7, 'J': 0.0315,
                                    'b': 0.3, 'Mc': 1.0}),
                          ('bad', {'Ra': float('nan'), 'La': 0.016, 'CPhi': 0.7, 'J': -1e308,
                                   'b': 0.3, 'Mc': 1.0})):
        for k in range(4):
            result = {'parameters': values, 'stderr': dict.fromkeys(values, 1e-3),
                      'method': 'refined', 'effects': [], 'error_before': {},
                      'error_after': {}, 'unexplained': False}
            rows.append(dict(result_row(result), motor_id=motor, source_bag=f'/{motor}/{k}',
                             window_index=0, window_start_ns=day * (19_700 + k),
                             window_end_ns=day * (19_700 + k) + 10 ** 10, run_id='r',
                             processed_at=None))
    write_rows(os.path.join(work, 'history'), rows, 'r')


NODE_RUNTIME = textwrap.dedent("""
    import math, rclpy
    from rclpy.parameter import Parameter
    from dcmotor_id.nodes.identifier import Identifier
    from dcmotor_id.nodes.sim_motor import SimMotor
    rclpy.init()
    ident = Identifier(parameter_overrides=[Parameter('record', value=False)])
    for name, value in (('method', 'bogus'), ('input', 'telepathy'), ('window_s', 1e12),
                        ('min_window_s', 1e9), ('record_dir', '/proc/forbidden'),
                        ('effort_scale', math.inf)):
        outcome, = ident.set_parameters([Parameter(name, value=value)])
        print(name, 'refused' if not outcome.successful else 'TAKEN', outcome.reason)
    sim = SimMotor()
    outcome, = sim.set_parameters([Parameter('J', value=0.0)])
    print('J', 'refused' if not outcome.successful else 'TAKEN', outcome.reason)
    rclpy.try_shutdown()
""")

PAPER_SHORT_WINDOW = textwrap.dedent("""
    import warnings, numpy as np
    from dcmotor_id.core.errors import FitError
    from dcmotor_id.core.records import Record
    from dcmotor_id.identification.estimators.paper import PaperEstimator
    warnings.simplefilter('error')
    t = np.arange(300) * 1e-3
    record = Record(t, current=np.sin(50 * t), voltage=np.zeros_like(t), speed=np.cos(30 * t))
    try:
        PaperEstimator().fit([record])
    except FitError as error:
        print('refused:', error)
        raise SystemExit(2)
""")


def cases() -> list[Case]:
    """Return the cases, one (or a few) per class of issues 30 and 21."""
    ros = {'ROS_DOMAIN_ID': str(100 + os.getpid() % 100),
           'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    inside = 'inside the input bag directory'
    return [
        Case('1', 'identify --json onto the bag', cli('identify', 'bag', '--json',
                                                      'bag/bag.mcap'),
             phrases=(inside,), untouched=('bag',)),
        Case('1', 'identify --json onto metadata.yaml', cli(
            'identify', 'bag', '--json', 'bag/metadata.yaml'), phrases=(inside,),
            untouched=('bag',)),
        Case('1', 'validate --json onto the bag', cli(
            'validate', 'model.json', 'bag', '--json', 'bag/bag.mcap'), phrases=(inside,),
            untouched=('bag',)),
        Case('2', 'design --export over its input', cli(
            'design', 'X/model_statespace.json', '--export', 'X'),
            phrases=('would overwrite the input',), untouched=('X',)),
        Case('3', 'structure bootstrap 1000 under --max-time 10', cli(
            'identify', 'base.csv', '--structure-bootstrap', '1000', '--max-time', '10',
            '--quiet'), codes=(0,), phrases=('resamples were done',), max_s=40.0),
        Case('4', 'fleet --workers -3', cli('fleet', '.', '--history', 'h', '--workers', '-3'),
             phrases=('must be 1 or more',), timeout_s=30.0),
        Case('4', 'fleet --workers 0', cli('fleet', '.', '--history', 'h', '--workers', '0'),
             phrases=('must be 1 or more',), timeout_s=30.0),
        Case('5', 'replay of a 31-year gap', node('replay', 'bag:=gap_bag',
                                                  'start_delay_s:=0.0'),
             codes=(0,), phrases=('is played as max_gap_s', 'done: 6 messages played'),
             max_s=60.0, env=ros),
        Case('6', '--speed-unit rpm on rad/s', cli('identify', 'base.csv', '--no-discover',
                                                   '--speed-unit', 'rpm'),
             codes=(0,), phrases=('looks already in rad/s',)),
        Case('6', '--speed-unit deg/s on rad/s', cli('identify', 'base.csv', '--no-discover',
                                                     '--speed-unit', 'deg/s'),
             codes=(0,), phrases=('looks already in rad/s',)),
        Case('7', 'a byte-identical copy', cli('identify', 'base.csv', 'copy.csv',
                                               '--no-discover'),
             phrases=('byte for byte the same recording',)),
        Case('8', '--sample-period 10x off the stamps', cli(
            'identify', 'base.csv', '--no-discover', '--sample-period', '1e-3'), codes=(0,),
            phrases=('disagrees with the time column',)),
        Case('9', 'validate of an edited parameters block', cli(
            'validate', 'edited.json', 'base.csv'), phrases=('one model',)),
        Case('10', 'design --current-bandwidth 1e6', cli(
            'design', 'model.json', '--current-bandwidth', '1e6'), phrases=('Nyquist',)),
        Case('11', 'simulate --effect ...=nan', cli(
            'simulate', '--effect', 'load_torque:torque_Nm=nan', '--out', 'nan.csv'),
            phrases=('not a finite number',)),
        Case('12', 'node parameters changed at run time', [PYTHON, '-c', NODE_RUNTIME],
             codes=(0,), phrases=('method refused', 'input refused', 'window_s refused',
                                  'min_window_s refused', 'record_dir refused',
                                  'effort_scale refused', 'J refused'), env=ros),
        Case('12', 'min_window_s > window_s at start-up', node(
            'identifier', 'window_s:=1.0', 'min_window_s:=2.0'), phrases=('min_window_s',),
            env=ros, timeout_s=60.0),
        Case('13', 'a 2 MB column name', cli('identify', 'longname.csv'),
             phrases=('line 1', 'field larger than field limit')),
        Case('14', '--sample-period 1e300', cli('identify', 'base.csv', '--sample-period',
                                                '1e300'), phrases=('s apart',)),
        Case('15', 'validate of a JSON 100,000 deep', cli('validate', 'deep.json', 'base.csv'),
             phrases=('nested too deeply',)),
        Case('15', 'design of a JSON 100,000 deep', cli('design', 'deep.json'),
             phrases=('nested too deeply',)),
        Case('15', 'plan --prior of a JSON 100,000 deep', cli('plan', '--prior', 'deep.json'),
             phrases=('nested too deeply',)),
        Case('15', '"parameters": [1,2,3]', cli('validate', 'list.json', 'base.csv'),
             phrases=('not a mapping',)),
        Case('15', 'YAML with a !!python tag', cli('plan', '--prior', 'tag.yaml'),
             phrases=('not plain YAML',)),
        Case('16', 'fleet-report of an absurd motor', cli('fleet-report', 'history', '--out',
                                                          'report'),
             codes=(0,), phrases=('report:',)),
        Case('17', 'exciter rate_hz:=1e9', node('exciter', 'rate_hz:=1e9'),
             phrases=('out of range',), env=ros, timeout_s=60.0),
        Case('17', 'replay rate:=0.0', node('replay', 'rate:=0.0', 'bag:=bag'),
             phrases=('out of range',), env=ros, timeout_s=60.0),
        Case('17', 'replay rate:=-1.0', node('replay', 'rate:=-1.0', 'bag:=bag'),
             phrases=('out of range',), env=ros, timeout_s=60.0),
        Case('unclear', 'plan --rate 1e9', cli('plan', '--rate', '1e9'),
             phrases=('--memory-budget',)),
        Case('unclear', 'simulate --duration 1e9', cli('simulate', '--duration', '1e9',
                                                       '--out', 'big.csv'),
             phrases=('--memory-budget',)),
        Case('unclear', 'simulate --sample-period 1e-12', cli(
            'simulate', '--sample-period', '1e-12', '--out', 'big.csv'),
            phrases=('--memory-budget',)),
        Case('unclear', 'plan --ramp-in 100 --duration 5', cli(
            'plan', '--ramp-in', '100', '--duration', '5'), phrases=('never reach',)),
        Case('unclear', 'complex .mat', cli('identify', 'complex.mat'),
             phrases=('complex values',)),
        Case('unclear', '--speed-cutoff without a position', cli(
            'identify', 'base.csv', '--no-discover', '--speed-cutoff', '50'), codes=(0,),
            phrases=('--speed-cutoff 50 Hz ignored',)),
        Case('unclear', '--duty-full-scale without duty', cli(
            'identify', 'base.csv', '--no-discover', '--duty-full-scale', '100'), codes=(0,),
            phrases=('--duty-full-scale 100 ignored',)),
        Case('unclear', 'replay of undecodable payloads',
             node('replay', 'bag:=undecodable_bag'),
             phrases=('payload is not a valid',), env=ros, timeout_s=60.0),
        Case('unclear', "replay topic_prefix:='../bad name'", node(
            'replay', 'bag:=bag', 'topic_prefix:=../bad name'), phrases=('topic_prefix',),
            env=ros, timeout_s=60.0),
        Case('unclear', 'identifier record_dir not writable', node(
            'identifier', 'record_dir:=/proc/forbidden'), phrases=('record_dir',), env=ros,
            timeout_s=60.0),
        Case('unclear', 'paper method on a window without voltage',
             [PYTHON, '-c', PAPER_SHORT_WINDOW], phrases=('weight w1 (voltage) is 0',)),
        Case('round 3', 'a FIFO as input', cli('identify', 'pipe.csv'),
             phrases=('FIFO',), timeout_s=30.0),
        Case('round 3', '/dev/zero as input', cli('identify', '/dev/zero'),
             phrases=('character device',), timeout_s=30.0),
        Case('round 3', '--json onto the input', cli('identify', 'base.csv', '--json',
                                                     'base.csv'),
             phrases=('is the input',), untouched=('base.csv',)),
        Case('round 3', 'the same file twice', cli('identify', 'base.csv', 'base.csv'),
             phrases=('given twice',)),
        Case('round 3', 'a NUL-padded 2 GB CSV', cli('identify', 'padded.csv'),
             phrases=('NUL byte',), max_s=30.0),
    ]


def main(argv: Optional[list[str]] = None) -> int:
    """Run every case; print and optionally write the results; 1 if any is not clean."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--out', help='write the results as Markdown')
    args = parser.parse_args(argv)
    counts = dict.fromkeys(('clean',) + CLASSES, 0)
    lines = ['| item | case | result | detail |', '|---|---|---|---|']
    with tempfile.TemporaryDirectory(prefix='attack_round4_') as work:
        make_inputs(work)
        for case in cases():
            kind, reason = judge(case, work)
            counts[kind] += 1
            print(f'{kind:14s} [{case.item}] {case.name}: {reason}', flush=True)
            lines.append(f'| {case.item} | {case.name} | {kind} | '
                         f'{reason.replace("|", "/")[:120]} |')
    summary = ', '.join(f'{counts[name]} {name}' for name in ('clean',) + CLASSES)
    print(summary)
    if args.out:
        with open(args.out, 'w', encoding='utf-8') as stream:
            stream.write('# Reliability attack, rounds 3 and 4 (bench/attack_round4.py)\n\n'
                         f'{summary}\n\n' + '\n'.join(lines) + '\n')
    return 0 if counts['clean'] == sum(counts.values()) else 1


if __name__ == '__main__':
    raise SystemExit(main())
