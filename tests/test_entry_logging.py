"""The executables' entry (ros/entry.py) hands rclpy's logger each message's caller from the
frames' code instead of ``inspect.getframeinfo``: the caller rclpy finds, and what it passes
on (function, file, line), are those its own lookup finds, and the ``once`` filter, keyed by
them, still works. No ROS graph: rclpy's logging in this process."""

from __future__ import annotations

import inspect

import pytest
from rclpy.impl import rcutils_logger
from rclpy.logging import get_logger

from fohssv_sim.ros import entry


@pytest.fixture
def cheap(monkeypatch):
    """The entry's lookup installed for the test (rclpy's own restored after it)."""
    monkeypatch.setattr(rcutils_logger, 'inspect', inspect)
    entry.cheap_log_callers()
    assert rcutils_logger.inspect is not inspect


def _here() -> rcutils_logger.CallerId:
    """The CallerId rclpy makes for a message logged here (it walks back from its own
    frames to this one)."""
    return rcutils_logger.CallerId()


def test_the_caller_is_the_one_rclpy_finds(cheap):
    found = _here()
    rcutils_logger.inspect = inspect               # rclpy's own lookup
    assert found == _here()
    assert (found.function_name, found.file_path) == ('_here', __file__)


def test_the_once_filter_still_logs_once_per_call_site(cheap):
    logger = get_logger('fohssv_entry_test')
    logged = [logger.info('first', once=True) for _ in range(3)]
    assert logged == [True, False, False]
    assert logger.info('another call site', once=True) is True
