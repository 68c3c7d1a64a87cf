"""What every command pays at start: the installed version looked up only for --version."""

import os
import subprocess
import sys

import pytest

from dcmotor_id.cli.main import main

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_building_the_parser_does_not_look_up_the_installed_version():
    # importlib.metadata and the search of the installed distributions cost about 25 ms of
    # CPU; every command paid them when the parser was built (``--version``'s text).
    code = ('import sys; from dcmotor_id.cli.main import build_parser; build_parser(); '
            "print('importlib.metadata' in sys.modules)")
    env = dict(os.environ, PYTHONPATH=ROOT)
    found = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                           text=True, check=True)
    assert found.stdout.strip() == 'False'


def test_version_is_printed_on_stdout_and_help_names_it(capsys):
    with pytest.raises(SystemExit) as stop:
        main(['--version'])
    assert stop.value.code == 0
    captured = capsys.readouterr()
    assert captured.out.startswith('dcmotor-id ') and captured.out.endswith('\n')
    assert not captured.err
    with pytest.raises(SystemExit):
        main(['--help'])
    assert "--version             show program's version number and exit" in \
        capsys.readouterr().out
