"""
package.xml: every dependency key resolves for ROS 2 Jazzy on Ubuntu noble.

Against test/rosdep_snapshot.yaml (ros/rosdistro's rules for these keys, its commit recorded;
tools/rosdep_snapshot.py regenerates it) and the keys the repository ships in
rosdep/dcmotor_id.yaml. A key in neither makes ``rosdep install --from-paths`` fail.
"""

import os
import re
import sys

import pytest
import yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'tools'))

from rosdep_snapshot import package_keys  # noqa: E402, I100

with open(os.path.join(ROOT, 'test', 'rosdep_snapshot.yaml')) as _file:
    SNAPSHOT = yaml.safe_load(_file)
with open(os.path.join(ROOT, 'rosdep', 'dcmotor_id.yaml')) as _file:
    SHIPPED = yaml.safe_load(_file)
KEYS = package_keys(os.path.join(ROOT, 'package.xml'))


def noble_rule(rule):
    """Return what a rosdep rule installs on Ubuntu noble, or None when it has nothing."""
    ubuntu = (rule or {}).get('ubuntu')
    if isinstance(ubuntu, dict) and 'pip' not in ubuntu:
        ubuntu = ubuntu.get('noble', ubuntu.get('*'))
    if isinstance(ubuntu, dict):
        return ubuntu.get('pip', {}).get('packages') or None
    return ubuntu or None


def test_the_snapshot_records_its_rosdistro_commit():
    assert re.fullmatch(r'[0-9a-f]{40}', SNAPSHOT['rosdistro_commit'])


@pytest.mark.parametrize('key', KEYS)
def test_every_key_resolves_on_noble(key):
    if key in SNAPSHOT['jazzy_packages']:
        return
    if key in SNAPSHOT['rosdep_rules']:
        assert noble_rule(SNAPSHOT['rosdep_rules'][key]), f'{key}: no rule for noble'
        return
    assert key in SNAPSHOT['absent'], (
        f'{key} is not in test/rosdep_snapshot.yaml: regenerate it (tools/rosdep_snapshot.py)')
    assert key in SHIPPED, (f'{key}: no rosdep rule in ros/rosdistro nor in '
                            'rosdep/dcmotor_id.yaml')
    assert noble_rule(SHIPPED[key]), f'{key}: rosdep/dcmotor_id.yaml has no rule for ubuntu'


def test_shipped_keys_do_not_shadow_rosdistro():
    """A key rosdistro has is used from there, not redefined (rosdep would see two rules)."""
    known = set(SNAPSHOT['rosdep_rules']) | set(SNAPSHOT['jazzy_packages'])
    assert not known & set(SHIPPED)
    assert set(SHIPPED) <= set(KEYS), 'a shipped key package.xml does not use'


def test_every_install_requirement_has_a_key():
    """Each install_requires of setup.py is in package.xml under some key's pip or apt name."""
    with open(os.path.join(ROOT, 'setup.py')) as file:
        setup = file.read()
    requirements = re.search(r'install_requires=\[(.*?)\]', setup, re.S).group(1)
    names = {re.split(r'[<>=\[]', item)[0] for item in re.findall(r"'([^']+)'", requirements)}
    provided = set()
    for key in KEYS:
        rule = SNAPSHOT['rosdep_rules'].get(key) or SHIPPED.get(key)
        for name in noble_rule(rule) or []:
            provided.add(re.split(r'[<>=]', name)[0].removeprefix('python3-'))
    # dask[distributed]: the pip package distributed requires dask.
    provided |= {'dask'} if 'distributed' in provided else set()
    assert names - provided == set(), names - provided
