"""
Where the command line's results go: ``--json FILE``, or ``--json -`` on stdout alone.

Every JSON the command line writes carries ``schema_version``
(:data:`dcmotor_id.formats.json_file.SCHEMA_VERSION`); the schemas are
``docs/schema/*.schema.json``. With ``--json -`` the JSON is the only thing on stdout:
:func:`json_on_stdout` sends everything else the command prints (the table, notes, report
paths) to stderr, so that ``dcmotor-id identify X.csv --json - | python -m json.tool`` works.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from typing import Any, Iterator, Mapping

from dcmotor_id.formats.json_file import STDOUT, write_result_json

__all__ = ['emit_json', 'json_on_stdout', 'package_version', 'STDOUT', 'VersionAction']


def package_version() -> str:
    """Return the installed version of dcmotor_id (``dcmotor-id --version``)."""
    # Imported here: importlib.metadata and the search of the installed distributions cost
    # about 25 ms of CPU, which every command paid when the parser was built.
    import importlib.metadata

    try:
        return importlib.metadata.version('dcmotor_id')
    except importlib.metadata.PackageNotFoundError:
        return 'unknown (not installed: run it from an install, e.g. `pip install -e .`)'


class VersionAction(argparse.Action):
    """``--version``: print the program's name and installed version, then exit."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS,
                 **options: Any) -> None:
        options.setdefault('default', argparse.SUPPRESS)
        options.setdefault('help', "show program's version number and exit")
        super().__init__(option_strings, dest=dest, nargs=0, **options)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        """Print the version (looked up now, not when the parser is built) and exit."""
        print(f'{parser.prog} {package_version()}')
        parser.exit()


@contextlib.contextmanager
def json_on_stdout(args: argparse.Namespace) -> Iterator[None]:
    """
    With ``--json -``, keep stdout for the JSON: whatever else is printed goes to stderr.

    The real stdout is kept in ``args.json_stream`` for :func:`emit_json`.
    """
    if getattr(args, 'json', None) != STDOUT:
        yield
        return
    args.json_stream = sys.stdout
    with contextlib.redirect_stdout(sys.stderr):
        yield


def emit_json(args: argparse.Namespace, result: Mapping[str, Any]) -> None:
    """Write ``result`` (with its schema version) to ``--json``: a file, or stdout for ``-``."""
    write_result_json(args.json, result, getattr(args, 'json_stream', None))
