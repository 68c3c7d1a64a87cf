"""ament_pep257 over the package, tests and benchmarks (docstring conventions of ROS 2)."""

import os

from ament_pep257.main import main
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    paths = [os.path.join(ROOT, name) for name in ('dcmotor_id', 'studies', 'test', 'bench',
                                                   'setup.py')
             if os.path.exists(os.path.join(ROOT, name))]
    assert main(argv=paths) == 0, 'Found docstring style errors (see the output above)'
