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

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = ['Topic', 'STATE', 'PLANING_FORCE', 'COMMAND', 'CLOCK', 'TOPICS', 'decode',
           'ContractError', 'POSE', 'TWIST', 'WRENCH', 'MARKER', 'VIEW_TOPICS',
           'VIEW_WORLD_FRAME', 'VIEW_BODY_FRAME', 'RUN_END', 'run_end_text', 'parse_run_end',
           'find_topic']


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
              'mode: every clock_period if set) while someone subscribes', 'clock')

TOPICS = (STATE, PLANING_FORCE, COMMAND, CLOCK)

# -- views for people ------------------------------------------------------------------------
# Typed messages that viewers (Foxglove, RViz, PlotJuggler) draw and name without knowing the
# contract: published every ``view_period`` of simulated time (decimated; ``view_period`` 0 =
# off), never the control interface. Frames (no tf is published; REP 103 axes, z up):
#
# * ``fohssv_world``: x along the direction of travel (horizontal), y to port, z up, origin at
#   depth 0. It travels with the vehicle at V (the model has no horizontal position), so the
#   pose's x and y are 0.
# * ``fohssv_body``: at the nose (cavitator, the model's reference point), x along the body
#   axis forward, y to port, z up in the body.
#
# The model's z, w, Fp are positive down and theta, q nose up: on these z-up axes the views
# carry -z, -w, -Fp, and the nose-up pitch theta is a rotation of -theta about y (all exact
# negations; theta = -2 atan2(qy, qw) to rounding). ``header.stamp`` = round(t * 1e9) ns.
VIEW_WORLD_FRAME = 'fohssv_world'
VIEW_BODY_FRAME = 'fohssv_body'
POSE = Topic('pose', 'geometry_msgs/msg/PoseStamped',
             ('header.stamp', 'pose.position.z', 'pose.orientation'), ('s', 'm', '-'),
             'view: the nose in fohssv_world: position.z = -z (up), orientation = pitch theta '
             '(nose up) as the quaternion (0, -sin(theta/2), 0, cos(theta/2))', 'views')
TWIST = Topic('twist', 'geometry_msgs/msg/TwistStamped',
              ('header.stamp', 'twist.linear.x', 'twist.linear.z', 'twist.angular.y'),
              ('s', 'm/s', 'm/s', 'rad/s'),
              'view: body velocity in fohssv_body: linear.x = V (forward speed), linear.z = -w, '
              'angular.y = -q', 'views')
WRENCH = Topic('planing_wrench', 'geometry_msgs/msg/WrenchStamped',
               ('header.stamp', 'wrench.force.z'), ('s', 'm^2/s^2'),
               'view: the planing force in fohssv_body: force.z = -Fp, normalised like Fp '
               '(force / rho pi R^2, m^2/s^2, not N); torque 0', 'views')
MARKER = Topic('vehicle_marker', 'visualization_msgs/msg/Marker',
               ('header.stamp', 'id', 'pose', 'scale'), ('s', '-', 'm', 'm'),
               'view: id 0 the body (ellipsoid L x 2R, pitched), id 1 the cavity (ellipsoid of '
               'length 2 Rn (1.92/sigma - 3) and radius Rn sqrt(0.82 (1 + sigma)/sigma), eqs. '
               '12-14, behind the nose along the travel) in fohssv_world', 'views')

#: The typed views (not the control contract): see above.
VIEW_TOPICS = (POSE, TWIST, WRENCH, MARKER)


def find_topic(name: str, topics: Sequence[Topic] = TOPICS) -> Topic | None:
    """The topic of ``topics`` whose name is the last part of ``name`` (``/vehicle1/state``
    -> :data:`STATE`: contract topics are found in any namespace), or None."""
    base = name.rstrip('/').rsplit('/', 1)[-1]
    return next((t for t in topics if t.name.lstrip('/') == base), None)


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


# -- end of run ------------------------------------------------------------------------------
# Published once by whatever produced a run's messages (the plant when its run ends, the player
# after a replay), reliable and transient-local: a recorder compares what it wrote with what
# was published, drains what is still in flight, and reports anything lost. Not a sample topic
# (not in TOPICS): a std_msgs/String holding one JSON object.
RUN_END = Topic('run_end', 'std_msgs/msg/String', ('data',), ('-',),
                "end of run, once: JSON {source, reason, exit_code, t, published: {topic: "
                "messages}} (published = every message the source sent on each topic whose "
                "delivery is complete: reliable, deeper than 1; the plant adds the commands it "
                "received)", 'run_end')


def run_end_text(source: str, reason: str, exit_code: int, t: float,
                 published: Mapping[str, int]) -> str:
    """The JSON of a :data:`RUN_END` message (``published``: resolved topic name -> count)."""
    return json.dumps({'source': source, 'reason': reason, 'exit_code': int(exit_code),
                       't': float(t), 'published': {str(k): int(v) for k, v in
                                                    published.items()}})


def parse_run_end(text: str) -> dict:
    """Check and decode a :data:`RUN_END` message's JSON.

    Raises:
        ContractError: not a JSON object with a ``published`` map of topic names to counts >= 0.
    """
    try:
        info = json.loads(text)
    except ValueError as exc:
        raise ContractError(f'run_end: not JSON ({exc})') from None
    published = info.get('published') if isinstance(info, dict) else None
    if not isinstance(published, dict) or not all(
            isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) and v >= 0
            for k, v in published.items()):
        raise ContractError('run_end: expected a JSON object with "published": {topic: count '
                            f'>= 0}}, got {text[:200]!r}')
    return info
