"""
Command-line conventions: --version, ``--json -`` alone on stdout, schema versions, progress.

Issue 31: ``dcmotor-id --version``; ``identify X.csv --json - | python -m json.tool`` works
(the table and everything else on stderr) for every subcommand with ``--json``; a
``schema_version`` in every JSON, each layout documented as a JSON Schema (docs/schema/) and
checked here against real output; progress on stderr that is not a terminal as a line every
few seconds, none with ``--quiet``.
"""

import io
import json
import os
import re
import subprocess
import sys

import pytest
from schema_check import errors, load_schema, validate

from dcmotor_id.cli.main import main
from dcmotor_id.cli.terminal import terminal_progress
from dcmotor_id.core import progress as progress_module
from dcmotor_id.formats.json_file import SCHEMA_VERSION

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope='module')
def csv_and_result(tmp_path_factory):
    """Simulate a record (2 s at 1 kHz, 1 % noise) and identify it into a --json FILE."""
    directory = tmp_path_factory.mktemp('conventions')
    csv, result = str(directory / 'run.csv'), str(directory / 'result.json')
    assert main(['simulate', '--motor', 'paper2', '--excitation', 'prbs', '--amplitude', '24',
                 '--duration', '2', '--sample-period', '1e-3', '--noise', '0.01',
                 '--out', csv]) == 0
    assert main(['identify', csv, '--no-discover', '--json', result]) == 0
    return csv, result


def _stdout_json(capsys, argv):
    capsys.readouterr()
    assert main(argv) == 0
    captured = capsys.readouterr()
    return json.loads(captured.out), captured.err


def test_version_is_the_package_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(['--version'])
    assert stop.value.code == 0
    with open(os.path.join(ROOT, 'package.xml'), encoding='utf-8') as file:
        version = re.search(r'<version>(.*)</version>', file.read()).group(1)
    assert capsys.readouterr().out.strip() == f'dcmotor-id {version}'


def test_identify_json_dash_is_alone_on_stdout(capsys, csv_and_result):
    document, err = _stdout_json(capsys, ['identify', csv_and_result[0], '--no-discover',
                                          '--json', '-'])
    assert document['schema_version'] == SCHEMA_VERSION
    assert 'parameter' in err and 'Ra' in err  # the table went to stderr
    assert not os.path.exists('-')
    validate(document, 'result')


def test_identify_json_dash_pipes_into_json_tool(csv_and_result):
    command = [sys.executable, '-m', 'dcmotor_id.cli.main', 'identify', csv_and_result[0],
               '--no-discover', '--json', '-']
    identify = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert identify.returncode == 0, identify.stderr
    tool = subprocess.run([sys.executable, '-m', 'json.tool'], input=identify.stdout,
                          capture_output=True, text=True, timeout=60)
    assert tool.returncode == 0, tool.stderr
    assert 'Ra' in identify.stderr


def test_json_file_carries_the_schema_version(csv_and_result):
    with open(csv_and_result[1], encoding='utf-8') as file:
        document = json.load(file)
    assert document['schema_version'] == SCHEMA_VERSION
    validate(document, 'result')


def test_validate_design_plan_json_dash(capsys, csv_and_result, tmp_path):
    csv, result = csv_and_result
    for argv, schema in ((['validate', result, csv], 'validation'),
                         (['design', result], 'design'),
                         (['plan', '--duration', '2'], 'plan')):
        document, err = _stdout_json(capsys, argv + ['--json', '-'])
        assert document['schema_version'] == SCHEMA_VERSION, argv
        assert err.strip(), f'{argv}: the text went nowhere'
        validate(document, schema)
        path = str(tmp_path / f'{schema}.json')
        assert main(argv + ['--json', path]) == 0
        with open(path, encoding='utf-8') as file:
            assert json.load(file)['schema_version'] == SCHEMA_VERSION


def test_the_schemas_catch_a_broken_document(csv_and_result):
    """The check cannot pass on anything: a missing key or a wrong type fails it."""
    with open(csv_and_result[1], encoding='utf-8') as file:
        document = json.load(file)
    schema = load_schema('result')
    assert errors(document, schema) == []
    assert errors({key: v for key, v in document.items() if key != 'stderr'}, schema)
    assert errors(dict(document, n_samples='many'), schema)
    assert errors(dict(document, schema_version=SCHEMA_VERSION + 1), schema)


class _Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def _lines_over(monkeypatch, seconds, stream, quiet=False):
    clock = _Clock()
    monkeypatch.setattr(progress_module.time, 'monotonic', clock)
    progress = terminal_progress(None, quiet=quiet, stream=stream)
    progress.set_stage('base fit')
    while clock.now < seconds:
        clock.now += 0.1
        progress.update()
    progress.close()
    return stream.getvalue()


def test_progress_in_a_log_is_a_line_every_few_seconds(monkeypatch):
    text = _lines_over(monkeypatch, 30.0, io.StringIO())
    lines = text.splitlines()
    # 2 s of silence, then one line each LOG_INTERVAL_S (5 s): about 6 in 30 s.
    assert 4 <= len(lines) <= 8, text
    assert '\r' not in text and all('base fit' in line for line in lines)


def test_progress_quiet_writes_nothing(monkeypatch):
    assert _lines_over(monkeypatch, 30.0, io.StringIO(), quiet=True) == ''


def test_progress_on_a_terminal_redraws_in_place(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    text = _lines_over(monkeypatch, 5.0, Terminal())
    assert text.count('\r') > 5 and '\n' not in text.rstrip('\n')


def test_progress_in_a_log_new_stages_wait_for_the_interval(monkeypatch):
    clock = _Clock()
    monkeypatch.setattr(progress_module.time, 'monotonic', clock)
    stream = io.StringIO()
    progress = terminal_progress(None, stream=stream)
    while clock.now < 30.0:
        clock.now += 0.1
        progress.set_stage(f'candidate {int(clock.now * 10)}')
    assert 4 <= len(stream.getvalue().splitlines()) <= 8, stream.getvalue()
