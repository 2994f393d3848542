"""The hosted law (``controller:=NAME``): its parameters, the law at every sample, bursts of
samples in one compiled call.

Rooms of :class:`fohssv_sim.ros.plant_node.PlantNode`: :class:`LawWatch`, an object that owns
the watch for a law's call that does not return; :class:`HostedRoom`, a mixin over the
node's attributes, as a burst of samples writes the node's messages, counters and model
directly (the per-sample path).
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Callable, Mapping
from time import monotonic, perf_counter, sleep
from typing import Any

import numpy as np

from ... import control
from ...control import NonFiniteCommand
from ...models import MAX_PITCH, check_state
from ...params import ParameterError, ParameterSpec, field_specs
from ..loop import HostedLaw, time_text
from ..nodekit import (
    PLUGIN_FAULTS,
    STOP,
    LogLimiter,
    build_plugin,
    declare,
    install_validation,
)
from ..spin import PluginHung
from .codes import CONTROLLER_PREFIX, EXIT_LAW_HUNG, EXIT_PUBLISH_FAILED, PublishFailed
from .commands import LOG_EACH

#: With a hosted controller: the wall time (s) one chunk of samples runs before the executor
#: is spun again (services, parameters, the graph checks, signals).
_CHUNK = 0.02

#: Lockstep with a hosted law: samples per compiled call (between looks at the clock).
_FREE_BURST = 32

#: Most samples of one burst (a realtime backlog beyond it is taken in several).
BURST_ROWS = 64

#: A hosted law's call that has not returned after this wall time (s) is hung: logged (plugin,
#: sample time), and a SIGINT/SIGTERM then ends the run in order with exit 10.
LAW_TIMEOUT = 1.0


class LawWatch:
    """A hosted law's call that has not returned for :data:`LAW_TIMEOUT` s: logged once per
    call by a daemon thread, and said by the signal handler, which then ends the run (exit
    10) instead of waiting for the call.

    Given the law's ``name``, ``t()`` (the sample time of the call) and the node's logger.
    Made, it installs :meth:`stuck` as the signal handler's
    :attr:`~fohssv_sim.ros.spin.StopSignal.stuck` and starts its thread; the node sets
    :attr:`started` around each call of the law (per sample, inline) and calls :meth:`end`
    at the run's end."""

    def __init__(self, name: str, t: Callable[[], float], log: Any) -> None:
        self._name, self._t, self._log = name, t, log
        self.started = 0.0                   # perf_counter of the call in progress, 0: none
        self._end = threading.Event()        # ends the watch (at the run's end)
        STOP.stuck = self.stuck
        threading.Thread(target=self._watch, name='law-watch', daemon=True).start()

    def end(self) -> None:
        self._end.set()

    def stuck(self) -> str | None:
        """The call in progress when it has not returned for :data:`LAW_TIMEOUT` s (plugin,
        sample time, how long), else None. Read by the signal handler and the watch
        thread."""
        start = self.started
        if not start:
            return None
        late = perf_counter() - start
        if late < LAW_TIMEOUT:
            return None
        return (f'hosted law {self._name}.command(t={time_text(self._t())}) has not '
                f'returned for {late:.1f} s (LAW_TIMEOUT={LAW_TIMEOUT:g} s)')

    def _watch(self) -> None:
        """The daemon thread: log a hung law call once per call (the loop is stuck in it)."""
        reported = 0.0
        while not self._end.wait(LAW_TIMEOUT / 4):
            start, why = self.started, self.stuck()
            if why is not None and start != reported:
                reported = start
                self._log.error(f'{why}; SIGINT or SIGTERM now ends the run (exit '
                                f'{EXIT_LAW_HUNG}) after closing its outputs')


class HostedRoom:
    """The plant node with a hosted law (the module docstring)."""

    commanded = 0        # commands the law gave
    commands_sent = 0    # of those, published (subscribed) or put into the in-plant bag
    law_failures = 0     # samples the law gave no command for
    law_time = 0.0       # wall time in the law's calls (s)

    def _host(self, name: str) -> HostedLaw | None:
        """The plugin ``name`` hosted in the loop, its parameters declared under
        :data:`CONTROLLER_PREFIX` from its table (the controller node's descriptors, ranges,
        units; the run-time changeable ones change here too); None for '' (external).

        Raises:
            control.UnknownController: no such plugin (the message lists the valid ones).
            ParameterError: an invalid value of one of its parameters.
        """
        if not name:
            return None
        self._controller_cls = control.load(name)
        specs: tuple[ParameterSpec, ...] = tuple(
            dataclasses.replace(spec, name=CONTROLLER_PREFIX + spec.name)
            for spec in field_specs(self._controller_cls.Parameters))
        law = HostedLaw(self._build_controller(declare(self, specs)))
        install_validation(self, tuple(s.name for s in specs), self._build_controller,
                           self._apply_controller)
        self.law_watch = LawWatch(law.name, lambda: self.sim.plant.t, self.get_logger())
        self._log_law = LogLimiter(self.get_logger(), LOG_EACH)   # samples without a command
        # the rows a burst of samples is computed into (SampledPlant.advance_burst) and
        # [max |delta_f|, max |delta_c|, max |w|, max |theta|] (the first three set at each
        # burst: the options and the model may change at run time)
        self._rows = np.zeros((BURST_ROWS, 7))
        self._limits = np.array([0.0, 0.0, 0.0, MAX_PITCH])
        return law

    def _build_controller(self, values: Mapping[str, Any]) -> control.Controller:
        cls = self._controller_cls
        n = len(CONTROLLER_PREFIX)
        fields = {k[n:]: v for k, v in values.items() if k.startswith(CONTROLLER_PREFIX)}
        try:
            return build_plugin(cls, cls.Parameters(**fields))
        except ParameterError as exc:   # the dataclass names the field without the prefix
            text = str(exc)
            if any(text.startswith(f'{f}=') for f in fields):
                text = CONTROLLER_PREFIX + text
            raise ParameterError(text) from None

    def _apply_controller(self, controller: control.Controller) -> None:
        self.hosted = HostedLaw(controller)
        self.get_logger().info(f'controller parameters changed: {controller.describe()}')

    def _advance_burst(self, periods: int) -> bool:
        """Hosted affine law: up to ``periods`` samples (and their commands) in one compiled
        call, then each published as :meth:`_advance` and :meth:`_control` would, in order:
        the same numbers, messages and counts, one Python call into the kernel instead of one
        per sample. Plugins that are not affine, the interpreted engine and ``profile:=1`` take
        the per-sample path. False when the run ended."""
        sim = self.sim
        law = self.hosted.law
        if law is None or self.profile is not None:
            return self._advance_each(periods)
        o = self.options
        periods = min(periods, sim.samples_until(o.duration), len(self._rows))
        every = o.pace_to_subscribers if self.pacer is None else 0
        if every:
            periods = min(periods, every - sim.samples % every)
        limits = self._limits
        limits[0], limits[1] = o.max_fin_deflection, o.max_cavitator_deflection
        limits[2] = self.model.speed
        plant = sim.plant
        n0 = plant.n
        try:
            done, status = sim.advance_burst(law, periods, limits, self._rows)
        except FloatingPointError as exc:    # raised by the SOE history's own checks
            self._diverged(exc)
            return False
        if status < 0:                       # no compiled kernel
            return self._advance_each(periods)
        # Python floats (one conversion for the burst, not a numpy scalar per value)
        rows, hold, h = self._rows[:done].tolist(), sim.hold, plant.h
        state, force, pacer = self._state_data, self._force_data, self.pacer
        end = o.duration - 1e-9 * o.control_period if o.duration > 0.0 else math.inf
        last = done - 1
        for j in range(done):
            row = rows[j]
            if j == last and status == 2:   # outside the physical bounds: as advance() raises
                sim.samples += 1
                try:
                    check_state(plant)
                except FloatingPointError as exc:
                    self._diverged(exc)
                return False
            t = (n0 + (j + 1) * hold) * h
            state[0] = force[0] = t
            state[1], state[2], state[3], state[4] = row[0], row[1], row[2], row[3]
            force[1] = row[4]
            self.sent += 1
            try:
                self._send_sample(sim.samples + 1)
            except PublishFailed as exc:
                sim.samples += 1
                # the kernel computed the burst's later samples too: the run ended here
                self._cut = (t, n0 + (j + 1) * hold)
                self._fail(EXIT_PUBLISH_FAILED, str(exc))
                return False
            if pacer is not None:
                pacer.published(monotonic())
            if t >= end:
                sim.samples += 1
                self._finish(f'duration {o.duration:g} s reached')
                return False
            if j == last and status == 3:   # the law's command needs the slow path
                sim.samples += 1
                self._control()             # may end the run (a hung law and a signal)
                break
            df, dc = row[5], row[6]
            sim.took((df, dc))
            self._publish_command(t, df, dc)
        if status == 1:                      # the next period turned non-finite
            try:
                plant.raise_failure()
            except FloatingPointError as exc:
                self._diverged(exc)
            return False
        if every and self.running and sim.samples % every == 0:
            self.reader_pacing.keep_up(sim.samples, every, sim.t)
        return self.running

    def _advance_each(self, periods: int) -> bool:
        """``periods`` samples one at a time (:meth:`_advance`); False when the run ended."""
        every = self.options.pace_to_subscribers if self.pacer is None else 0
        for _ in range(periods):
            if not self._advance():
                return False
            if every and self.sim.samples % every == 0:
                self.reader_pacing.keep_up(self.sim.samples, every, self.sim.t)
        return True

    def _control(self) -> None:
        """The hosted law's command for the sample just published: published on ``command``
        (t = that sample, as a controller node answers) and held over the next control period
        if within the deflection limits (else rejected, as the plant rejects an external
        one). A non-finite output or a failing plugin gives no command: the last good one
        stays held, and it is counted and logged."""
        sim = self.sim
        t = sim.plant.t
        watch = self.law_watch
        watch.started = start = perf_counter()   # watched by LawWatch.stuck
        try:
            df, dc = self.hosted.command(t, sim.plant.x)
        except PluginHung as exc:     # a signal after the call hung for LAW_TIMEOUT
            self._fail(EXIT_LAW_HUNG, f'{exc}: stopped by a signal')
            return
        except PLUGIN_FAULTS as exc:  # a plugin's bug (even sys.exit) must not end the plant
            self._law_failed(t, exc)
            return
        finally:
            watch.started = 0.0
            self.law_time += perf_counter() - start
        self._publish_command(t, df, dc)
        o = self.options
        if abs(df) <= o.max_fin_deflection and abs(dc) <= o.max_cavitator_deflection:
            sim.command = (df, dc)
        else:
            self._take((t, df, dc))   # rejects it with the reason; the last good one stays

    def _publish_command(self, t: float, df: float, dc: float) -> None:
        """Publish what the hosted law commanded for the sample at ``t``."""
        self.commanded += 1
        if self._command_on:
            data = self._command_data
            data[0] = t
            data[1] = df
            data[2] = dc
            self._send_command(self._command_out.payload())
            self.commands_sent += 1

    def _law_failed(self, t: float, exc: BaseException) -> None:
        self.law_failures += 1
        what = (str(exc) if isinstance(exc, NonFiniteCommand) else
                f'{self.hosted.name}.command(t={time_text(t)}) raised {type(exc).__name__}: {exc}')
        df, dc = self.sim.command
        text = (f'{what}; no command for this sample, holding delta_f={df!r}, delta_c={dc!r} '
                f'rad ({self.law_failures} without a command)')
        self._log_law(text)

    def _run_chunk(self) -> None:
        """Hosted: samples for ``_CHUNK`` s of wall time, then the executor's turn (services,
        parameters, the graph checks; a signal ends the loop there). Lockstep: back to back;
        realtime: each when due, sleeping in between: ``time.sleep`` costs about half the
        CPU of a ``spin_once`` wait, and nothing is to be taken between samples."""
        self._refresh_matched()
        self._check_real_time()
        if not self.running:         # max_deadline_miss_rate ended the run
            return
        now = monotonic()
        end = now + _CHUNK
        pacer, bursts = self.pacer, self.bursts
        while now < end:
            if pacer is None:
                due = _FREE_BURST
            else:
                first = pacer.next_due()
                wake = first + bursts.wait()
                if now < wake:  # asleep until a whole burst is due (one wake-up per burst)
                    sleep(wake - now)
                    now = monotonic()
                    bursts.observe(now - first, now)
                due = pacer.due(now)
            if not self._advance_burst(due):
                return
            now = monotonic()
