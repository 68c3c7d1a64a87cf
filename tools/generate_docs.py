"""
Regenerate the manual's command output and report figures from the current code.

``make docs-regenerate`` (or ``python tools/generate_docs.py``) runs the commands the manual
shows, in a scratch directory, and rewrites every block of a page that lies between
``<!-- generated: NAME -->`` and ``<!-- end -->`` with the commands and what they printed, and
the report figures in ``docs/_static/`` (reduced to 64 colours; each PNG records the numbers its
title shows in a text chunk, :data:`NUMBERS_KEY`). ``test/test_docs_generated.py`` runs the
same commands without the figures and fails when a page differs from what they print now, or
when a figure records other numbers than the current output: the manual never shows stale
output.

Numbers the prose quotes from a committed benchmark table (``bench/*_results.md``) are written
``<!-- from: SPEC -->number<!-- /from -->`` (:func:`quoted_value` reads SPEC): the generator
parses the table and fills them in, so a changed table makes the page stale too.  Output of
runs lasting minutes (the online alarms, the fleet's progress) is quoted from those runs'
committed results the same way.  A page differing only in the last printed digit of a decimal
number (a fit on another CPU) is not stale (:func:`same_numbers`).

``--check`` reports the stale pages without writing (exit 1 when one is stale).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from typing import Callable, Mapping, Sequence

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STATIC = os.path.join(ROOT, 'docs', '_static')
#: The PNG text chunk holding the numbers a figure's title shows (JSON).
NUMBERS_KEY = 'dcmotor_id numbers'
#: What the message of a stale page tells the reader to run.
REGENERATE = 'run `make docs-regenerate`'
BLOCK = re.compile(r'(<!-- generated: (?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- end -->)',
                   re.DOTALL)


@dataclass(frozen=True)
class Command:
    """A ``dcmotor-id`` command of a session: its arguments and those only the figures need."""

    key: str
    argv: tuple[str, ...]
    #: Arguments shown and run only when the figures are drawn (e.g. ``--report report/``).
    slow: tuple[str, ...] = ()
    #: Where the manual breaks the shown line (before these arguments).
    breaks: tuple[str, ...] = ()
    exit_code: int = 0

    def shown(self, prefix: str) -> list[str]:
        """Return the command as the manual shows it (continuation lines indented)."""
        lines = [prefix]
        for argument in self.argv + self.slow:
            if argument in self.breaks:
                lines[-1] += ' \\'
                lines.append('   ')
            lines[-1] += ' ' + (argument if re.fullmatch(r'[\w./:=,+-]+', argument)
                                else repr(argument))
        return lines


@dataclass
class Session:
    """Commands run in turn in one scratch directory; their output, by command key."""

    name: str
    commands: Sequence[Command]
    stdout: dict[str, str] = field(default_factory=dict)
    stderr: dict[str, str] = field(default_factory=dict)
    directory: str = ''

    def command(self, key: str) -> Command:
        """Return the command of ``key``."""
        return next(command for command in self.commands if command.key == key)

    def json(self, name: str) -> dict:
        """Return a JSON file the session wrote."""
        with open(os.path.join(self.directory, name), encoding='utf-8') as stream:
            return json.load(stream)


def run_session(session: Session, directory: str, figures: bool) -> Session:
    """Run the session's commands in ``directory`` (the slow arguments with ``figures``)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [ROOT] + [part for part in [os.environ.get('PYTHONPATH', '')] if part]))
    session.directory = directory
    for command in session.commands:
        argv = list(command.argv) + (list(command.slow) if figures else [])
        done = subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.main', *argv],
                              cwd=directory, env=env, capture_output=True, text=True,
                              timeout=600)
        if done.returncode != command.exit_code:
            raise RuntimeError(f'{session.name}: dcmotor-id {" ".join(argv)} ended with '
                               f'{done.returncode}, not {command.exit_code}:\n{done.stderr}')
        session.stdout[command.key] = done.stdout
        session.stderr[command.key] = done.stderr
    return session


SIMULATE_PRBS = Command('simulate', (
    'simulate', '--motor', 'paper2', '--excitation', 'prbs', '--amplitude', '24', '--duration',
    '10', '--sample-period', '1e-3', '--noise', '0.01', '--out', 'run.csv'),
    breaks=('--sample-period',))
SIMULATE_STRIBECK = Command('simulate', (
    'simulate', '--excitation', 'sine', '--duration', '8', '--sample-period', '1e-3', '--noise',
    '0.005', '--amplitude', '20', '--effect', 'stribeck:excess_Nm=0.5,velocity_rad_s=3',
    '--out', 'stribeck.csv'), breaks=('--amplitude',))

#: The sessions: the manual's examples, each run once for all the blocks that quote it.
SESSIONS = {
    'prbs': (
        SIMULATE_PRBS,
        Command('identify', ('identify', 'run.csv', '--json', 'result.json')),
        Command('design', ('design', 'result.json', '--sample-period', '1e-4', '--gear-ratio',
                           '10', '--json', 'design.json'),
                slow=('--report', 'report/', '--export', 'model/'), breaks=('--report',)),
        Command('refused', ('design', 'result.json', '--speed-bandwidth', '1'), exit_code=2),
    ),
    'stribeck': (
        SIMULATE_STRIBECK,
        Command('identify', ('identify', 'stribeck.csv', '--json', 'result.json'),
                slow=('--report', 'report/')),
        Command('design', ('design', 'result.json', '--json', 'design.json')),
    ),
}


def comment(text: str) -> list[str]:
    """Return printed text as the manual's comment lines (``# line``)."""
    return [f'# {line}'.rstrip() for line in text.rstrip('\n').split('\n')]


def parameter_table(stdout: str) -> list[str]:
    """Return the identify table's head and the six physical parameters."""
    lines = stdout.split('\n')
    start = next(n for n, line in enumerate(lines) if line.startswith('parameter '))
    return lines[start:start + 7]


def lines_from(stdout: str, first: str, skip: Sequence[str] = ()) -> list[str]:
    """Return the printed lines from the first one starting with ``first``, minus ``skip``."""
    lines = stdout.rstrip('\n').split('\n')
    start = next(n for n, line in enumerate(lines) if line.startswith(first))
    return [line for line in lines[start:] if not line.startswith(tuple(skip))]


def matching(stdout: str, *starts: str) -> list[str]:
    """Return the printed lines that start (after blanks) with one of ``starts``."""
    return [line.strip() for line in stdout.split('\n') if line.strip().startswith(starts)]


def code(lines: Sequence[str]) -> str:
    """Return an indented code block of ``lines`` (a blank line before and after)."""
    return '\n' + ''.join(f'    {line}\n' for line in lines) + '\n'


def _identify_block(sessions: Mapping[str, Session], prefix: str, elide: bool) -> str:
    prbs = sessions['prbs']
    shown = prbs.command('simulate').shown(prefix) + prbs.command('identify').shown(prefix)
    table = comment('\n'.join(parameter_table(prbs.stdout['identify'])))
    return code(shown + table + (['# ...'] if elide else []))


def _readme_block(sessions: Mapping[str, Session]) -> str:
    prbs = sessions['prbs']
    identify = Command('identify', prbs.command('identify').argv, slow=('--report', 'report/'))
    shown = prbs.command('simulate').shown('.venv/bin/dcmotor-id') + identify.shown(
        '.venv/bin/dcmotor-id')
    return code(shown + comment('\n'.join(parameter_table(prbs.stdout['identify']))))


def _design_block(sessions: Mapping[str, Session]) -> str:
    prbs = sessions['prbs']
    shown = prbs.command('identify').shown('dcmotor-id') + prbs.command('design').shown(
        'dcmotor-id')
    stderr = stderr_range(prbs.json('result.json'))
    printed = lines_from(prbs.stdout['design'], 'current PI')
    return code(shown + [f'# (run.csv of Getting started: standard errors {stderr})']
                + comment('\n'.join(printed)))


def _refused_block(sessions: Mapping[str, Session]) -> str:
    prbs = sessions['prbs']
    message = prbs.stderr['refused'].strip().split('\n')[-1]
    return code(prbs.command('refused').shown('dcmotor-id') + ['# exit code 2:']
                + comment('\n'.join(wrap(message, 92))))


def _stribeck_block(sessions: Mapping[str, Session]) -> str:
    stribeck = sessions['stribeck']
    shown = stribeck.command('simulate').shown('dcmotor-id') + stribeck.command(
        'identify').shown('dcmotor-id')
    printed = matching(stribeck.stdout['identify'], 'effect ', 'all records, held-out')
    return code(shown + comment('\n'.join('\n'.join(wrap(line, 92)) for line in printed)))


def _stribeck_design_block(sessions: Mapping[str, Session]) -> str:
    stribeck = sessions['stribeck']
    feedforward = stribeck.json('design.json')['feedforward']
    lines = [line for line in lines_from(stribeck.stdout['design'], 'feedforward')
             if not line.startswith('over the')]
    lines.insert(1, f"(design.json: kS_coulomb = {feedforward['kS_coulomb']:.5g} V, the "
                    'sliding friction alone)')
    return code(stribeck.command('design').shown('dcmotor-id')
                + comment('\n'.join('\n'.join(wrap(line, 92)) for line in lines)))


def _figure_caption(sessions: Mapping[str, Session]) -> str:
    numbers = figure_numbers(sessions['stribeck'].json('result.json'))
    text = ("The figure's title gives the held-out NRMSE of the base model "
            f"({numbers['before']}) and of the final one ({numbers['after']}).")
    return '\n' + '\n'.join(wrap(text, 96)).replace('\n  ', '\n') + '\n\n'


def sampled_current_figures(result: Mapping, sample_period_s: float = 1e-4) -> list[tuple]:
    """
    Return ``(f_s / f_c, widening %, sampling_correction)`` of the sampled current loop.

    For the identified motor of ``result`` at ``f_c = f_s/50`` and ``f_s/20``: how much wider
    than ``f_c`` the closed form's sampled loop is, and the factor the design scales it by
    (:func:`dcmotor_id.design.loops.sampled_current_pi`).
    """
    if ROOT not in sys.path:
        sys.path.insert(0, ROOT)
    from dcmotor_id.design.loops import (bandwidth_hz, current_pi, inner_loop,
                                         sampled_current_pi)
    from dcmotor_id.design.plant import motor_from_result
    motor = motor_from_result(dict(result))
    figures = []
    for ratio in (50, 20):
        f_c = 1.0 / (ratio * sample_period_s)
        inner = inner_loop(motor, current_pi(motor, f_c), None, sample_period_s)
        widening = 100.0 * (bandwidth_hz(inner[inner.output_labels.index('i'), 0]) / f_c - 1)
        figures.append((ratio, widening, sampled_current_pi(motor, f_c, sample_period_s)[1]))
    return figures


def _current_loop_block(sessions: Mapping[str, Session]) -> str:
    (low, low_wide, low_factor), (high, high_wide, high_factor) = sampled_current_figures(
        sessions['prbs'].json('result.json'))
    text = (
        '**Current loop** (`u` from `i_ref - i`): pole-zero cancellation of the armature pole, '
        '`Ti = La/Ra`, `Kp = 2 pi f_c La`, `Ki = Kp/Ti = 2 pi f_c Ra`. Without back-EMF the '
        'open loop is `2 pi f_c / s`: a first-order closed loop of bandwidth `f_c` and 90 deg '
        'phase margin (continuous design: exactly these gains, `closed_form` in the JSON). '
        "Sampled, the zero-order hold's half-sample delay makes the loop peak and widens its "
        f'bandwidth (on the motor of the example above: {low_wide:+.0f} % at `f_c = f_s/{low}`, '
        f'{high_wide:+.0f} % at `f_s/{high}`), so with `--sample-period` the closed form is '
        f'used at `f_c` times a factor (`sampling_correction`, {low_factor:.2f} and '
        f'{high_factor:.2f} there, found by brentq) that makes the sampled closed loop'
        "'s -3 dB bandwidth `f_c`; `Ti = La/Ra` is kept. The back-EMF (`CPhi w`, given as "
        '`back_emf_feedforward_v_per_rad_s` to add to `u`) is in the evaluated plant; the '
        'reported bandwidth and margins are those of the exact (sampled) loop.')
    kept = re.sub(r'`[^`]*`', lambda found: found.group(0).replace(' ', '\0'), text)
    lines = '\n'.join(wrap(kept, 96)).replace('\n  ', '\n').replace('\0', ' ')
    return '\n' + lines + '\n\n'


def bench_lines(name: str, pattern: str) -> list[str]:
    """Return group 1 of every line of a committed results file that ``pattern`` matches."""
    lines = [m.group(1) for m in re.finditer(pattern, read_bench(name), re.MULTILINE)]
    if not lines:
        raise RuntimeError(f'bench/{name}: no line matches {pattern!r}')
    return lines


def _online_alarms_block(sessions: Mapping[str, Session]) -> str:
    alarms = bench_lines('online_results.md', r'^- paper2, `[^`]*`: (.*)$')[:3]
    return code([
        'sim_motor --ros-args -p transport:=batch \\',
        "    -p schedule:='Ra:+25%:ramp:30:90;b:+50%:step:120;load_torque:+0.5:step:160'",
        'identifier --ros-args -p input:=batch -p record:=false',
        'ros2 topic echo /diagnostics    # identifier: condition; the first alarms of paper',
        '# motor 2 in bench/online_results.md (each change a run of its own, from 40 s):']
        + [f'# {line}' for line in alarms])


def _fleet_block(sessions: Mapping[str, Session]) -> str:
    progress = bench_lines('fleet_results.md', r'^- progress .*/ `(fleet .*)`$')[0]
    output = bench_lines('fleet_results.md', r'^- command output: `(.*)`$')[0]
    return code([
        'dcmotor-id fleet /data/bags --history /data/fleet_history --workers 2',
        '# (the fleet of bench/fleet_results.md, on two workers:)', f'# {progress}',
        *comment('\n'.join(wrap(output, 96))),
        'dcmotor-id fleet /data/bags --history /data/fleet_history     # tomorrow: only new bags',
        'dcmotor-id fleet-report /data/fleet_history --out fleet_report/'])


def _readme_emps_block(sessions: Mapping[str, Session]) -> str:
    """Return the README's EMPS table from bench/emps_score_results.md."""
    table = next(t for t in bench_tables(read_bench('emps_score_results.md'))
                 if 'product path' in t.heading)
    column = table.header.index('PULSES position RMSE [mm]')

    def rmse(part: str) -> str:
        row = next(row for row in table.rows if part in row[0])
        return f'{float(NUMBER.findall(row[column])[0]):.4g} mm'
    loop = next(row for row in table.rows if 'README' in row[0])
    slopes = NUMBER.findall(loop[table.header.index('effects')])[2:4]
    lines = ['| model trained on DATA_EMPS | effects | PULSES position RMSE |', '|---|---|---|',
             f'| `identify` as above (the loop) | viscous_asymmetry (b+ {float(slopes[0]):.0f} '
             f'/ b- {float(slopes[1]):.0f} N s/m), load_torque | **{rmse("README")}** |',
             f'| `identify --no-discover` | none | {rmse("--no-discover")} |',
             f'| baseline: published IDIM-LS | offset | {rmse("IDIM-LS")} |',
             '| baseline: plain output-error fit on the position (M, Fv, Fc, offset) | offset | '
             f'{rmse("output error on position")} |']
    return '\n' + '\n'.join(lines) + '\n\n'


#: The EMPS study's rows the manual shows: (label, the row of bench/emps_score_results.md).
EMPS_STUDY_ROWS = (
    ('published IDIM-LS parameters (M, Fv, Fc, offset)', 'published IDIM-LS (M, Fv, Fc, offset)'),
    ('4-parameter rigid model, output error on speed (`--criterion speed`)',
     '4-parameter rigid model, output error on speed'),
    ('4-parameter rigid model, output error on position',
     '4-parameter rigid model, output error on position'),
    ('discovery loop on speed (`identify --criterion speed`, {effects})',
     'discovery loop on speed'),
    ('**position output error + viscous_asymmetry** (Fv+ {b_pos:.0f}, Fv- {b_neg:.0f} N s/m)',
     'position output error + viscous_asymmetry'),
    ('position output error + viscous and Coulomb asymmetry',
     'position output error + viscous and coulomb asymmetry'),
    ('... + Stribeck friction', 'position output error + viscous_asymmetry + stribeck'),
    ('... + quadratic drag (Fv {Fv:g} N s/m)',
     'position output error + viscous_asymmetry + quadratic_drag'),
    ('... + force periodic in position, 58 mm (not reproduced on PULSES)',
     'position output error + viscous_asymmetry + force periodic in position (cogging, period '
     '58 mm)'),
    ('... + first-order lag of the force (fits {lag})',
     'position output error + viscous_asymmetry + first-order lag of the force'),
    ('diagnosis, not a score: viscous_asymmetry structure fitted on PULSES',
     'diagnosis, not a score: position output error + viscous_asymmetry fitted on PULSES'))


def _emps_study_block(sessions: Mapping[str, Session]) -> str:
    """Return the EMPS study's scores from bench/emps_score_results.md (The study)."""
    table = next(t for t in bench_tables(read_bench('emps_score_results.md'))
                 if 'The study' in t.heading)
    head = {name: table.header.index(name) for name in table.header}
    lines = ['| model (trained on DATA_EMPS) | PULSES position RMSE | DATA_EMPS |', '|---|---|---|']
    for label, wanted in EMPS_STUDY_ROWS:
        row = next(row for row in table.rows if row[0] == wanted or (
            wanted == 'discovery loop on speed' and row[0].startswith(wanted)))
        effects = row[head['effects']]
        fv = float(row[head['Fv [N s/m]']])
        delta = re.search(r'viscous_asymmetry delta_Nm_s ([-+.\de]+)', effects)
        lag = re.search(r'force lag ([-+.\de]+ ms)', effects)
        text = label.format(
            effects=re.sub(r'^.*\((identify, )?(.*)\)$', r'\2', row[0]), Fv=fv, lag=lag and lag.group(1),
            b_pos=fv + float(delta.group(1)) if delta else 0.0,
            b_neg=fv - float(delta.group(1)) if delta else 0.0)
        score = row[head['PULSES position RMSE [mm]']].strip('*')
        score = f'**{score} mm**' if text.startswith('**') else f'{score} mm'
        lines.append(f"| {text} | {score} | {row[head['DATA_EMPS position RMSE [mm]']]} mm |")
    return '\n' + '\n'.join(lines) + '\n\n'


def study_table(nth: int) -> str:
    """Return the ``nth`` table of bench/emps_study_results.md's study, as the file has it."""
    tables = [t for t in bench_tables(read_bench('emps_study_results.md'))
              if t.heading == 'The study']
    table = tables[nth - 1]
    lines = ['| ' + ' | '.join(table.header) + ' |', '|' + '---|' * len(table.header)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in table.rows]
    return '\n' + '\n'.join(lines) + '\n\n'


#: Block name -> (page, how the block is made from the sessions).
BLOCKS: dict[str, tuple[str, Callable[[Mapping[str, Session]], str]]] = {
    'readme': ('README.md', _readme_block),
    'first-identification': ('docs/getting_started.md',
                             lambda sessions: _identify_block(sessions, '.venv/bin/dcmotor-id',
                                                              True)),
    'stribeck-example': ('docs/closing_the_loop.md', _stribeck_block),
    'report-figure-numbers': ('docs/closing_the_loop.md', _figure_caption),
    'design-example': ('docs/control_design.md', _design_block),
    'current-loop': ('docs/control_design.md', _current_loop_block),
    'design-refused': ('docs/control_design.md', _refused_block),
    'design-stribeck': ('docs/control_design.md', _stribeck_design_block),
    # from the committed benchmark results (their live runs take minutes)
    'readme-emps': ('README.md', _readme_emps_block),
    'emps-study': ('docs/emps.md', _emps_study_block),
    'emps-idim': ('docs/emps.md', lambda sessions: study_table(1)),
    'emps-criteria': ('docs/emps.md', lambda sessions: study_table(2)),
    'emps-speed-loop': ('docs/emps.md', lambda sessions: study_table(3)),
    'online-alarms': ('docs/online.md', _online_alarms_block),
    'fleet-example': ('docs/fleet.md', _fleet_block),
}


def wrap(line: str, width: int) -> list[str]:
    """Break a long printed line at blanks (continuations indented by two)."""
    out: list[str] = []
    current = ''
    for word in line.split(' '):
        if current and len(current) + 1 + len(word) > width:
            out.append(current)
            current = '  ' + word
        else:
            current = f'{current} {word}' if current else word
    return out + [current]


def stderr_range(result: Mapping) -> str:
    """Return the range of the physical parameters' relative standard errors, in percent."""
    relative = [100 * abs(result['stderr'][name] / value)
                for name, value in result['parameters'].items()
                if name in ('Ra', 'La', 'CPhi', 'J', 'b', 'Mc') and value]
    return f'{min(relative):.2g} to {max(relative):.2g} %'


def figure_numbers(result: Mapping) -> dict[str, str]:
    """Return the numbers the report's fit figure shows in its title (held-out NRMSE)."""
    def text(errors: Mapping) -> str:
        return ', '.join(f'{channel} {errors[f"{channel}_nrmse_pct"]:.3g} %'
                         for channel in ('current', 'speed'))
    return {'before': text(result['error_before']), 'after': text(result['error_after'])}


# ----------------------------------------------------------------------------- bench numbers

#: A number of the prose quoted from a committed benchmark table: ``<!-- from: SPEC -->text
#: <!-- /from -->``, SPEC being ``key: value`` pairs joined by ``;`` (:func:`quoted_value`).
QUOTED = re.compile(r'<!-- from: (?P<spec>.*?) -->(?P<body>.*?)<!-- /from -->', re.DOTALL)
BENCH = os.path.join(ROOT, 'bench')
#: The pages whose quoted numbers are filled in (the README and the Markdown pages; the reST
#: pages have no HTML comments, and architecture.rst shows the syntax).
QUOTING_PAGES = ('README.md', 'docs/*.md', 'docs/benchmarks/index.md')
#: A number in a text (a sign only where it does not follow a digit: ``0.7-0.9`` is two).
NUMBER = re.compile(r'(?<![\d.])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|(?:\d+\.?\d*|\.\d+)')
#: Printed numbers that differ by at most this relative amount, or by one unit of their last
#: printed decimal, are taken as the same (a fit on another CPU may round the other way).
RELATIVE_TOLERANCE = 1e-3


@dataclass
class Table:
    """A markdown table of a benchmark's results: the heading above it, its header and rows."""

    heading: str
    header: list[str]
    rows: list[list[str]]


def bench_tables(text: str) -> list[Table]:
    """Return the markdown tables of a results file, each with the heading above it."""
    tables: list[Table] = []
    heading, inside = '', False
    for line in text.split('\n'):
        if line.startswith('#'):
            heading, inside = line.lstrip('#').strip(), False
        elif line.startswith('|') and not inside:
            tables.append(Table(heading, _cells(line), []))
            inside = True
        elif line.startswith('|') and not set(line) <= set('|-: '):
            tables[-1].rows.append(_cells(line))
        elif not line.startswith('|'):
            inside = False
    return tables


def _cells(line: str) -> list[str]:
    inner = line.strip()[1:-1] if line.strip().endswith('|') else line.strip()[1:]
    return [cell.strip() for cell in re.split(r'(?<!\\)\|', inner)]


def _spec(text: str) -> dict[str, str]:
    """Return the ``key: value`` pairs of a quoted number's SPEC."""
    pairs = [part.split(':', 1) for part in text.split(';') if part.strip()]
    if any(len(pair) != 2 for pair in pairs):
        raise RuntimeError(f'quoted number {text!r}: the spec is "key: value; key: value"')
    return {key.strip(): value.strip() for key, value in pairs}


def _one(found: list, what: str, spec: Mapping[str, str]) -> object:
    nth = int(spec.get('nth', '0'))
    if nth:
        if len(found) < nth:
            raise RuntimeError(f'{dict(spec)}: fewer than {nth} {what}')
        return found[nth - 1]
    if len(found) != 1:
        raise RuntimeError(f'{dict(spec)}: {len(found)} {what} (one expected; give nth: N)')
    return found[0]


def _selected(table: Table, spec: Mapping[str, str]) -> list[list[str]]:
    """Return the rows meeting the spec's ``row`` conditions (``COL = TEXT``, ``COL ~ PART``)."""
    rows = table.rows
    for condition in filter(None, (part.strip() for part in spec.get('row', '').split('&'))):
        column, operator, wanted = re.fullmatch(r'(.*?)\s*(!=|[=~])\s*(.*)',
                                                condition).groups()
        index = table.header.index(column)
        rows = [row for row in rows if {'=': row[index] == wanted, '!=': row[index] != wanted,
                                        '~': wanted in row[index]}[operator]]
    if not rows:
        raise RuntimeError(f'{dict(spec)}: no row of table {table.heading!r} matches')
    return rows


def _share(table: Table, row: list[str], spec: Mapping[str, str]) -> float:
    """Return the factor of a percentage cell's number with ``per``: that column's / 100."""
    if 'per' not in spec:
        return 1.0
    return float(NUMBER.findall(row[table.header.index(spec['per'])])[0]) / 100.0


def quoted_value(spec: Mapping[str, str], read: Callable[[str], str]) -> str:
    """
    Return the text of a number quoted from a benchmark's results file.

    ``bench``: the file under bench/; either ``match``: a regular expression whose group 1 (of
    its only match, or the ``nth``) is the text, or ``table``: a part of the heading above the
    table (``nth`` among several), ``row``: conditions joined by ``&`` (``COL = TEXT`` or
    ``COL != TEXT``, ``COL ~ PART``), ``column``: its header (several, joined by ``,``, for
    ``max`` and ``min``); ``nth: 1,2``: the rows of several such tables together; ``value``:
    ``cell`` (the default: the text of the one row; ``part: N`` its N-th number), or ``max``,
    ``min``, ``abs`` (the largest size), ``range`` (``min-max``) of the ``part``-th number
    (default the first) of the cells that have one, or their ``sum`` (with ``per: COLUMN``
    each a percentage of that column's number: counts from rates), written with ``format``
    (default ``g``); ``count``: the number of rows meeting the conditions (no ``column``).
    """
    text = read(spec['bench'])
    if 'match' in spec:
        return str(_one([m.group(1) for m in re.finditer(spec['match'], text)], 'matches',
                        spec))
    tables = [t for t in bench_tables(text) if spec['table'] in t.heading]
    if ',' in spec.get('nth', ''):  # several tables of the same layout: their rows together
        tables = [tables[int(n) - 1] for n in spec['nth'].split(',')]
        if any(t.header != tables[0].header for t in tables):
            raise RuntimeError(f'{dict(spec)}: the tables have different columns')
        tables = [Table(tables[0].heading, tables[0].header, sum((t.rows for t in tables), []))]
        spec = {key: value for key, value in spec.items() if key != 'nth'}
    table = _one(tables, 'tables', spec)
    assert isinstance(table, Table)
    rows = _selected(table, spec)
    if spec.get('value') == 'count':
        return str(len(rows))
    names = ([spec['column']] if spec['column'] in table.header
             else [name.strip() for name in spec['column'].split(',')])
    missing = [name for name in names if name not in table.header]
    if missing:
        raise RuntimeError(f'{dict(spec)}: no column {missing} in {table.header}')
    columns = [table.header.index(name) for name in names]
    how, part = spec.get('value', 'cell'), int(spec.get('part', '1')) - 1
    if how == 'cell':
        cell = str(_one([row[columns[0]] for row in rows], 'rows', spec))
        return NUMBER.findall(cell)[part] if 'part' in spec else cell
    numbers = [float(found[part]) * _share(table, row, spec) for row in rows
               for index in columns for found in [NUMBER.findall(row[index])]
               if len(found) > part]
    form = spec.get('format', 'g')
    if how == 'sum':
        return format(sum(numbers), form)
    low, high = format(min(numbers), form), format(max(numbers), form)
    size = format(max(abs(number) for number in numbers), form)
    return {'max': high, 'min': low, 'abs': size,
            'range': low if low == high else f'{low}-{high}'}[how]


def fill_quoted(text: str, read: Callable[[str], str]) -> str:
    """Return a page with every quoted number replaced by what its benchmark table says now."""
    return QUOTED.sub(lambda m: m.group(0).replace(
        f'-->{m.group("body")}<!--', f'-->{quoted_value(_spec(m.group("spec")), read)}<!--', 1),
        text)


def read_bench(name: str) -> str:
    """Return a committed results file of bench/."""
    with open(os.path.join(BENCH, name), encoding='utf-8') as stream:
        return stream.read()


def quoting_pages() -> list[str]:
    """Return the absolute paths of the pages whose quoted numbers are filled in."""
    import glob
    return sorted(path for pattern in QUOTING_PAGES
                  for path in glob.glob(os.path.join(ROOT, pattern)))


def _last_unit(text: str) -> float:
    """Return one unit of the last printed decimal of a number (0 for an integer)."""
    mantissa, _, exponent = text.lower().partition('e')
    if '.' not in mantissa or mantissa.endswith('.'):
        return 0.0
    return 10.0 ** (int(exponent or 0) - len(mantissa.split('.')[1]))


def same_numbers(before: str, after: str) -> bool:
    """
    Return whether two texts are the same but for the last digit of some decimal numbers.

    The text between numbers must be identical, and so must integers; two decimal numbers
    match within :data:`RELATIVE_TOLERANCE` of their size or one unit of their last printed
    decimal (``0.995`` and ``0.996``, not ``0.995`` and ``0.998``).
    """
    if before == after:
        return True
    old, new = NUMBER.split(before), NUMBER.split(after)
    if old != new:
        return False
    for one, other in zip(NUMBER.findall(before), NUMBER.findall(after)):
        if one == other:
            continue
        a, b = float(one), float(other)
        allowed = max(RELATIVE_TOLERANCE * max(abs(a), abs(b)), _last_unit(one),
                      _last_unit(other)) * (1.0 + 1e-9)
        if not (_last_unit(one) or _last_unit(other)) or abs(a - b) > allowed:
            return False
    return True


def regenerate_pages(sessions: Mapping[str, Session]) -> dict[str, tuple[str, str]]:
    """Return, per page with generated blocks, its text now and its text regenerated."""
    pages: dict[str, tuple[str, str]] = {}
    for name, (page, make) in BLOCKS.items():
        path = os.path.join(ROOT, page)
        if path not in pages:
            with open(path, encoding='utf-8') as stream:
                text = stream.read()
            pages[path] = (text, text)
        before, text = pages[path]
        found = [match for match in BLOCK.finditer(text) if match.group('name') == name]
        if len(found) != 1:
            raise RuntimeError(f'{page}: {len(found)} blocks named {name} (one expected)')
        match = found[0]
        text = text[:match.start('body')] + make(sessions) + text[match.end('body'):]
        pages[path] = (before, text)
    for path in quoting_pages():
        if path not in pages:
            with open(path, encoding='utf-8') as stream:
                text = stream.read()
            pages[path] = (text, text)
        pages[path] = (pages[path][0], fill_quoted(pages[path][1], read_bench))
    for path, (before, text) in pages.items():
        unknown = {match.group('name') for match in BLOCK.finditer(text)} - set(BLOCKS)
        if unknown:
            raise RuntimeError(f'{path}: generated blocks nobody makes: {sorted(unknown)}')
    return pages


def write_figures(stribeck: Session) -> list[str]:
    """Copy the Stribeck example's report figures into docs/_static (64 colours, numbers)."""
    from PIL import Image, PngImagePlugin
    numbers = json.dumps(figure_numbers(stribeck.json('result.json')), sort_keys=True)
    written = []
    for source, target in (('fit.png', 'report_fit.png'),
                           ('transients.png', 'report_transients.png')):
        image = Image.open(os.path.join(stribeck.directory, 'report', source))
        info = PngImagePlugin.PngInfo()
        info.add_text(NUMBERS_KEY, numbers)
        path = os.path.join(STATIC, target)
        image.convert('RGB').quantize(64).save(path, optimize=True, pnginfo=info)
        written.append(path)
    return written


def recorded_numbers(path: str) -> dict[str, str] | None:
    """Return the numbers a figure of docs/_static records (None when it records none)."""
    from PIL import Image
    with Image.open(path) as image:
        text = getattr(image, 'text', {}).get(NUMBERS_KEY)
    return None if text is None else json.loads(text)


def run_all(directory: str, figures: bool) -> dict[str, Session]:
    """Run every session in its own subdirectory of ``directory``."""
    sessions = {}
    for name, commands in SESSIONS.items():
        place = os.path.join(directory, name)
        os.makedirs(place, exist_ok=True)
        sessions[name] = run_session(Session(name, commands), place, figures)
    return sessions


def main(argv: Sequence[str] | None = None) -> int:
    """Regenerate the pages and figures (``--check``: only report what is stale)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    parser.add_argument('--check', action='store_true',
                        help='write nothing; exit 1 when a page is stale')
    args = parser.parse_args(argv)
    directory = tempfile.mkdtemp(prefix='dcmotor_id_docs_')
    try:
        sessions = run_all(directory, figures=not args.check)
        stale = []
        for path, (before, text) in regenerate_pages(sessions).items():
            if not same_numbers(before, text) or (before != text and not args.check):
                stale.append(os.path.relpath(path, ROOT))
                if not args.check:
                    with open(path, 'w', encoding='utf-8') as stream:
                        stream.write(text)
        if not args.check:
            for path in write_figures(sessions['stribeck']):
                print(f'figure: {os.path.relpath(path, ROOT)}')
        print(('stale: ' if args.check else 'rewritten: ') + (', '.join(stale) or 'none'))
        return 1 if args.check and stale else 0
    finally:
        shutil.rmtree(directory, ignore_errors=True)


if __name__ == '__main__':
    sys.exit(main())
