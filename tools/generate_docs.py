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


#: Block name -> (page, how the block is made from the sessions).
BLOCKS: dict[str, tuple[str, Callable[[Mapping[str, Session]], str]]] = {
    'readme': ('README.md', _readme_block),
    'first-identification': ('docs/getting_started.md',
                             lambda sessions: _identify_block(sessions, '.venv/bin/dcmotor-id',
                                                              True)),
    'stribeck-example': ('docs/closing_the_loop.md', _stribeck_block),
    'report-figure-numbers': ('docs/closing_the_loop.md', _figure_caption),
    'design-example': ('docs/control_design.md', _design_block),
    'design-refused': ('docs/control_design.md', _refused_block),
    'design-stribeck': ('docs/control_design.md', _stribeck_design_block),
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
            if before != text:
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
