"""The terminal's status lines live with the command line; the ground floor only reports."""

import ast
import io
import pathlib

import dcmotor_id
from dcmotor_id.cli.terminal import FleetProgressBar, StatusLine, terminal_progress
from dcmotor_id.core.progress import Progress

CORE = pathlib.Path(dcmotor_id.__file__).parent / 'core'


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_status_line_redraws_on_a_terminal_and_writes_lines_in_a_log():
    terminal = _Terminal()
    line = StatusLine(terminal, interval_s=0.0)
    line.show('long text')
    line.show('short')
    line.clear()
    assert terminal.getvalue() == '\rlong text\rshort    \r     \r'
    log = io.StringIO()
    line = StatusLine(log, interval_s=0.0)
    line.show('a')
    line.show('a')
    line.show('b', final=True)
    assert log.getvalue() == 'a\nb\n'


def test_fleet_bar_counts_bags_windows_and_failures():
    log = io.StringIO()
    bar = FleetProgressBar(log, interval_s=3600.0, width=4)
    bar.update(1, 2, 3, 4, 0, planning=True)  # the first write is due at once
    bar.update(2, 2, 4, 4, 1)  # not due: the interval has not passed
    bar.update(2, 2, 4, 4, 1, final=True)
    first, last = log.getvalue().splitlines()
    assert first.startswith('fleet [##..] bags 1/2  windows 3/4+  failures 0')
    assert last.startswith('fleet [####] bags 2/2  windows 4/4  failures 1')


def test_identify_progress_draws_in_place_on_a_terminal_only():
    terminal = _Terminal()
    progress = Progress(stream=terminal, delay_s=0.0, interval_s=0.0)
    assert progress.enabled
    progress.set_stage('base fit')
    progress.set_stage('done')
    progress.close()
    drawn = terminal.getvalue()
    assert drawn.startswith('\rdcmotor-id: ') and 'base fit' in drawn
    assert drawn.endswith(' \r') and '\n' not in drawn
    assert terminal_progress(None, quiet=True).line is None


def test_the_ground_floor_parses_no_command_line():
    for path in sorted(CORE.glob('*.py')):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                names = [alias.name for alias in node.names] + [getattr(node, 'module', '')]
                assert 'argparse' not in names, f'{path.name} imports argparse'
