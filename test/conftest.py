"""Test configuration shared by every test module."""

import os

import pytest

#: ROS 2 domain of this test run (0..232 are valid): node tests never see another run's graph.
ROS_DOMAIN_ID = 100 + os.getpid() % 100


@pytest.fixture(scope='session')
def ros_env():
    """
    Isolate this run's ROS 2 graph: its own ROS_DOMAIN_ID, discovery on localhost only.

    Returns the environment for subprocesses. Request it before ``rclpy.init``.
    """
    os.environ['ROS_DOMAIN_ID'] = str(ROS_DOMAIN_ID)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    return dict(os.environ)
