"""Publishing a sample: state, planing_force, /clock and the views, the publish retry, what is
published while nobody subscribes. Every path a sample takes (interpreted, burst, the short and
the compiled lockstep path) ends here.

A room of :class:`fohssv_sim.ros.plant_node.PlantNode`: a mixin whose methods run on the node,
as every sample passes here; its counters and switches are declared in its class body, the
messages and publishers are made by ``PlantNode._open_topics``.
"""

from __future__ import annotations

import time
from time import monotonic
from typing import Any

from ..loop import time_text
from .codes import PublishFailed
from .fastpath import sample as fastpath

#: How long a sample DDS refuses is retried (s; every millisecond) before the run ends
#: (exit 9).
_PUBLISH_RETRY = 1.0


class Publishing:
    """How the plant node publishes a sample (the module docstring): a mixin, as every
    sample path ends here; its counters and switches are declared here."""

    sent = 0               # samples published (state, planing_force)
    forces_lost = 0        # planing_force samples not published (their state was)
    publish_retries = 0    # publishes DDS refused at first
    # /clock and a hosted law's command (volatile) are published only while someone
    # subscribes (_refresh_matched); *_on: made at all (published, or with record:=PATH only
    # put into the in-plant bag)
    _clock_wanted = _clock_on = True
    _command_wanted = _command_on = True

    def _publish(self) -> None:
        self.sent += 1
        self.sim.write_sample(self._state_data, self._force_data)
        self._send_sample(self.sim.samples)

    def _send_sample(self, sample: int) -> None:
        """Publish sample number ``sample``, written into the state and force messages: state,
        planing_force, /clock and the views when due."""
        # a failed publish (rclpy's RCLError 'Failed to publish' under load) is retried,
        # and ends the run with exit 9 (summary, run_end) if DDS keeps refusing it
        # (each payload made once: a retry sends the same bytes)
        payload = self._state_out.payload()
        try:
            self._send_state(payload)
        except Exception as exc:  # noqa: BLE001 - RCLError is not exported by rclpy
            self._retry_publish(self._send_state, self.state_pub.topic_name, payload, exc,
                                state=True)
        self._send_rest(sample)

    def _send_rest(self, sample: int) -> None:
        """What :meth:`_send_sample` publishes after the state: planing_force, /clock and
        the views when due."""
        payload = self._force_out.payload()
        try:
            self._send_force(payload)
        except Exception as exc:  # noqa: BLE001
            self._retry_publish(self._send_force, self.force_pub.topic_name, payload, exc)
        self._send_after_force(sample)

    def _send_after_force(self, sample: int) -> None:
        """What :meth:`_send_rest` publishes after the planing force: /clock and the views
        when due."""
        if self._clock_on and sample % self._clock_every == 0:
            try:
                self._send_clock(self._clock_out.payload(round(self._state_data[0] * 1e9)))
            except Exception as exc:  # noqa: BLE001 - keep-last 1: the next one replaces it
                self._log_retry(f'/clock at t={time_text(self._state_data[0])} s not published: '
                                f'{exc}')
        self._send_views(sample)

    def _send_views(self, sample: int) -> None:
        """The views' messages of ``sample``, when due (one per sample: views.py)."""
        views = self.views
        if views is not None:     # a view's messages go out one per sample (views.py)
            try:
                if sample % self._view_every == 0:
                    views.publish(self._state_data, self._force_data[1])
                elif views.pending:
                    views.publish_next()
            except Exception as exc:  # noqa: BLE001 - views are for people: never fatal
                self._log_retry(f'views at t={time_text(self._state_data[0])} s not published: '
                                f'{exc}')

    def _retry_publish(self, send: Any, name: str, payload: Any, exc: Exception,
                       state: bool = False) -> None:
        """Publish again every millisecond for up to :data:`_PUBLISH_RETRY` s (counted, the
        first lines logged); raise :class:`PublishFailed` if DDS still refuses."""
        self.publish_retries += 1
        self._log_retry(f'{name}: publishing the sample at t={time_text(self._state_data[0])} '
                        f'failed ({exc}); retrying ({self.publish_retries} retried)')
        deadline = monotonic() + _PUBLISH_RETRY
        while monotonic() < deadline and self.context.ok():
            time.sleep(0.001)
            try:
                send(payload)
                self.command_wait.checked = monotonic()   # the plant's own wait (see _next)
                return
            except Exception as again:  # noqa: BLE001
                exc = again
        if state:
            self.sent -= 1   # the state of this sample never went out, nor (not counted in
                             # sent) its planing_force, which is not published after it
        else:
            self.forces_lost += 1              # the state went out, its planing_force not
        raise PublishFailed(f'{name}: the sample at t={time_text(self._state_data[0])} s '
                            f'could not be published for {_PUBLISH_RETRY:g} s ({exc}); '
                            'stopping the run')

    def _compiled_rest(self, sample: int) -> None:
        """What :meth:`_send_after_force` does after a compiled sample, which published the
        clock itself: a clock rcl refused is said (as :meth:`_send_after_force` says it),
        and the views when due."""
        c = self._compiled
        if c.clock_asked & fastpath.CLOCK_PUBLISH and c.clock_ret != 0:
            self._log_retry(f'/clock at t={time_text(self._state_data[0])} s not published: '
                            f'rcl_publish_serialized_message returned {c.clock_ret}: '
                            f'{c.take_error()}')
        self._send_views(sample)

    def _refresh_matched(self) -> None:
        """Whether anyone subscribes to ``/clock`` (and, hosted, to ``command``): a volatile
        topic nobody reads is not published (a reader that is not there gets nothing either
        way; 4-10 us of CPU per sample saved, on the lockstep round trip too; a reader
        that matches during a run gets /clock from the next look). Looked at
        between chunks of samples (hosted) or in the timer's checks (external controller:
        every 10 ms in real time, every ``min(0.05 s, command_timeout / 4)`` in lockstep),
        never per sample; at the start the plant waits for the listed ``/clock`` readers to
        match (:meth:`_listed_matched`). With ``record`` both are still made and put into
        the in-plant bag, which holds them all (inplant_record.py publishes them only while
        wanted)."""
        recording = self.record is not None
        self._clock_wanted = self.clock_pub.get_subscription_count() > 0
        self._clock_on = self._clock_wanted or recording
        if self.command_pub is not None:
            self._command_wanted = self.command_pub.get_subscription_count() > 0
            self._command_on = self._command_wanted or recording
