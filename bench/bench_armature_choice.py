"""
The armature's choice (issue 29): full equation or quasi-static, by a constant or by a test.

Stage 3 (:mod:`dcmotor_id.identification.pipeline.armature`) chooses between the full armature
equation (La) and the quasi-static one (La -> 0).  For every case this bench stops the
pipeline at that stage, fits the quasi-static equation whatever the gate says, and records
what each rule would choose:

* *gate alone*: ``la_unresolved`` (La/Ra below the sample period, or La's relative standard
  error above 0.5), which alone lets a refit happen, and the refit kept whenever it fits;
* *margin* (what the stage uses, ``quasi_kept``'s default): the gate, then the refit kept when its
  current simulation error is at most ``1.25 full + 0.5`` points (``QUASI_MARGIN``);
* *likelihood-ratio*: the gate, then the refit kept unless the likelihood ratio of the full
  equation over the quasi-static one on the current's effective samples
  (:func:`~dcmotor_id.identification.pipeline.armature.armature_likelihood_ratio`) exceeds
  its chi-square threshold (size 0.135 %); the same ratio without the gate, and on the
  current and the speed after it;
* *La/Ra not 3 errors above dt*: the refit kept unless the full fit's La/Ra is more than 3
  of its standard errors above the sample period (a one-sided test of the gate's own
  question);

with the errors of Ra, CPhi and J of each fit against the truth.  Cases: the random motors of
``bench_random_motors.py``; the same motors with La set so that La/Ra is a given multiple of
the sample period (``--ratios``; 1 or 2 ms, speed sensor, step, stairs and PRBS); the lab
classes of :mod:`dcmotor_id.simulation.lab_scenarios` (seeds 0 and 1).

The brief's size (La wrongly dropped): the share choosing quasi-static where La/Ra is at least
twice the sample period.  Its power: the share choosing it where La/Ra is below the sample
period.  The likelihood ratio's own size (the full equation kept where La -> 0 holds): the
share choosing the full equation where La/Ra is below a tenth of a sample.

Run from the repository root (about 1-4 minutes on 2 cores, by the load)::

    PYTHONPATH=$PWD .venv/bin/python bench/bench_armature_choice.py --out FILE

Its table is the top section of ``bench/armature_results.md`` (pasted above the older ones).
"""

import argparse
from dataclasses import replace
import os
import sys
import time
import warnings

import numpy as np

from dcmotor_id.core.errors import DcMotorIdError
from dcmotor_id.core.records import Record
from dcmotor_id.identification.estimators.uncertainty import with_robust_stderr
from dcmotor_id.identification.identify import identify, prepare_records
from dcmotor_id.identification.pipeline import armature as stage, run
from dcmotor_id.simulation.lab_scenarios import simulate_drive

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_armature  # noqa: E402,I100  (beside this script)
import bench_random_motors  # noqa: E402,I100
from common import markdown_table, write_report  # noqa: E402,I100

NAMES = ('Ra', 'CPhi', 'J')


class Stop(Exception):
    """Raised by the probe once stage 3's choice is measured."""


def probe(truth):
    """Return a stand-in for stage 3 that measures every rule's choice, then stops."""
    def measure(inputs, fit):
        if inputs.mechanical_only:
            raise Stop(None)
        dt = inputs.records[0].sample_period_s
        robust = with_robust_stderr(fit.estimate)
        la, la_se, ra = (robust.parameters['La'], robust.stderr['La'],
                         robust.parameters['Ra'])
        row = {'dt': dt, 'fit_tau': la / ra, 'tau_z': (la / ra - dt) / (la_se / ra),
               'gate': stage.la_unresolved(la, la_se, ra, dt),
               'full': errors_of(fit.estimate.parameters, truth)}
        models = replace(fit.models, quasi_static=True)
        refit = stage.quasi_static_fit(fit.estimate, models, inputs.initial_state,
                                       inputs.progress, inputs.on.position_error)
        if refit is not None:
            free = inputs.initial_state == 'estimate'
            row['both'], row['needed'] = stage.armature_likelihood_ratio(
                fit.estimate, refit[0], fit.models, models, free, ('current', 'speed'))
            row['lr_current'] = stage.armature_likelihood_ratio(fit.estimate, refit[0], fit.models,
                                                                models, free)[0]
            row.update({choice: stage.quasi_kept(fit, refit, models, inputs.initial_state,
                                                 choice)
                        for choice in stage.ARMATURE_CHOICES})
            row.update(quasi=errors_of(refit[0].parameters, truth),
                       currents=(fit.errors.get('current_nrmse_pct') or 0.0,
                                 refit[1].get('current_nrmse_pct')))
        raise Stop(row)
    return measure


def errors_of(values, truth):
    """Relative errors [%] of Ra, CPhi and J."""
    return {name: 100.0 * (values[name] / getattr(truth, name) - 1.0) for name in NAMES}


def measure_case(truth, records, constant):
    """Run the pipeline to stage 3 on one case; return the probe's row (None: no base fit)."""
    original = run.armature
    run.armature = probe(truth)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            identify(prepare_records(records, constant), torque_constant=constant)
    except Stop as stop:
        return stop.args[0]
    except DcMotorIdError:
        return None
    finally:
        run.armature = original
    return None


def ratio_case(index, ratio):
    """Return a random motor of ``bench_random_motors`` with La/Ra of ``ratio`` samples."""
    kind = bench_random_motors.KINDS[index % 3]
    rng = np.random.default_rng(9000 + index)
    motor, volts, tau_m = bench_random_motors.random_motor(rng)
    dt = (1e-3, 2e-3)[(index // 3) % 2]
    motor = replace(motor, La=ratio * dt * motor.Ra)
    command = bench_random_motors.command_of(kind, volts, tau_m, dt, rng)
    out = simulate_drive(motor, command, dt)
    t = np.arange(command.size) * dt
    current = out['current'] + rng.normal(0.0, 0.005 * volts / motor.Ra, command.size)
    speed = out['speed'] + rng.normal(0.0, 0.005 * volts / motor.CPhi, command.size)
    return motor, Record(t, current=current, voltage=command, speed=speed,
                         source=f'ratio {ratio:g} case {index}'), kind


def cases(random_count, ratios, per_ratio, lab):
    """Yield (label, truth, records, torque constant) of every case."""
    for index in range(random_count):
        motor, record, row = bench_random_motors.case(index)
        yield f"random {index} {row['kind']}", motor, [record], None
    for ratio in ratios:
        for index in range(per_ratio):
            motor, record, kind = ratio_case(index, ratio)
            yield f'ratio {ratio:g} {index} {kind}', motor, [record], None
    if lab:
        yield from bench_armature.lab_cases()


#: Rules measured: name -> whether it chooses the quasi-static equation on a row.
RULES = {
    'gate alone (refit kept)': lambda row: row['gate'] and 'quasi' in row,
    'margin (default: gate, then 1.25 full + 0.5)': lambda row: (
        row['gate'] and row.get('current-error-margin', False)),
    'likelihood-ratio (gate, then LR of the current)': lambda row: (
        row['gate'] and row.get('likelihood-ratio', False)),
    'LR of the current alone': lambda row: 'quasi' in row and row['lr_current'] <= row['needed'],
    'gate, then LR of current and speed': lambda row: (
        row['gate'] and 'quasi' in row and row['both'] <= row['needed']),
    'La/Ra not 3 errors above dt': lambda row: 'quasi' in row and not row['tau_z'] > 3.0,
}
#: Bins of the true La/Ra in sample periods.
BINS = (('La/Ra < 0.1 dt', 0.0, 0.1), ('0.1 dt <= La/Ra < dt', 0.1, 1.0),
        ('dt <= La/Ra < 2 dt', 1.0, 2.0), ('La/Ra >= 2 dt', 2.0, np.inf))


def within(errors):
    """Whether Ra and CPhi are within 5 %, J within 10 %."""
    return all(abs(errors[name]) <= bench_random_motors.GOALS_PCT[name] for name in NAMES)


def chosen_errors(row, rule):
    """Return the errors of the fit a rule keeps."""
    return row['quasi'] if RULES[rule](row) else row['full']


def summary_rows(rows):
    """Per bin of La/Ra and rule: cases, quasi-static chosen, the kept fit within the goals."""
    table = []
    for label, low, high in BINS:
        mine = [row for row in rows if low <= row['ratio'] < high]
        for rule in RULES:
            table.append([label, rule, str(len(mine)),
                          str(sum(bool(RULES[rule](row)) for row in mine)),
                          str(sum(within(chosen_errors(row, rule)) for row in mine))])
    return table


def detail_rows(rows):
    """Every case where the rules disagree, or a quasi-static fit is within the goals alone."""
    table = []
    for row in rows:
        choices = [bool(RULES[rule](row)) for rule in RULES]
        if len(set(choices)) == 1:
            continue
        table.append([row['case'], f"{row['ratio']:.2f}", f"{row['fit_tau'] / row['dt']:.2f}",
                      'yes' if row['gate'] else 'no',
                      f"{row['lr_current']:.3g}, {row['both']:.3g} / {row['needed']:.3g}"
                      if 'quasi' in row else '-',
                      '-' if 'currents' not in row else
                      f"{row['currents'][0]:.3g} / {row['currents'][1]:.3g}",
                      ', '.join(f'{name} {value:+.1f}' for name, value in row['full'].items()),
                      ', '.join(f'{name} {value:+.1f}' for name, value in row['quasi'].items())
                      if 'quasi' in row else '-',
                      ' '.join('Q' if choice else 'F' for choice in choices)])
    return table


def main(argv=None):
    """Measure the cases; write the markdown report."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--random-cases', type=int, default=120)
    parser.add_argument('--ratios', type=float, nargs='*', default=[0.25, 0.5, 2.0, 4.0, 8.0])
    parser.add_argument('--per-ratio', type=int, default=12)
    parser.add_argument('--no-lab', action='store_true')
    parser.add_argument('--out', default='/tmp/armature_choice.md')
    args = parser.parse_args(argv)
    load, started = os.getloadavg(), time.time()
    rows = []
    for label, truth, records, constant in cases(args.random_cases, args.ratios,
                                                 args.per_ratio, not args.no_lab):
        row = measure_case(truth, records, constant)
        if row is not None:
            rows.append({**row, 'case': label, 'ratio': truth.La / truth.Ra / row['dt']})
        print(f'[{time.time() - started:5.0f} s] {label}: '
              f"{'-' if row is None else row.get('lr_current')}", file=sys.stderr, flush=True)
    lines = ["# The armature's choice: the margin against the likelihood ratio (issue 29)",
             '', f'Command: `bench/bench_armature_choice.py {" ".join(argv or sys.argv[1:])}`  ',
             f'Load average at the start: {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}; run '
             f'time {time.time() - started:.0f} s', '',
             'Per bin of the true La/Ra in sample periods and rule: the cases, those the rule '
             'gives the quasi-static equation, and those whose kept fit has Ra and CPhi within '
             '5 %, J within 10 % of the truth (at stage 3, before discovery).', '']
    lines += markdown_table(['true La/Ra', 'rule', 'cases', 'quasi-static', 'within the goals'],
                            summary_rows(rows)).splitlines()
    lines += ['', '## The cases where the rules differ', '',
              'Choices in the order of the table above (F full, Q quasi-static).', '']
    lines += markdown_table(['case', 'La/Ra / dt', 'fitted / dt', 'gate',
                             'LR of the current, of both / needed', 'current % full / quasi',
                             'full fit [%]', 'quasi-static fit [%]', 'choices'],
                            detail_rows(rows)).splitlines()
    write_report(lines, args.out)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
