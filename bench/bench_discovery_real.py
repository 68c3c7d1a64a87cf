"""
False effects on real recordings: the effects ``identify`` adds under each discovery rule.

For every real record of the scorecard (``bench/bench_real.py``: the HSM150 servo's 12 torque
steps, the UBC MECH 467 ball screw's Part B and C records, EMPS's two records; with
``--sysidopt``, ``--wheels``, ``--qube`` also its robot and lab logs: SysIdOpt's SysId
routine, the omni robot's three wheel motors as logged and with the current signed, the
QUBE-Servo 2's records), the default
``dcmotor-id identify`` (in process, with the scorecard's reading options and torque constant)
is run once per rule of :data:`dcmotor_id.identification.discovery.state.ACCEPTANCE_RULES`, and
the effects it adds are listed. The references name the effects each set is known to have
(HSM150 and EMPS: a constant load torque, the offset of their references; EMPS also the
direction-dependent friction of its published model); any other effect counts as a false one
(the robot and lab logs document none beyond the base model: the wheels' constant torque
``T_0`` is the base's Coulomb friction).

Run from the repository root (the data fetched as for ``bench/bench_real.py``)::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_discovery_real.py --hsm150 HSM150-data \
        --mech467 mech467 --emps data/emps [--sysidopt SysIdOpt] [--wheels WHEELS] \
        [--qube ACL_LABisca] [--quick] [--rules RULE ...] [--out bench/discovery_real_results.md]
"""

import argparse
import json
import os
import sys
import tempfile
import time
import warnings

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import bench_real  # noqa: E402  (the scorecard's data sets)

from dcmotor_id.cli.main import main as cli_main  # noqa: E402
from dcmotor_id.identification.discovery.state import ACCEPTANCE_RULES  # noqa: E402

from common import judged_by  # noqa: E402,I100

#: Effects each data set is known to have (its references' offset; EMPS's published
#: direction-dependent friction, Fv+ 166.7 / Fv- 240.4 N s/m, Fc+ 20.1 / Fc- 20.6 N, and its
#: own account of asymmetric friction); others are false.
KNOWN = {'hsm150': ('load_torque', 'coulomb_asymmetry'),
         'emps': ('load_torque', 'coulomb_asymmetry', 'viscous_asymmetry'), 'mech467': (),
         'SysIdOpt': (), 'wheels': (), 'QUBE-Servo 2': ()}


def effects_of(arguments, directory):
    """Run ``identify ARGUMENTS`` in process; return the effects' names and the time."""
    out = os.path.join(directory, 'result.json')
    argv = ['identify', *arguments, '--json', out]
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        try:
            code = cli_main(argv)
        except SystemExit as stop:
            code = stop.code
    elapsed = time.perf_counter() - start
    if code != 0 or not os.path.isfile(out):
        return None, elapsed
    with open(out, encoding='utf-8') as stream:
        result = json.load(stream)
    os.remove(out)
    return [effect['name'] for effect in result.get('effects', [])], elapsed


def data_sets(args, cache):
    """Return the data sets the arguments name."""
    sets = []
    if args.hsm150:
        sets.append(bench_real.hsm150_set(args.hsm150, cache, args.quick))
    if args.mech467:
        sets.append(bench_real.mech467_set(args.mech467, cache, args.quick))
    if args.emps:
        sets.append(bench_real.emps_set(args.emps, args.quick))
    return sets


def runs_of(args, cache):
    """Return ``(data set, record, identify's arguments)`` of every record asked for."""
    runs = [(data_set.name, name, [rec.path, *data_set.reading, '--torque-constant',
                                   f'{data_set.torque_constant:.6g}'])
            for data_set in data_sets(args, cache) for name, rec in data_set.records.items()]
    if args.sysidopt:
        runs += [(run.data, run.label, run.args)
                 for run in bench_real.sysidopt_runs(args.sysidopt, cache)]
    if args.wheels:
        runs += [(run.data, run.label, run.args)
                 for run in bench_real.wheels_runs(args.wheels, cache)[0]]
    if args.qube:
        runs += [(run.data, run.label, run.args)
                 for run in bench_real.qube_runs(args.qube, cache)]
    return runs


def main(argv=None):
    """Write the table of effects per record and rule."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--hsm150')
    parser.add_argument('--mech467')
    parser.add_argument('--emps')
    parser.add_argument('--sysidopt', help='calcmogul/SysIdOpt (work tree or bare clone)')
    parser.add_argument('--wheels', help='BrOleg5/research-wheel-slippage')
    parser.add_argument('--qube', help='JackDelcaro/ACL_LABisca')
    parser.add_argument('--quick', action='store_true')
    parser.add_argument('--out', default='bench/discovery_real_results.md')
    parser.add_argument('--rules', nargs='+', choices=ACCEPTANCE_RULES,
                        default=list(ACCEPTANCE_RULES), help='the rules compared (default all)')
    args = parser.parse_args(argv)
    rules = tuple(args.rules)
    columns = ' | '.join(f'effects ({rule}) | false ({rule}) | time ({rule})'
                         for rule in rules)
    lines = ['| data set | record | ' + columns + ' |',
             '|---|---|' + '---|---|---|' * len(rules)]
    totals = {rule: [0, 0] for rule in rules}
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as directory:
        for data, name, arguments in runs_of(args, os.path.join(directory, 'cache')):
            cells = []
            for rule in rules:
                with judged_by(rule):
                    names, seconds = effects_of(arguments, directory)
                false = None if names is None else [item for item in names
                                                    if item not in KNOWN[data]]
                totals[rule][0] += bool(false)
                totals[rule][1] += names is not None
                cells += ['refused' if names is None else ', '.join(names) or 'none',
                          '-' if false is None else ', '.join(false) or '0',
                          f'{seconds:.1f} s']
            lines.append(f'| {data} | {name} | ' + ' | '.join(cells) + ' |')
            print(lines[-1], flush=True)
    summary = ', '.join(f'{rule}: {count} of {runs} records with a false effect'
                        for rule, (count, runs) in totals.items())
    text = '\n'.join([
        '# False effects on real records, per discovery rule', '',
        f'Generated by `python bench/bench_discovery_real.py{" --quick" if args.quick else ""}'
        f'{" --rules " + " ".join(rules) if rules != ACCEPTANCE_RULES else ""}` '
        '(HSM150, MECH 467 and EMPS as for bench/bench_real.py) in '
        f'{time.perf_counter() - started:.0f} s.  Known effects: HSM150 and EMPS a constant '
        'load torque (or its equivalent, coulomb_asymmetry), the offset of their references; '
        'EMPS also viscous_asymmetry (its published direction-dependent friction, Fv+ 166.7 / '
        'Fv- 240.4 N s/m); MECH 467 and the robot and lab logs none documented.  '
        + summary + '.', ''] + lines) + '\n'
    with open(args.out, 'w', encoding='utf-8') as stream:
        stream.write(text)
    print(summary)
    return 0


if __name__ == '__main__':
    sys.exit(main())
