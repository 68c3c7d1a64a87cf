"""Test configuration shared by every test module."""

import fcntl
import os
import tempfile

import pytest


def _claim_domain(first, count=100):
    """
    Return a ROS 2 domain id (``first`` .. ``first + count - 1``) no other test run holds.

    A run holds its domain by an exclusive lock on a file in the temporary directory, kept
    for the whole session (released by the kernel when the process ends, also on SIGKILL):
    two runs at once (several worktrees) never share a graph and answer each other's calls.
    """
    start = os.getpid() % count
    for step in range(count):
        domain = first + (start + step) % count
        path = os.path.join(tempfile.gettempdir(), f'dcmotor_id_ros_domain_{domain}.lock')
        stream = open(path, 'a')
        try:
            fcntl.flock(stream, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            stream.close()
            continue
        _HELD.append(stream)
        return domain
    return first + start  # every one taken: share, as before


_HELD = []
#: ROS 2 domain of this test run (0..232 are valid): node tests never see another run's graph.
ROS_DOMAIN_ID = _claim_domain(100)


@pytest.fixture(scope='session')
def ros_env():
    """
    Isolate this run's ROS 2 graph: its own ROS_DOMAIN_ID, discovery on localhost only.

    Returns the environment for subprocesses. Request it before ``rclpy.init``.
    """
    os.environ['ROS_DOMAIN_ID'] = str(ROS_DOMAIN_ID)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return dict(os.environ)
