"""The plant node's rooms: each policy of :class:`fohssv_sim.ros.plant_node.PlantNode` in a
module of its own, and the optional compiled fast path (:mod:`.fastpath`)."""
