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
rotation of -theta about y). The messages are made once and only their numbers are written
when a view is due (the plant's per-sample path pays one integer test otherwise); rclpy
serializes them at ``publish``. Measured with ``profile:=1`` (``publish_views``; realtime
delay-free plant at 1e-4 s, no view subscriber): 131 us per view for all four topics and both
markers, 1.3 us per sample at the default view_period; the sample that carries a view is that
much later (well inside the 1 ms deadline tolerance).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from visualization_msgs.msg import Marker

from ..contract import MARKER, POSE, TWIST, VIEW_BODY_FRAME, VIEW_WORLD_FRAME, WRENCH
from ..params import ModelParameters
from .qos import profile

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


class ViewPublisher:
    """The view publishers of ``node`` and their preallocated messages."""

    def __init__(self, node: Any, params: ModelParameters) -> None:
        self.pose_pub = node.create_publisher(PoseStamped, POSE.name, profile(POSE))
        self.twist_pub = node.create_publisher(TwistStamped, TWIST.name, profile(TWIST))
        self.wrench_pub = node.create_publisher(WrenchStamped, WRENCH.name, profile(WRENCH))
        self.marker_pub = node.create_publisher(Marker, MARKER.name, profile(MARKER))
        self.pose = PoseStamped()
        self.pose.header.frame_id = VIEW_WORLD_FRAME
        self.twist = TwistStamped()
        self.twist.header.frame_id = VIEW_BODY_FRAME
        self.twist.twist.linear.x = float(params.speed)
        self.wrench = WrenchStamped()
        self.wrench.header.frame_id = VIEW_BODY_FRAME
        self.half_length = 0.5 * params.length
        diameter = 2.0 * params.body_radius
        self.body = _marker(0, (params.length, diameter, diameter), (0.55, 0.57, 0.6, 1.0))
        length, radius = cavity_size(params)
        self.cavity = _marker(1, (length, 2.0 * radius, 2.0 * radius), (0.3, 0.65, 1.0, 0.25))
        self.cavity.pose.position.x = -0.5 * length
        self.stamps = [m.header.stamp for m in (self.pose, self.twist, self.wrench, self.body,
                                                self.cavity)]
        self.published = 0

    @property
    def publishers(self) -> tuple:
        return self.pose_pub, self.twist_pub, self.wrench_pub, self.marker_pub

    def publish(self, sample: Sequence[float], fp: float) -> None:
        """Publish the views of ``sample`` = [t, z, w, theta, q] and planing force ``fp``."""
        t, z, w, theta, q = sample[0], sample[1], sample[2], sample[3], sample[4]
        sec, nanosec = divmod(round(t * 1e9), 1_000_000_000)
        for stamp in self.stamps:
            stamp.sec = sec
            stamp.nanosec = nanosec
        up = -z
        qy, qw = -math.sin(0.5 * theta), math.cos(0.5 * theta)
        pose = self.pose.pose
        pose.position.z = up
        pose.orientation.y = qy
        pose.orientation.w = qw
        self.pose_pub.publish(self.pose)
        self.twist.twist.linear.z = -w
        self.twist.twist.angular.y = -q
        self.twist_pub.publish(self.twist)
        self.wrench.wrench.force.z = -fp
        self.wrench_pub.publish(self.wrench)
        body = self.body.pose
        body.position.x = -self.half_length * math.cos(theta)
        body.position.z = up - self.half_length * math.sin(theta)
        body.orientation.y = qy
        body.orientation.w = qw
        self.marker_pub.publish(self.body)
        self.cavity.pose.position.z = up
        self.marker_pub.publish(self.cavity)
        self.published += 1
