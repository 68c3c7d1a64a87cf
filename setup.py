"""Setup for the dcmotor_id ament_python package (pip and colcon)."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'dcmotor_id'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'studies', 'studies.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.py')),
    ],
    python_requires='>=3.10',
    # py.typed: the package's type hints apply to its users (PEP 561).
    package_data={PACKAGE: ['py.typed']},
    install_requires=['numpy', 'scipy', 'numba>=0.68,<0.69', 'matplotlib', 'rosbags', 'mcap',
                      'control>=0.10,<0.11', 'dask[distributed]', 'pyarrow', 'threadpoolctl'],
    extras_require={'test': ['pytest', 'mypy'], 'mat73': ['h5py'],
                    'wpilog': ['robotpy-wpiutil']},
    zip_safe=True,
    maintainer='dcmotor_id developers',
    maintainer_email='dev@dcmotor-id.invalid',
    description='DC motor parameter identification: paper baseline, exact output error, ROS 2.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'dcmotor-id = dcmotor_id.cli.main:main',
            'identifier = dcmotor_id.nodes.identifier:main',
            'sim_motor = dcmotor_id.nodes.sim_motor:main',
            'replay = dcmotor_id.nodes.replay:main',
            'exciter = dcmotor_id.nodes.exciter:main',
        ],
    },
)
