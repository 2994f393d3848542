"""profile:=1 as a hook over the plant node's own calls (fohssv_sim.ros.plant.instrumentation):
a hosted lockstep run built in this process counts each named part as often as the run's
schedule says it happens, and the node keeps its product path (the same samples)."""

from __future__ import annotations

import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from fohssv_sim.ros.plant.instrumentation import PROFILE_PARTS, Profile
from fohssv_sim.ros.plant_node import EXIT_OK, PlantNode

import rosproc


def _hosted_run(profile: int) -> PlantNode:
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=rosproc.unique_domain_id())
    node = PlantNode(context=context, parameter_overrides=[
        Parameter('model', value='delay-free'), Parameter('duration', value=0.01),
        Parameter('controller', value='state_feedback'), Parameter('profile', value=profile),
        Parameter('view_period', value=0.0), Parameter('end_linger', value=0.0)])
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 60.0
        while not node.finished.done():
            assert time.monotonic() < deadline, 'the run did not end'
            executor.spin_once(timeout_sec=0.0)
            node.publish_due()          # the chunks of samples the plant's spin loop runs
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    return node


@pytest.mark.graph
def test_profile_counts_each_part_of_a_hosted_run_and_changes_nothing_else():
    """0.01 s at 1e-4 s: 100 periods stepped, 101 samples written and published (t = 0
    too), and the law asked after each sample but the last (the run ends there): 100."""
    plain, profiled = _hosted_run(0), _hosted_run(1)
    assert plain.exit_code == profiled.exit_code == EXIT_OK
    assert plain.profile is None
    s, p = plain.summary(), profiled.summary()
    keys = ('t', 'samples', 'steps', 'published_states', 'hosted_commands', 'law_failures')
    assert {k: s[k] for k in keys} == {k: p[k] for k in keys}
    prof = p['profile']
    assert tuple(prof) == ('advance', 'write_sample', 'publish_state', 'publish_planing_force',
                           'hosted_law')
    assert prof['advance']['calls'] == 100
    assert prof['write_sample']['calls'] == prof['publish_state']['calls'] == 101
    assert prof['publish_planing_force']['calls'] == 101
    assert prof['hosted_law']['calls'] == p['hosted_commands'] == 100
    for part in prof.values():
        assert 0.0 < part['mean_us'] <= part['worst_us']


def test_timed_adds_each_call_and_more_adds_to_the_last_one():
    profile = Profile()
    calls = []
    timed = profile.timed('publish_views', calls.append)
    more = profile.timed('publish_views', calls.append, more=True)
    timed(1)
    more(2)
    timed(3)
    i = PROFILE_PARTS.index('publish_views')
    assert calls == [1, 2, 3]
    assert profile.calls[i] == 2                   # the later piece belongs to the first call
    assert profile.ns[i] >= profile.worst[i] >= profile.last[i] > 0
