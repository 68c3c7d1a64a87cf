"""
Write the versions installed in this interpreter's environment as a pip constraints file.

`make upgrade-deps` runs it after upgrading the venv to the newest versions requirements.txt
allows; `make` installs with ``-c constraints.txt``, so a fresh install gets the versions the
tests passed on, not whatever is newest that day.

Only distributions installed by pip are written (``pip inspect``): the ROS wheels also unpack
egg-info directories of their ROS packages (``rclpy-7.1.5-py3.11.egg-info``), which are not on
the package index, and the project itself (an editable install) is left out.
"""

import datetime
import json
import subprocess
import sys

PROJECT = 'dcmotor-id'
# Left out as pip freeze leaves them out: the venv's own installers. A pin of the setuptools a
# Python 3.11 venv bundles (65.5) breaks numba.pycc on 3.12 (pkgutil.ImpImporter is gone).
BOOTSTRAP = ('pip', 'setuptools', 'wheel', 'distribute')


def pinned_lines(inspect_report: dict) -> list:
    """
    Return ``name==version`` for every pip-installed distribution but the project.

    Parameters
    ----------
    inspect_report : dict
        The JSON of ``python -m pip inspect``.

    Returns
    -------
    list of str
        Sorted case-insensitively by name.
    """
    lines = []
    for dist in inspect_report['installed']:
        name = dist['metadata']['name']
        canonical = name.lower().replace('_', '-').replace('.', '-')
        if dist.get('installer') != 'pip' or canonical == PROJECT or canonical in BOOTSTRAP:
            continue
        if dist['metadata_location'].endswith('.egg-info'):
            continue
        lines.append(f"{name}=={dist['metadata']['version']}")
    return sorted(lines, key=str.lower)


def main() -> int:
    """Print the constraints file for the running interpreter to stdout."""
    report = json.loads(subprocess.run(
        [sys.executable, '-m', 'pip', 'inspect', '--local'], check=True,
        capture_output=True, text=True).stdout)
    version = '.'.join(map(str, sys.version_info[:3]))
    print('# Versions the test suite passed on (make upgrade-deps regenerates this file from '
          'the venv;')
    print('# commit it only after `make test` passes). Upper bounds where an API is known to '
          'break are')
    print(f'# in requirements.txt and setup.py. Python {version}, '
          f'{datetime.date.today().isoformat()}.')
    for line in pinned_lines(report):
        print(line)
    return 0


if __name__ == '__main__':
    sys.exit(main())
