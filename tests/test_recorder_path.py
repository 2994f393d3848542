"""Two recorders started on one bag path: the one that loses the race to create it is refused
as a ``bag_path`` that exists (exit 2, as the docs say), not failed with an OS error (exit 1).
In process: a real recorder node (rclpy, its own context and domain)."""

from __future__ import annotations

import pytest
import rclpy
from rclpy.parameter import Parameter

from fohssv_sim.params import ParameterError
from fohssv_sim.ros.recorder_node import Recorder

import rosproc


@pytest.mark.graph
def test_a_bag_path_created_by_another_recorder_meanwhile_is_refused_as_existing(tmp_path):
    bag = tmp_path / 'bag'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=rosproc.unique_domain_id())
    node = None
    try:
        node = Recorder(context=ctx, parameter_overrides=[Parameter('bag_path',
                                                                    value=str(bag))])
        assert bag.is_dir()
        # the second recorder's step after its check that the path is free: the first one
        # has created it in between
        with pytest.raises(ParameterError, match=rf"bag_path='{bag}' exists already: the "
                                                 'recorder never overwrites a bag'):
            node._create_bag()
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.shutdown(context=ctx)
