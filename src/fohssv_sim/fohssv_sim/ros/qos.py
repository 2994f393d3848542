"""QoS profiles of the topic contract (:mod:`fohssv_sim.contract`), by the names its topics give.

* ``reliable_samples`` (``state``, ``planing_force``): reliable, keep-last with a deep queue
  (:data:`SAMPLE_DEPTH`), transient-local: the lockstep loop stalled when the controller's
  reader matched the plant only after the sample t = 0 was written. A recorder must keep
  every sample: at the default 10 kHz sample rate the queue covers 0.2 s of backlog; with
  ``pace_to_subscribers`` a lockstep plant waits for its subscribers' acknowledgements, so a
  keep-all reader (the recorder's) that falls behind paces the run instead of losing samples.
  (A deeper queue slowed Fast DDS: 10000 halved the lockstep rate.)
* ``reliable_commands`` (``command``): reliable, keep-last :data:`COMMAND_DEPTH`, volatile.
  Lockstep depends on every command arriving, and a recorder must keep them all: a reliable
  keep-last writer drops what a slow reader has not acknowledged once its queue is full, so
  commands get the samples' depth (with 100, a recorder lagging 70 ms lost commands).
* ``clock`` (``/clock``): reliable, keep-last 1, volatile. A reliable writer also serves the
  best-effort reader that rclpy's time source creates for ``use_sim_time``.
* ``views`` (the typed views ``pose``, ``twist``, ``planing_wrench``, ``vehicle_marker``):
  reliable, keep-last :data:`VIEW_DEPTH`, transient-local (a viewer or recorder that matches
  late still gets the last second of views at the default ``view_period``); volatile readers
  match too.
* ``run_end`` (``run_end``, once per run): reliable, keep-last 1, transient-local (a recorder
  that matches after the run ended still gets it).

Publishers and subscribers must take their profile from :func:`profile` with the topic's
``qos`` field, never build one inline.

:func:`offered_qos` gives the profile the plant offers on a topic as rosbag2 records it
(``offered_qos_profiles`` in metadata.yaml and in the MCAP channel metadata), so that
``ros2 bag play`` offers the same reliability and durability as the plant and the project's
transient-local readers match a replay.
"""

from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from ..contract import Topic

__all__ = ['SAMPLE_DEPTH', 'COMMAND_DEPTH', 'VIEW_DEPTH', 'PROFILES', 'profile', 'offered_qos',
           'DURATION_INFINITE']

#: Queue depth of state and force samples (0.2 s at the default 1e-4 s control period).
SAMPLE_DEPTH = 2000
#: Queue depth of commands: as deep as the samples (a recorder lags the same on both).
COMMAND_DEPTH = SAMPLE_DEPTH
#: Queue depth of the typed views (1 s of simulated time at the default view_period 0.01 s).
VIEW_DEPTH = 100


def _reliable(depth: int, durability: DurabilityPolicy = DurabilityPolicy.VOLATILE
              ) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE, durability=durability)


PROFILES: dict[str, QoSProfile] = {
    # transient-local: a reader whose side of the match completes after the plant published
    # its first sample (DDS discovery is not symmetric in time) still gets it; volatile readers
    # (third-party tools) stay compatible.
    'reliable_samples': _reliable(SAMPLE_DEPTH, DurabilityPolicy.TRANSIENT_LOCAL),
    'reliable_commands': _reliable(COMMAND_DEPTH),
    'clock': _reliable(1),
    'views': _reliable(VIEW_DEPTH, DurabilityPolicy.TRANSIENT_LOCAL),
    # once per run; transient-local so that a recorder that matches late still gets it
    'run_end': _reliable(1, DurabilityPolicy.TRANSIENT_LOCAL),
}


def profile(topic: Topic | str) -> QoSProfile:
    """The QoS profile of ``topic`` (a contract :class:`~fohssv_sim.contract.Topic` or the name
    of a profile).

    Raises:
        KeyError: no such profile (lists the valid names).
    """
    name = topic.qos if isinstance(topic, Topic) else topic
    try:
        return PROFILES[name]
    except KeyError:
        raise KeyError(f"no QoS profile {name!r}; valid: {', '.join(PROFILES)}") from None


#: RMW_DURATION_INFINITE as rosbag2 writes it: {sec: 9223372036, nsec: 854775807}.
DURATION_INFINITE = QosTime(9223372036, 854775807)


def _time(d: Duration) -> QosTime:
    # 0 is "the rmw's default", which for deadline, lifespan and liveliness lease duration is
    # infinite: that is what the graph reports for the plant's publishers (tested)
    ns = d.nanoseconds
    return DURATION_INFINITE if ns == 0 else QosTime(ns // 10**9, ns % 10**9)


def offered_qos(topic: Topic | str) -> Qos:
    """The profile a publisher of ``topic`` (as :func:`profile`) offers, in rosbags' form
    (which writes it as rosbag2 does: policy names, ``{sec, nsec}`` durations).

    History and depth are the profile's (the graph does not report them); the durations and
    liveliness the profile leaves to the rmw are written as the rmw resolves them (infinite,
    automatic).
    """
    p = profile(topic)
    liveliness = (LivelinessPolicy.AUTOMATIC if p.liveliness == LivelinessPolicy.SYSTEM_DEFAULT
                  else p.liveliness)
    return Qos(history=QosHistory[p.history.name], depth=int(p.depth),
               reliability=QosReliability[p.reliability.name],
               durability=QosDurability[p.durability.name],
               deadline=_time(p.deadline), lifespan=_time(p.lifespan),
               liveliness=QosLiveliness[liveliness.name],
               liveliness_lease_duration=_time(p.liveliness_lease_duration),
               avoid_ros_namespace_conventions=bool(p.avoid_ros_namespace_conventions))
