"""The topic contract between the plant, controllers, the recorder and the analysis.

One source of truth for topic names, message types, data layouts and units. Names are
relative (resolved in the node's namespace) except ``/clock``. This module is pure: the QoS
profiles that go with it are in :mod:`fohssv_sim.ros.qos`.

Why ``std_msgs/Float64MultiArray`` with the time in ``data[0]``: the standard stamped
messages carry at most 3 doubles (``Vector3Stamped``) or give them another meaning
(``QuaternionStamped``, ``PoseStamped`` would store theta as a quaternion and lose bits).
A float64 array carries the state exactly, and its first element is the simulation time
``t = n h`` exactly as the plant computed it, so a subscriber, a recording and the batch
runner all see the same double. Recordings additionally log every message at its simulation
time (nanoseconds) and ``/clock`` carries the same time for ``use_sim_time`` nodes.

Layouts (``layout.dim[0].label`` names the fields, so a bag is self-describing):

=====================  =====================================  ====================================
topic                  data                                   units
=====================  =====================================  ====================================
``state``              [t, z, w, theta, q]                    s, m, m/s, rad, rad/s
``planing_force``      [t, Fp]                                s, m^2/s^2 (normalised, eq. 10)
``command``            [t, delta_f, delta_c]                  s, rad, rad
``/clock``             rosgraph_msgs/Clock                    simulation time
=====================  =====================================  ====================================

``command.data[0]`` is the time of the state the command answers. In lockstep mode the plant
advances only on a command whose time equals the state it published; in real-time mode the
time is used for latency statistics and the latest command is held (zero-order hold).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ['Topic', 'STATE', 'PLANING_FORCE', 'COMMAND', 'CLOCK', 'TOPICS', 'decode',
           'ContractError']


class ContractError(ValueError):
    """A message does not fit the contract (wrong length, non-finite values)."""


@dataclass(frozen=True)
class Topic:
    """One topic of the contract."""

    name: str
    type: str                     # ROS 2 type name, e.g. 'std_msgs/msg/Float64MultiArray'
    fields: tuple[str, ...]       # names of data[i]
    units: tuple[str, ...]
    description: str
    qos: str                      # name of the profile in fohssv_sim.ros.qos

    @property
    def label(self) -> str:
        """The ``layout.dim[0].label`` value: the field names joined by commas."""
        return ','.join(self.fields)


FLOAT64_ARRAY = 'std_msgs/msg/Float64MultiArray'

STATE = Topic('state', FLOAT64_ARRAY, ('t', 'z', 'w', 'theta', 'q'),
              ('s', 'm', 'm/s', 'rad', 'rad/s'),
              'plant state at every published step: depth (down), vertical velocity of the '
              'nose (down), pitch (nose up), pitch rate', 'reliable_samples')
PLANING_FORCE = Topic('planing_force', FLOAT64_ARRAY, ('t', 'Fp'), ('s', 'm^2/s^2'),
                      'normalised planing force Fp (eq. 10, force / rho pi R^2, positive down) '
                      'at the same step as the state', 'reliable_samples')
COMMAND = Topic('command', FLOAT64_ARRAY, ('t', 'delta_f', 'delta_c'), ('s', 'rad', 'rad'),
                'fin and cavitator deflections; t = time of the state they answer',
                'reliable_commands')
CLOCK = Topic('/clock', 'rosgraph_msgs/msg/Clock', ('clock',), ('s',),
              'simulation time, published by the plant at every published step (realtime '
              'mode: every clock_period if set)', 'clock')

TOPICS = (STATE, PLANING_FORCE, COMMAND, CLOCK)


def decode(topic: Topic, data: Sequence[float]) -> tuple[float, ...]:
    """Check ``data`` against ``topic``'s layout and return it as a tuple of floats.

    Raises:
        ContractError: wrong length or a non-finite value (the message must be dropped).
    """
    if len(data) != len(topic.fields):
        raise ContractError(f'{topic.name}: expected {len(topic.fields)} values '
                            f'[{topic.label}], got {len(data)}')
    vals = tuple(float(v) for v in data)
    bad = [f'{f}={v}' for f, v in zip(topic.fields, vals) if not math.isfinite(v)]
    if bad:
        raise ContractError(f"{topic.name}: non-finite {', '.join(bad)}")
    return vals
