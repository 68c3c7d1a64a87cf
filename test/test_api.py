"""The public surface: names from the package face, doctested examples, no import leak."""

import doctest
import subprocess
import sys

import pytest

import dcmotor_id
from dcmotor_id.simulation import compiled

#: What the command line, the package face and ``identify`` on a CSV must not import (the
#: optimiser, the JIT, plotting, ROS, Dask, the bag, Parquet, HDF5 and control libraries:
#: hundreds of milliseconds of a process that does not need them; issues 11 and 29).
HEAVY = ('scipy', 'numba', 'matplotlib', 'rclpy', 'dask', 'rosbags', 'pyarrow', 'h5py',
         'control', 'pandas')

LEAK_CHECK = """
import sys
HEAVY = {heavy!r}
{statement}
print('loaded:' + ','.join(sorted(m for m in HEAVY if m in sys.modules)))
"""


def loaded_after(statement: str) -> str:
    code = LEAK_CHECK.format(statement=statement, heavy=HEAVY)
    completed = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                               timeout=300)
    assert completed.returncode == 0, completed.stderr
    lines = [line for line in completed.stdout.splitlines() if line.startswith('loaded:')]
    assert lines, completed.stdout
    return lines[-1][len('loaded:'):]


def test_every_public_name_resolves():
    for name in dcmotor_id.__all__:
        assert getattr(dcmotor_id, name) is not None, name
    with pytest.raises(AttributeError):
        dcmotor_id.no_such_name  # noqa: B018


@pytest.mark.parametrize('module', ['dcmotor_id', 'dcmotor_id.core.model',
                                    'dcmotor_id.identification.effects',
                                    'dcmotor_id.design.control'])
def test_doctested_examples(module):
    imported = __import__(module, fromlist=['_'])
    failures, attempted = doctest.testmod(imported, optionflags=doctest.ELLIPSIS)
    assert attempted > 0, f'{module} has no example'
    assert failures == 0


def test_command_line_imports_neither_scipy_nor_numba():
    assert loaded_after('import dcmotor_id.cli.main') == ''


def test_package_face_is_light():
    assert loaded_after('import dcmotor_id; dcmotor_id.Record') == ''


@pytest.mark.skipif(compiled.built_path() is None,
                    reason='the ahead-of-time module is built by the set-up step (make)')
def test_identify_path_loads_neither_scipy_nor_numba(tmp_path):
    """A whole ``dcmotor-id identify`` of a CSV, discovery included, without scipy or numba."""
    csv_path, out = tmp_path / 'r.csv', tmp_path / 'r.json'
    subprocess.run([sys.executable, '-m', 'dcmotor_id.cli.main', 'simulate', '--motor', 'paper2',
                    '--excitation', 'paper', '--duration', '4', '--sample-period', '1e-3',
                    '--noise', '0.01', '--out', str(csv_path)], check=True, timeout=300)
    statement = ('from dcmotor_id.cli.main import main\n'
                 f'assert main(["identify", {str(csv_path)!r}, "--json", {str(out)!r}, '
                 '"--quiet"]) == 0')
    assert loaded_after(statement) == ''


def test_design_controller_is_public_and_takes_a_result_object():
    """Issue 31: the design from the package face, for an IdentificationResult as for its JSON."""
    import numpy as np
    true = dcmotor_id.PAPER_MOTORS['paper2']
    t = np.arange(0.0, 3.0, 1e-3)
    voltage = 60.0 * np.sign(np.sin(2 * np.pi * 1.5 * t)) + 20.0 * np.sin(2 * np.pi * 7 * t)
    current, speed = dcmotor_id.simulate_motor(true, voltage, 1e-3)
    result = dcmotor_id.identify([dcmotor_id.Record(t, current, voltage, speed)],
                                 discover=False)
    made = dcmotor_id.design_controller(result, sample_period_s=1e-4)
    assert made == dcmotor_id.design_controller(result.as_dict(), sample_period_s=1e-4)
    assert made['feedforward']['kA'] == pytest.approx(true.Ra * true.J / true.CPhi)
    assert made['current_loop']['kp'] > 0
    # the notebook way: the result designs its own controller, the same dict
    assert result.design(sample_period_s=1e-4) == made
    assert result.design(speed_bandwidth_hz=10.0)['nominal']['speed']['bandwidth_hz'] == \
        pytest.approx(10.0, rel=1e-6)


def test_a_result_designs_only_through_the_package_face_binding():
    from dcmotor_id.core import lazy
    assert lazy.bound('design_controller') is dcmotor_id.design_controller
    with pytest.raises(LookupError, match='nothing is bound'):
        lazy.bound('no such function')


IN_MEMORY_IDENTIFY = """
import sys
import numpy as np
import dcmotor_id
t = np.arange(0.0, 2.0, 1e-3)
voltage = 60.0 * np.sign(np.sin(2 * np.pi * 1.5 * t))
current, speed = dcmotor_id.simulate_motor(dcmotor_id.PAPER_MOTORS['paper2'], voltage, 1e-3)
from dcmotor_id.identification.identify import identify, prepare_records
identify(prepare_records([dcmotor_id.Record(t, current, voltage, speed)]))
print('loaded:' + ','.join(sorted(m for m in {modules!r} if m in sys.modules)))
"""


def test_identify_in_memory_loads_no_file_handling():
    """Issue 29 (speed): records in memory: no path checks, JSON files or temporary files."""
    modules = ('tempfile', 'shutil', 'dcmotor_id.formats.paths', 'dcmotor_id.formats.json_file',
               'dcmotor_id.formats.csv')
    completed = subprocess.run([sys.executable, '-c', IN_MEMORY_IDENTIFY.format(
        modules=modules)], capture_output=True, text=True, timeout=300)
    assert completed.returncode == 0, completed.stderr
    assert completed.stdout.strip().splitlines()[-1] == 'loaded:'
