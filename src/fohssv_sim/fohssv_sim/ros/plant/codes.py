"""The plant's exit codes (``docs/ros.md`` lists them), the hosted law's parameter prefix and
the error a sample that could not be published raises. Re-exported by
:mod:`fohssv_sim.ros.plant_node`."""

from __future__ import annotations

__all__ = ['EXIT_OK', 'EXIT_DIVERGED', 'EXIT_BAD_PARAMETERS', 'EXIT_TIMEOUT', 'EXIT_NO_PEERS',
           'EXIT_SECOND_PLANT', 'EXIT_COMMAND_LAG', 'EXIT_SECOND_CONTROLLER',
           'EXIT_PUBLISH_FAILED', 'EXIT_LAW_HUNG', 'EXIT_NOT_REAL_TIME',
           'CONTROLLER_PREFIX', 'PublishFailed']

EXIT_OK, EXIT_DIVERGED, EXIT_BAD_PARAMETERS, EXIT_TIMEOUT, EXIT_NO_PEERS = 0, 1, 2, 3, 4
#: Another publisher of ``state`` on the plant's domain and namespace (a second plant).
EXIT_SECOND_PLANT = 5
#: Realtime: an external controller's commands lagged beyond ``max_command_lag``.
EXIT_COMMAND_LAG = 6
#: A hosted controller and another publisher of ``command`` (two controllers would mix).
EXIT_SECOND_CONTROLLER = 7
#: A sample DDS refused to take for a second (retried every millisecond).
EXIT_PUBLISH_FAILED = 9
#: A hosted law's call that did not return (for ``LAW_TIMEOUT``) ended by SIGINT/SIGTERM.
EXIT_LAW_HUNG = 10
#: Realtime: more than ``max_deadline_miss_rate`` of the deadlines missed (when set).
EXIT_NOT_REAL_TIME = 11
#: The hosted controller's parameters are declared on the plant under this prefix.
CONTROLLER_PREFIX = 'controller.'


class PublishFailed(Exception):
    """A sample that could not be published (after retries); ends the run with exit 9."""
