"""The plant node's rooms: each policy of :class:`fohssv_sim.ros.plant_node.PlantNode` in a
module of its own (a mixin over the node's attributes, set in ``PlantNode.__init__``).

* :mod:`.start`: the start gate (peers, listed readers, a second plant or controller) and
  the ``reset`` service;
* :mod:`.publishing`: how a sample goes out (state, planing_force, /clock, views, retries);
* :mod:`.hosted`: a hosted law (``controller:=NAME``), bursts of samples;
* :mod:`.lockstep`: the awaited command, its timeout and graces, the short path;
* :mod:`.realtime`: pacing, the watchdog, the command lag stop;
* :mod:`.commands`: an external controller's commands checked, held or rejected;
* :mod:`.run_end`: the summary, ``run_end``, the flush and the linger;
* :mod:`.host_tuning`: affinity, CPU latency, SCHED_FIFO;
* :mod:`.instrumentation`: ``profile:=1``, a hook over the node's own calls;
* :mod:`.codes`: the exit codes;
* :mod:`.fastpath`: optional, the lockstep FOM sample in compiled code, rcl called by
  address (:mod:`.fastpath.taking` is the node's side).
"""
