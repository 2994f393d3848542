"""The viewer's Foxglove side: the plant's typed views served live over the Foxglove WebSocket
protocol with the Foxglove SDK for Python (``foxglove-sdk``). Pure: no rclpy (the viewer node,
:mod:`.viewer_node`, feeds it plain numbers), so it is tested alone with a WebSocket client.

What is served (topic names: the plant's topics resolved in the viewer's namespace, so that
the layout ``docs/foxglove/fohssv_layout.json`` draws a live run and a recorded bag with the
same topics and message paths):

* ``/vehicle_marker``: ``foxglove.SceneUpdate`` (protobuf), entities ``body`` and ``cavity``,
  one ellipsoid each (``spheres[0]``) with the pose, size and colour of the plant's markers
  id 0 and id 1, in fohssv_world;
* ``/tf``: ``foxglove.FrameTransform`` (protobuf), fohssv_world -> fohssv_body: the pose (the
  nose at -z, pitched);
* ``/pose``: ``foxglove.PoseInFrame`` (protobuf), the pose view (``pose.position.z`` = -z,
  ``pose.orientation``);
* ``/twist``: ``fohssv.TwistStamped`` (JSON), the twist view with geometry_msgs/TwistStamped's
  fields;
* ``/planing_wrench``: ``fohssv.WrenchStamped`` (JSON), the wrench view with
  geometry_msgs/WrenchStamped's fields;
* ``/state``: ``fohssv.State`` (JSON), ``t, z, w, theta, q`` and ``data`` = [t, z, w, theta,
  q] (as the state topic's data);
* ``/planing_force``: ``fohssv.PlaningForce`` (JSON), ``t, Fp`` and ``data`` = [t, Fp].

All of one view carry its stamp (log time and timestamps: the plant's t rounded to the
nanosecond, as ``header.stamp``; ``t`` = stamp / 1e9). The state and the force are the views'
numbers with the view's signs undone: z = -pose.position.z, w = -twist.linear.z, q =
-twist.angular.y, Fp = -wrench.force.z (exact negations) and theta = -2 atan2(qy, qw) (to
rounding). The JSON channels carry JSON Schemas (units in the descriptions); the Foxglove
schemas are the SDK's (protobuf, schema advertised as a FileDescriptorSet).

Clients connect to the gate (:mod:`.foxglove_gate`), which accepts both names of the
protocol (``foxglove.websocket.v1``, ``foxglove.sdk.v1``), the allowed origins only and at
most ``max_clients`` connections, and relays each to the SDK's server on a loopback port of
its own. The server advertises the ``time`` capability and broadcasts the stamp of
each view sent, so Foxglove's clock is simulation time. A reset of the plant (a stamp earlier
than the last one sent) starts a new session: the panels clear instead of drawing a line
back to t = 0.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import foxglove
from foxglove.channels import FrameTransformChannel, PoseInFrameChannel, SceneUpdateChannel
from foxglove.messages import (
    Color,
    FrameTransform,
    Pose,
    PoseInFrame,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)
from foxglove.websocket import Capability, ChannelView, Client

from .foxglove_gate import Gate

__all__ = ['Marker', 'View', 'ViewAssembler', 'LiveServer', 'TOPICS', 'ENTITY_IDS',
           'JSON_SCHEMAS', 'scene_update', 'frame_transform', 'pose_in_frame',
           'state_message', 'force_message', 'twist_message', 'wrench_message']

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

#: Role -> default topic name of each served channel (the viewer node passes the names
#: resolved in its namespace; ``tf`` is not namespaced).
TOPICS: dict[str, str] = {
    'scene': '/vehicle_marker', 'tf': '/tf', 'pose': '/pose', 'twist': '/twist',
    'wrench': '/planing_wrench', 'state': '/state', 'force': '/planing_force'}

#: The plant's marker ids (contract.MARKER) -> the scene entity ids.
ENTITY_IDS: dict[int, str] = {0: 'body', 1: 'cavity'}

_PARTS = ('pose', 'twist', 'wrench', *(f'marker{i}' for i in ENTITY_IDS))


@dataclass(frozen=True)
class Marker:
    """One marker of ``vehicle_marker`` (an ellipsoid): its numbers."""

    ident: int
    frame_id: str
    position: Vec3
    orientation: Quat
    scale: Vec3
    color: Quat          # r, g, b, a


@dataclass(frozen=True)
class View:
    """One complete view of the plant at ``stamp`` (ns): the numbers of pose, twist,
    planing_wrench and the markers (id order), as the plant published them."""

    stamp: int
    world_frame: str
    body_frame: str
    position: Vec3
    orientation: Quat
    linear: Vec3
    angular: Vec3
    force: Vec3
    torque: Vec3
    markers: tuple[Marker, ...]

    @property
    def t(self) -> float:
        """Simulation time (s): the stamp."""
        return self.stamp / 1e9

    def state(self) -> tuple[float, float, float, float, float]:
        """[t, z, w, theta, q] with the views' signs undone (theta to rounding)."""
        _, oy, _, ow = self.orientation
        return (self.t, -self.position[2], -self.linear[2], -2.0 * math.atan2(oy, ow),
                -self.angular[1])

    def planing_force(self) -> tuple[float, float]:
        """[t, Fp]: Fp = -force.z."""
        return self.t, -self.force[2]


class ViewAssembler:
    """Collects the parts of each view as they arrive on their topics (keyed by stamp) and
    gives the newest complete view once (:meth:`take`): the viewer's decimation keeps the
    newest view at each tick and drops the rest. At most ``keep`` incomplete views are held
    (a part lost on the way leaves one incomplete for good)."""

    def __init__(self, keep: int = 8) -> None:
        self._keep = keep
        self._partial: dict[int, dict[str, Any]] = {}
        self._latest: View | None = None
        self._fresh = False
        self.complete = 0        # complete views assembled
        self.taken = 0           # views given by take()

    def add_pose(self, stamp: int, frame_id: str, position: Vec3, orientation: Quat) -> None:
        self._add(stamp, 'pose', (frame_id, position, orientation))

    def add_twist(self, stamp: int, frame_id: str, linear: Vec3, angular: Vec3) -> None:
        self._add(stamp, 'twist', (frame_id, linear, angular))

    def add_wrench(self, stamp: int, frame_id: str, force: Vec3, torque: Vec3) -> None:
        self._add(stamp, 'wrench', (frame_id, force, torque))

    def add_marker(self, stamp: int, marker: Marker) -> None:
        """A marker of another id than the plant's (0 and 1) is ignored."""
        if marker.ident in ENTITY_IDS:
            self._add(stamp, f'marker{marker.ident}', marker)

    def _add(self, stamp: int, part: str, value: Any) -> None:
        parts = self._partial.get(stamp)
        if parts is None:
            if len(self._partial) >= self._keep:
                del self._partial[next(iter(self._partial))]       # the oldest
            parts = self._partial[stamp] = {}
        parts[part] = value
        if len(parts) == len(_PARTS):
            del self._partial[stamp]
            self._latest = _view(stamp, parts)
            self._fresh = True
            self.complete += 1

    def take(self) -> View | None:
        """The newest complete view if it was not taken yet, else None."""
        if not self._fresh:
            return None
        self._fresh = False
        self.taken += 1
        return self._latest


def _view(stamp: int, parts: Mapping[str, Any]) -> View:
    world, position, orientation = parts['pose']
    body, linear, angular = parts['twist']
    _, force, torque = parts['wrench']
    return View(stamp, world, body, position, orientation, linear, angular, force, torque,
                tuple(parts[f'marker{i}'] for i in ENTITY_IDS))


# -- the messages ----------------------------------------------------------------------------
def _timestamp(stamp: int) -> Timestamp:
    sec, nsec = divmod(stamp, 1_000_000_000)
    return Timestamp(sec, nsec)


def _vector(v: Vec3) -> Vector3:
    return Vector3(x=v[0], y=v[1], z=v[2])


def _quaternion(q: Quat) -> Quaternion:
    return Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])


def scene_update(view: View) -> SceneUpdate:
    """The markers as a ``foxglove.SceneUpdate``: one entity per marker (``body``,
    ``cavity``), each one ellipsoid (a ``SpherePrimitive`` sized by the marker's scale)."""
    stamp = _timestamp(view.stamp)
    return SceneUpdate(entities=[SceneEntity(
        timestamp=stamp, frame_id=m.frame_id, id=ENTITY_IDS[m.ident],
        spheres=[SpherePrimitive(
            pose=Pose(position=_vector(m.position), orientation=_quaternion(m.orientation)),
            size=_vector(m.scale), color=Color(r=m.color[0], g=m.color[1], b=m.color[2],
                                               a=m.color[3]))])
        for m in view.markers])


def frame_transform(view: View) -> FrameTransform:
    """world -> body: the body frame at the nose, pitched (the pose)."""
    return FrameTransform(timestamp=_timestamp(view.stamp), parent_frame_id=view.world_frame,
                          child_frame_id=view.body_frame, translation=_vector(view.position),
                          rotation=_quaternion(view.orientation))


def pose_in_frame(view: View) -> PoseInFrame:
    """The pose view as a ``foxglove.PoseInFrame`` (paths ``pose.position.z`` as in the
    bag's PoseStamped)."""
    return PoseInFrame(timestamp=_timestamp(view.stamp), frame_id=view.world_frame,
                       pose=Pose(position=_vector(view.position),
                                 orientation=_quaternion(view.orientation)))


def _header(view: View, frame_id: str) -> dict[str, Any]:
    sec, nanosec = divmod(view.stamp, 1_000_000_000)
    return {'stamp': {'sec': sec, 'nanosec': nanosec}, 'frame_id': frame_id}


def _xyz(v: Vec3) -> dict[str, float]:
    return {'x': v[0], 'y': v[1], 'z': v[2]}


def twist_message(view: View) -> dict[str, Any]:
    """The twist view as JSON with geometry_msgs/TwistStamped's fields."""
    return {'header': _header(view, view.body_frame),
            'twist': {'linear': _xyz(view.linear), 'angular': _xyz(view.angular)}}


def wrench_message(view: View) -> dict[str, Any]:
    """The wrench view as JSON with geometry_msgs/WrenchStamped's fields."""
    return {'header': _header(view, view.body_frame),
            'wrench': {'force': _xyz(view.force), 'torque': _xyz(view.torque)}}


def state_message(view: View) -> dict[str, Any]:
    """``{t, z, w, theta, q, data: [t, z, w, theta, q]}`` (``data`` as the state topic's)."""
    state = view.state()
    return {**dict(zip(('t', 'z', 'w', 'theta', 'q'), state)), 'data': list(state)}


def force_message(view: View) -> dict[str, Any]:
    """``{t, Fp, data: [t, Fp]}``."""
    t, fp = view.planing_force()
    return {'t': t, 'Fp': fp, 'data': [t, fp]}


# -- JSON schemas -----------------------------------------------------------------------------
def _number(text: str) -> dict[str, str]:
    return {'type': 'number', 'description': text}


def _vector_schema(unit: str) -> dict[str, Any]:
    return {'type': 'object', 'properties': {k: _number(f'{k} ({unit})') for k in 'xyz'}}


_HEADER = {'type': 'object', 'properties': {
    'stamp': {'type': 'object', 'properties': {'sec': {'type': 'integer'},
                                               'nanosec': {'type': 'integer'}}},
    'frame_id': {'type': 'string'}}}
_DATA = {'type': 'array', 'items': {'type': 'number'}}

#: Role -> JSON Schema of the JSON channels.
JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    'twist': {'title': 'fohssv.TwistStamped', 'type': 'object',
              'description': 'the twist view in fohssv_body: linear.x = V, linear.z = -w, '
                             'angular.y = -q',
              'properties': {'header': _HEADER, 'twist': {'type': 'object', 'properties': {
                  'linear': _vector_schema('m/s'), 'angular': _vector_schema('rad/s')}}}},
    'wrench': {'title': 'fohssv.WrenchStamped', 'type': 'object',
               'description': 'the planing force view in fohssv_body: force.z = -Fp '
                              '(normalised: force / rho pi R^2, m^2/s^2, not N)',
               'properties': {'header': _HEADER, 'wrench': {'type': 'object', 'properties': {
                   'force': _vector_schema('m^2/s^2'), 'torque': _vector_schema('-')}}}},
    'state': {'title': 'fohssv.State', 'type': 'object',
              'description': 'the plant state at the view (model signs: z, w down, theta, q '
                             'nose up)',
              'properties': {'t': _number('simulation time (s)'),
                             'z': _number('depth, down (m)'),
                             'w': _number('vertical velocity of the nose, down (m/s)'),
                             'theta': _number('pitch, nose up (rad)'),
                             'q': _number('pitch rate (rad/s)'),
                             'data': {**_DATA, 'description': '[t, z, w, theta, q]'}}},
    'force': {'title': 'fohssv.PlaningForce', 'type': 'object',
              'description': 'the normalised planing force Fp (eq. 10, positive down)',
              'properties': {'t': _number('simulation time (s)'),
                             'Fp': _number('planing force / rho pi R^2 (m^2/s^2)'),
                             'data': {**_DATA, 'description': '[t, Fp]'}}},
}

_JSON_MESSAGES = {'twist': twist_message, 'wrench': wrench_message, 'state': state_message,
                  'force': force_message}


class _Subscriptions:
    """The server listener: counts the clients' subscriptions (the SDK calls it from its own
    threads)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.count = 0

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self.count += 1

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self.count -= 1


class LiveServer:
    """A Foxglove WebSocket server (the SDK's) with the viewer's channels; :meth:`send` a
    :class:`View` to every subscribed client.

    Args:
        host, port: where the gate binds (port 0: a free port; see :attr:`port`).
        topics: role -> topic name (default :data:`TOPICS`).
        name: the server name clients show.
        max_clients, allowed_origins, on_refused: the gate's (:class:`.foxglove_gate.Gate`).

    Raises:
        OSError: the server cannot bind (address in use, unknown host), with the SDK's reason.
    """

    def __init__(self, host: str, port: int, topics: Mapping[str, str] | None = None,
                 name: str = 'fohssv', *, max_clients: int = 16,
                 allowed_origins: Sequence[str] = (),
                 on_refused: Callable[[str], None] | None = None) -> None:
        self.topics = {**TOPICS, **(topics or {})}
        self._context = foxglove.Context()
        ctx = self._context
        self._subscriptions = _Subscriptions()
        try:
            self._server = foxglove.start_server(
                name=name, host='127.0.0.1', port=0, capabilities=[Capability.Time],
                context=ctx, server_listener=self._subscriptions)
        except RuntimeError as exc:
            raise OSError(f'cannot serve Foxglove on 127.0.0.1: {exc}') from None
        try:
            self._gate = Gate(host, port, self._server.port, max_clients=max_clients,
                              allowed_origins=allowed_origins, on_refused=on_refused)
        except OSError:
            self._server.stop()
            raise
        t = self.topics
        self._scene = SceneUpdateChannel(t['scene'], context=ctx)
        self._tf = FrameTransformChannel(t['tf'], context=ctx)
        self._pose = PoseInFrameChannel(t['pose'], context=ctx)
        self._json = {role: foxglove.Channel(t[role], schema=schema, context=ctx)
                      for role, schema in JSON_SCHEMAS.items()}
        self._last: int | None = None
        self.sent = 0
        self.sessions = 1

    @property
    def port(self) -> int:
        """The port clients connect to (the gate's)."""
        return self._gate.port

    @property
    def subscriptions(self) -> int:
        """The clients' subscriptions now (one per client and channel)."""
        return self._subscriptions.count

    def send(self, view: View) -> None:
        """Log ``view`` on every channel at its stamp and broadcast the stamp as the time."""
        if self._last is not None and view.stamp < self._last:
            self._server.clear_session()       # a reset: clients start over
            self.sessions += 1
        self._last = view.stamp
        log_time = view.stamp
        self._scene.log(scene_update(view), log_time=log_time)
        self._tf.log(frame_transform(view), log_time=log_time)
        self._pose.log(pose_in_frame(view), log_time=log_time)
        for role, channel in self._json.items():
            channel.log(_JSON_MESSAGES[role](view), log_time=log_time)
        self._server.broadcast_time(log_time)
        self.sent += 1

    def stop(self) -> None:
        """Close the channels and the server (clients are disconnected)."""
        for channel in (self._scene, self._tf, self._pose, *self._json.values()):
            channel.close()
        self._gate.stop()
        self._server.stop()
