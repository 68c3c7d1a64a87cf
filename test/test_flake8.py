"""ament_flake8 over the package, tests and benchmarks (the ROS 2 lint of Python code)."""

import os

from ament_flake8.main import main_with_errors
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    paths = [os.path.join(ROOT, name) for name in ('dcmotor_id', 'studies', 'test', 'bench',
                                                   'setup.py')
             if os.path.exists(os.path.join(ROOT, name))]
    rc, errors = main_with_errors(argv=['--config', os.path.join(ROOT, 'test', 'flake8.ini')]
                                  + paths)
    assert rc == 0, f'Found {len(errors)} code style errors / warnings:\n' + '\n'.join(errors)
