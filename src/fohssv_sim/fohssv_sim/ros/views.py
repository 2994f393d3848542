"""Typed views of the plant for people and their viewers (Foxglove, RViz, PlotJuggler).

Every ``view_period`` of simulated time (default 0.01 s: every 100th sample at the default
control period; 0 = off) the plant also publishes, besides the ``Float64MultiArray`` contract
that stays the control interface:

* ``pose`` (``geometry_msgs/PoseStamped``, frame ``fohssv_world``): the nose at depth z and
  pitch theta;
* ``twist`` (``geometry_msgs/TwistStamped``, frame ``fohssv_body``): V, w and q;
* ``planing_wrench`` (``geometry_msgs/WrenchStamped``, frame ``fohssv_body``): Fp;
* ``vehicle_marker`` (``visualization_msgs/Marker``, frame ``fohssv_world``): two markers,
  id 0 the body and id 1 the cavity, as ellipsoids.

Frames, signs and units: :mod:`fohssv_sim.contract` (z up, so -z, -w, -Fp, pitch as a
rotation of -theta about y). Each message is serialized once, by rclpy's own serializer, and
only its stamp and numbers are written into the bytes when a view is due (offsets found by
probing, checked by a round trip: :class:`_Serialized`), so a view costs five raw publishes
instead of five conversions of message objects (the markers' were most of the 342-440 us a
view took in one sample). The five messages then go out one per sample, each with the due
sample's stamp and numbers, so no sample carries more than one of them and the plant's
per-sample path pays one attribute test otherwise. Measured: ``profile:=1``,
``publish_views`` (mean per view, worst per view) and ``bench/bench_ros.py``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from rclpy.serialization import deserialize_message
from visualization_msgs.msg import Marker

from ..contract import MARKER, POSE, TWIST, VIEW_BODY_FRAME, VIEW_WORLD_FRAME, WRENCH
from ..params import ModelParameters
from .qos import profile
from .wire import WireError, serialized

__all__ = ['ViewPublisher', 'cavity_size']


def cavity_size(p: ModelParameters) -> tuple[float, float]:
    """Length and largest radius of the cavity (m), eqs. 12-14: 2 Rn (1.92/sigma - 3) and
    Rn sqrt(0.82 (1 + sigma) / sigma) (the radius at the cavity's middle, where K1 = 0)."""
    sigma, rn = p.cavitation_number, p.cavitator_radius
    return 2.0 * rn * (1.92 / sigma - 3.0), rn * math.sqrt(0.82 * (1.0 + sigma) / sigma)


def _marker(ident: int, scale: tuple[float, float, float],
            rgba: tuple[float, float, float, float]) -> Marker:
    m = Marker()
    m.header.frame_id = VIEW_WORLD_FRAME
    m.ns = 'fohssv'
    m.id = ident
    m.type = Marker.SPHERE          # scaled per axis: an ellipsoid
    m.action = Marker.ADD
    m.scale.x, m.scale.y, m.scale.z = scale
    m.color.r, m.color.g, m.color.b, m.color.a = rgba
    m.pose.orientation.w = 1.0
    return m


class _Serialized:
    """One view message serialized once (rclpy's own serializer, so the bytes are what
    ``publish(msg)`` sends) whose stamp and chosen doubles are written in place.

    ``fields`` are attribute paths of doubles (``'pose.position.z'``); their offsets in the
    CDR are found by serializing the message with a distinct probe value in each and the
    stamp, and checked by a round trip through ``deserialize_message``.
    """

    def __init__(self, msg: Any, fields: Sequence[str]) -> None:
        self.type = type(msg)
        probes = [1e-300 * (3 + i) for i in range(len(fields))]
        kept = [_get(msg, f) for f in fields]
        for f, v in zip(fields, probes):
            _set(msg, f, v)
        stamp = msg.header.stamp
        stamp.sec, stamp.nanosec = 0x1A2B3C4D, 0x0F1E2D3C
        raw = serialized(msg)      # padding zeroed: a bag is a function of the run
        self._stamp = _offset(raw, struct.pack('<iI', stamp.sec, stamp.nanosec), 'stamp')
        self._at = [_offset(raw, struct.pack('<d', v), f) for f, v in zip(fields, probes)]
        self._buf = raw
        self.write(0, 0, kept)
        back = deserialize_message(bytes(raw), self.type)
        if [_get(back, f) for f in fields] != kept or back.header.stamp.sec != 0:
            raise WireError(f'{self.type.__name__}: the fields are not where they were found')
        for f, v in zip(fields, kept):
            _set(msg, f, v)

    def write(self, sec: int, nanosec: int, values: Sequence[float]) -> None:
        buf = self._buf
        struct.pack_into('<iI', buf, self._stamp, sec, nanosec)
        for at, v in zip(self._at, values):
            struct.pack_into('<d', buf, at, v)

    def payload(self) -> bytes:
        return bytes(self._buf)


def _get(msg: Any, path: str) -> float:
    for name in path.split('.'):
        msg = getattr(msg, name)
    return msg


def _set(msg: Any, path: str, value: float) -> None:
    *parents, last = path.split('.')
    for name in parents:
        msg = getattr(msg, name)
    setattr(msg, last, value)


def _offset(raw: bytearray, pattern: bytes, what: str) -> int:
    at = raw.find(pattern)
    if at < 0 or raw.find(pattern, at + 1) >= 0:
        raise WireError(f'{what}: not found exactly once in the serialized message')
    return at


class ViewPublisher:
    """The view publishers of ``node`` and their messages, serialized once.

    :meth:`publish` writes the numbers of a due view into the five serialized messages (pose,
    twist, wrench, the two markers) and, with ``spread`` (the default when views are at
    least five samples apart), publishes only the first: :meth:`publish_next`, called at the
    following samples, publishes the others one per sample, so no sample carries more than
    one view message. Every message carries the due sample's stamp and numbers, so what a
    viewer or a bag receives is the same as if all went out at once. :meth:`flush` publishes
    what is still pending (before ``run_end`` counts them).
    """

    #: Messages per view (pose, twist, wrench, body marker, cavity marker).
    MESSAGES = 5

    def __init__(self, node: Any, params: ModelParameters, spread: bool = True) -> None:
        self.pose_pub = node.create_publisher(PoseStamped, POSE.name, profile(POSE))
        self.twist_pub = node.create_publisher(TwistStamped, TWIST.name, profile(TWIST))
        self.wrench_pub = node.create_publisher(WrenchStamped, WRENCH.name, profile(WRENCH))
        self.marker_pub = node.create_publisher(Marker, MARKER.name, profile(MARKER))
        pose = PoseStamped()
        pose.header.frame_id = VIEW_WORLD_FRAME
        pose.pose.orientation.w = 1.0
        twist = TwistStamped()
        twist.header.frame_id = VIEW_BODY_FRAME
        twist.twist.linear.x = float(params.speed)
        wrench = WrenchStamped()
        wrench.header.frame_id = VIEW_BODY_FRAME
        self.half_length = 0.5 * params.length
        diameter = 2.0 * params.body_radius
        body = _marker(0, (params.length, diameter, diameter), (0.55, 0.57, 0.6, 1.0))
        length, radius = cavity_size(params)
        cavity = _marker(1, (length, 2.0 * radius, 2.0 * radius), (0.3, 0.65, 1.0, 0.25))
        cavity.pose.position.x = -0.5 * length
        self._pose = _Serialized(pose, ('pose.position.z', 'pose.orientation.y',
                                        'pose.orientation.w'))
        self._twist = _Serialized(twist, ('twist.linear.z', 'twist.angular.y'))
        self._wrench = _Serialized(wrench, ('wrench.force.z',))
        self._body = _Serialized(body, ('pose.position.x', 'pose.position.z',
                                        'pose.orientation.y', 'pose.orientation.w'))
        self._cavity = _Serialized(cavity, ('pose.position.z',))
        self._queue = ((self.pose_pub, self._pose), (self.twist_pub, self._twist),
                       (self.wrench_pub, self._wrench), (self.marker_pub, self._body),
                       (self.marker_pub, self._cavity))
        self.spread = spread
        self.pending = 0          # messages of the last view still to publish
        self.published = 0        # views (all five messages written; flush() sends the rest)

    @property
    def publishers(self) -> tuple:
        return self.pose_pub, self.twist_pub, self.wrench_pub, self.marker_pub

    def publish(self, sample: Sequence[float], fp: float) -> None:
        """The views of ``sample`` = [t, z, w, theta, q] and planing force ``fp``: all five
        messages written, the first (or, without ``spread``, all) published."""
        self.flush()
        t, z, w, theta, q = sample[0], sample[1], sample[2], sample[3], sample[4]
        sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
        up = -z
        qy, qw = -math.sin(0.5 * theta), math.cos(0.5 * theta)
        self._pose.write(sec, nanosec, (up, qy, qw))
        self._twist.write(sec, nanosec, (-w, -q))
        self._wrench.write(sec, nanosec, (-fp,))
        self._body.write(sec, nanosec, (-self.half_length * math.cos(theta),
                                        up - self.half_length * math.sin(theta), qy, qw))
        self._cavity.write(sec, nanosec, (up,))
        self.published += 1
        self.pending = self.MESSAGES
        if self.spread:
            self.publish_next()
        else:
            self.flush()

    def publish_next(self) -> None:
        """Publish the next pending message of the last view (one per sample)."""
        pub, message = self._queue[self.MESSAGES - self.pending]
        self.pending -= 1
        pub.publish(message.payload())

    def flush(self) -> None:
        """Publish every pending message of the last view."""
        while self.pending:
            self.publish_next()
