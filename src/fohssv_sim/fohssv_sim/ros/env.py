"""``HSSVRos-v0``: the agent is the controller of a real plant node, in lockstep over DDS.

Each :meth:`HSSVRosEnv.step` publishes one ``command`` ``[t, delta_f, delta_c]`` answering
the plant's last ``state`` (as the controller node does, and like it holding the command until
the plant's subscription has matched the publisher: :class:`.matching.SubscriptionGate`) and
waits for the next ``state`` and ``planing_force``; the lockstep plant holds the command over
one control period in its own compiled call, so the observations are those of ``HSSV-v0``
with the same keyword arguments, seed and actions, bit for bit (tested over 10,000 steps).

The plant is started by the env (``start_plant=True``, the default: ``ros2 run fohssv_sim
plant`` in lockstep with the env's model parameters, control period and start state, under
``namespace``, on ``domain_id``; stopped by :meth:`close`) or already running
(``start_plant=False``: a lockstep plant under ``namespace`` with the same parameters).
``reset`` sets the plant's ``initial_state`` parameter to the drawn start and calls its
``reset`` service (std_srvs/Trigger). The model's parameters are read-only on a running plant,
so ``speed_range`` and ``order_range`` are refused here.

A lost vehicle: the plant node ends (exit 1, "simulation failed") without publishing the
state beyond the bounds. The env then computes that step as ``HSSV-v0`` does, replaying the
episode (its start and actions) in-process: the same numbers the plant computed, so the
observation, reward and terminated flag are ``HSSV-v0``'s at the same step (tested through a
loss), and ``info['lost']`` says why and names the plant's exit. A plant the env started is
started again at the next reset.

Needs rclpy (the ROS layer); everything else comes from :mod:`fohssv_sim.envs`.
"""

from __future__ import annotations

import functools
import os
import subprocess
import tempfile
import time
import weakref
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ..closed_loop import NodeSpec, ros_args
from ..contract import COMMAND, PLANING_FORCE, STATE
from ..envs.single import EpisodeEnv, HSSVEnv, spaces_of
from ..envs.task import make_task
from ..params import ParameterError
from ..solvers import soe_options
from .matching import SubscriptionGate
from .qos import profile
from .spin import make_executor
from .startup import default_discovery, default_transport

__all__ = ['HSSVRosEnv']

#: Wall seconds to wait for the first sample of a plant the env started (its start-up and,
#: on a new machine, the compilation of its kernels).
START_TIMEOUT = 120.0


class HSSVRosEnv(EpisodeEnv):
    """See the module docstring. Keyword arguments: those of ``HSSV-v0`` plus
    ``namespace`` (the plant's, '' = root), ``start_plant`` (bool), ``domain_id`` (the ROS
    domain of the env and the plant it starts; None = ``ROS_DOMAIN_ID``) and ``timeout``
    (s of wall time to wait for a sample, default 30).

    Raises:
        ParameterError: a bad keyword argument, or ``speed_range`` / ``order_range``.
        TimeoutError: no sample within ``timeout`` from a plant the env did not start.
        RuntimeError (from ``step``): the plant the env started ended with the vehicle
            within its bounds (killed, or stopped for another reason), naming its exit.
    """

    def __init__(self, namespace: str = '', start_plant: bool = True,
                 domain_id: int | None = None, timeout: float = 30.0, **kwargs: Any) -> None:
        self.task = make_task(kwargs)
        self._kwargs = kwargs
        for name in ('speed_range', 'order_range'):
            if getattr(self.task, name) is not None:
                raise ParameterError(f'{name}={getattr(self.task, name)!r} is not supported by '
                                     'HSSVRos-v0: the model parameters of a running plant are '
                                     'read-only (domain randomisation: HSSV-v0); allowed: none')
        if not (isinstance(timeout, (int, float)) and timeout > 0):
            raise ParameterError(f'timeout={timeout!r} is not valid; allowed: (0, inf) s')
        self.observation_space, self.action_space = spaces_of(self.task)
        self.namespace = namespace.strip('/')
        self.start_plant = bool(start_plant)
        self.timeout = float(timeout)
        self.episode_parameters = self.task.params.to_dict()
        self.process: subprocess.Popen | None = None
        self.domain_id = domain_id
        self._log = None
        self._context = _context(domain_id)
        self._node = rclpy.create_node('hssv_env', namespace='/' + self.namespace,
                                       context=self._context)
        node = self._node
        # the nodes' executor: half the CPU a step of the single-threaded one in this process
        self._executor = make_executor(self._context)
        self._executor.add_node(node)
        self._states: dict[float, tuple] = {}
        self._forces: dict[float, float] = {}
        self._command = Float64MultiArray()
        self._pub = node.create_publisher(Float64MultiArray, COMMAND.name, profile(COMMAND))
        # callbacks that hold the dicts, not the env: an executor's native side keeps them, and
        # the garbage collector could not free an env they referred to (its plant would run on)
        state = node.create_subscription(Float64MultiArray, STATE.name,
                                         functools.partial(_on_state, self._states),
                                         profile(STATE))
        # a command published before the plant's subscription matched this publisher is lost
        # (the plant can match our state reader first) and the lockstep plant waits for it:
        # hold the first command as the controller node does
        self._matched = SubscriptionGate(node, self._pub, follow=state.topic_name)
        node.create_subscription(Float64MultiArray, PLANING_FORCE.name,
                                 functools.partial(_on_force, self._forces),
                                 profile(PLANING_FORCE))
        self._reset_client = node.create_client(Trigger, 'reset')
        self._param_client = node.create_client(SetParameters, 'plant/set_parameters')
        self._t = 0.0
        self._heard = False       # a sample of the plant was taken (it answers us only)

    # -- the plant ------------------------------------------------------------------------
    def plant_args(self, initial_state: Sequence[float] | None = None) -> list[str]:
        """The arguments of ``ros2 run fohssv_sim plant`` for the plant this env expects
        (lockstep, its model parameters and control period, its namespace; the start state
        ``initial_state``, default the env's): how the env starts it, and how to start one
        for ``start_plant=False``."""
        task = self.task
        x0 = task.initial_state if initial_state is None else tuple(initial_state)
        p = dict(task.params.to_dict())
        if p['model'] == 'fractional' and p['solver'] == 'soe':
            # the in-process env's history: sized for an episode (the plant runs open-ended)
            p['soe_horizon_steps'] = float(soe_options(task.params, task.duration)
                                           ['horizon_steps'])
        p.update(mode='lockstep', control_period=task.control_period, initial_state=list(x0),
                 command_timeout=3600.0, min_state_subscribers=1)
        args = ros_args(NodeSpec('fohssv_sim', 'plant', 'plant', p))
        if self.namespace:
            args += ['-r', f'__ns:=/{self.namespace}']
        return args

    def _start(self, x0: tuple) -> None:
        from ament_index_python.packages import get_package_prefix

        exe = Path(get_package_prefix('fohssv_sim')) / 'lib' / 'fohssv_sim' / 'plant'
        env = dict(os.environ, PYTHONUNBUFFERED='1')
        if self.domain_id is not None:
            env['ROS_DOMAIN_ID'] = str(self.domain_id)
        if self._log is not None:
            self._log.close()
        self._log = tempfile.TemporaryFile('w+')  # noqa: SIM115 - closed with the env
        self.process = subprocess.Popen([str(exe), *self.plant_args(x0)], env=env,
                                        stdout=self._log, stderr=subprocess.STDOUT, text=True,
                                        start_new_session=True)
        # an env never closed (a notebook, a failing script) still stops its plant when it is
        # collected or the interpreter exits: the plant would otherwise wait for a controller
        weakref.finalize(self, _stop, self.process)

    def _plant_ended(self) -> str:
        """Why the plant the env started has ended ('' while it runs or when not ours)."""
        proc = self.process
        if proc is None or proc.poll() is None:
            return ''
        self._log.seek(0)
        lines = [ln for ln in self._log.read().splitlines() if ln.strip()]
        return f'the plant exited with code {proc.returncode}: ' + (lines[-1] if lines else '')

    # -- messages ---------------------------------------------------------------------------
    def _wait(self, t: float, timeout: float | None = None) -> tuple[tuple, float] | str:
        """The state and Fp of the sample at time ``t``, or why the plant ended."""
        timeout = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        while not (t in self._states and t in self._forces):
            why = self._plant_ended()
            if why:
                return why
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f'no sample at t={t!r} s from the plant within '
                                   f'{timeout:g} s (namespace '
                                   f"'/{self.namespace}')")
            self._executor.spin_once(timeout_sec=min(left, 0.1))
        return self._states.pop(t), self._forces.pop(t)

    def _call(self, client: Any, request: Any) -> Any:
        deadline = time.monotonic() + self.timeout
        while not client.wait_for_service(timeout_sec=0.1):
            if time.monotonic() > deadline or self._plant_ended():
                raise TimeoutError(f'service {client.srv_name} not available within '
                                   f'timeout={self.timeout:g} s')
        future = client.call_async(request)
        self._executor.spin_until_future_complete(future, timeout_sec=self.timeout)
        if not future.done():
            raise TimeoutError(f'service {client.srv_name} did not answer within '
                               f'timeout={self.timeout:g} s')
        return future.result()

    # -- the Gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None
              ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        params, x0 = self.task.draw(self.np_random, (options or {}).get('initial_state'))
        self._states.clear()
        self._forces.clear()
        wait = self.timeout
        if self.start_plant and (self.process is None or self.process.poll() is not None):
            self._start(x0)
            wait = max(wait, START_TIMEOUT)
        else:
            if not self._heard:
                # a running plant publishes its sample once this env's subscription matches:
                # take it first, so that it cannot pass for the sample of the reset below
                deadline = time.monotonic() + max(self.timeout, START_TIMEOUT)
                while not (self._states and self._forces):
                    if time.monotonic() > deadline:
                        raise TimeoutError(f'no sample from a plant under namespace '
                                           f"'/{self.namespace}' within "
                                           f'{max(self.timeout, START_TIMEOUT):g} s')
                    self._executor.spin_once(timeout_sec=0.1)
            req = SetParameters.Request()
            req.parameters = [Parameter('initial_state', Parameter.Type.DOUBLE_ARRAY,
                                        list(x0)).to_parameter_msg()]
            res = self._call(self._param_client, req)
            if not res.results[0].successful:
                raise RuntimeError(f'the plant refused initial_state={list(x0)}: '
                                   f'{res.results[0].reason}')
            self._states.clear()
            self._forces.clear()
            res = self._call(self._reset_client, Trigger.Request())
            if not res.success:
                raise RuntimeError(f'the plant refused the reset: {res.message}')
        got = self._wait(0.0, wait)
        if isinstance(got, str):
            raise RuntimeError(got)
        x, fp = got
        self._heard = True
        self._x0, self._actions = x0, []
        self._t = 0.0
        return self._begin_episode(x, fp, 0.0)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = self._begin_step(action)
        self._actions.append(np.array(action, dtype=float))
        self._command.data = [self._t, float(u[0]), float(u[1])]
        deadline = time.monotonic() + self.timeout
        while not self._matched():
            why = self._plant_ended()
            if why:
                return self._lost(why)
            if time.monotonic() > deadline:
                raise TimeoutError(f'the plant under namespace \'/{self.namespace}\' did not '
                                   f'subscribe to {self._pub.topic_name} within '
                                   f'{self.timeout:g} s')
            self._executor.spin_once(timeout_sec=0.01)
        self._pub.publish(self._command)
        t_next = (self._steps + 1) * self.task.hold * self.task.params.step
        got = self._wait(t_next)
        if isinstance(got, str):
            return self._lost(got)
        self._t = t_next
        return self._end_step(u, *got, t_next, '')

    def _lost(self, why: str) -> tuple[np.ndarray, float, bool, bool, dict]:
        """The step on which the plant ended (``why``): ``HSSV-v0``'s, from the episode's
        start and actions replayed in-process (the plant does not publish a state beyond its
        bounds). Raises RuntimeError when the replay keeps the vehicle (the plant ended for
        another reason)."""
        self._done = True
        env = HSSVEnv(**self._kwargs)
        env.reset(options={'initial_state': self._x0})
        for a in self._actions:
            obs, reward, terminated, truncated, info = env.step(a)
        if not terminated:
            raise RuntimeError(f'{why} (at t={self._t!r} s, the vehicle within its bounds)')
        self._t = info['t']
        info['lost'] = f"{info['lost']}; {why}"
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Stop the plant the env started (SIGINT, then SIGKILL after 10 s) and leave the
        ROS context."""
        if self.process is not None:
            _stop(self.process)
        if self._log is not None:
            self._log.close()
            self._log = None
        if self._context.ok():
            self._executor.shutdown()
            self._node.destroy_node()
            self._context.shutdown()
        super().close()


def _context(domain_id: int | None) -> Any:
    """An initialised rclpy context with the discovery and transport the nodes give themselves
    (:mod:`fohssv_sim.ros.startup`), on ``domain_id``."""
    saved = {k: os.environ.get(k) for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                            'FASTDDS_DEFAULT_PROFILES_FILE')}
    try:
        default_discovery()
        default_transport()
        ctx = rclpy.Context()
        if domain_id is None:
            rclpy.init(context=ctx)
        else:
            rclpy.init(context=ctx, domain_id=int(domain_id))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return ctx


def _stop(proc: subprocess.Popen) -> None:
    """SIGINT to a plant the env started, SIGKILL after 10 s."""
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def _on_state(states: dict, msg: Float64MultiArray) -> None:
    d = msg.data
    if len(d) == 5:
        states[d[0]] = (d[1], d[2], d[3], d[4])


def _on_force(forces: dict, msg: Float64MultiArray) -> None:
    d = msg.data
    if len(d) == 2:
        forces[d[0]] = d[1]
