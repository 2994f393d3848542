"""QoS profiles of the topic contract (:mod:`fohssv_sim.contract`), by the names its topics give.

* ``reliable_samples`` (``state``, ``planing_force``): reliable, keep-last with a deep queue
  (:data:`SAMPLE_DEPTH`), volatile. A recorder must keep every sample: at the default 10 kHz
  sample rate the queue covers 0.2 s of backlog before a slow reader loses anything.
* ``reliable_commands`` (``command``): reliable, keep-last :data:`COMMAND_DEPTH`, volatile.
  Lockstep depends on every command arriving; in real time only the newest one matters, but a
  reliable queue costs nothing at these rates and keeps the two modes on one profile.
* ``clock`` (``/clock``): reliable, keep-last 1, volatile. A reliable writer also serves the
  best-effort reader that rclpy's time source creates for ``use_sim_time``.

Publishers and subscribers must take their profile from :func:`profile` with the topic's
``qos`` field, never build one inline.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..contract import Topic

__all__ = ['SAMPLE_DEPTH', 'COMMAND_DEPTH', 'PROFILES', 'profile']

#: Queue depth of state and force samples (0.2 s at the default 1e-4 s control period).
SAMPLE_DEPTH = 2000
#: Queue depth of commands.
COMMAND_DEPTH = 100


def _reliable(depth: int) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


PROFILES: dict[str, QoSProfile] = {
    'reliable_samples': _reliable(SAMPLE_DEPTH),
    'reliable_commands': _reliable(COMMAND_DEPTH),
    'clock': _reliable(1),
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
