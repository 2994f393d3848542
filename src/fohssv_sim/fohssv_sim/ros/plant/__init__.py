"""The plant node's rooms: each policy of :class:`fohssv_sim.ros.plant_node.PlantNode` in a
module of its own. A room off the per-sample path is an object that owns its state, made in
``PlantNode.__init__`` with what it reads and the calls back it makes; a room on a per-sample
path is a mixin (a base of ``PlantNode``) that declares its counters and flags in its class
body, as an object's attribute hop there would cost every sample.

* :mod:`.start`: :class:`~.start.PeerGate` (object: peers, listed readers, a second plant or
  controller) and :class:`~.start.RunStart` (mixin: the start and the ``reset`` service);
* :mod:`.publishing`: mixin, how a sample goes out (state, planing_force, /clock, views,
  retries);
* :mod:`.hosted`: a hosted law (``controller:=NAME``): :class:`~.hosted.LawWatch` (object: a
  call that does not return) and :class:`~.hosted.HostedRoom` (mixin: bursts of samples);
* :mod:`.lockstep`: :class:`~.lockstep.CommandWait` (object: the awaited command's timeout,
  its graces, overruns), :class:`~.lockstep.ReaderPacing` (object:
  ``pace_to_subscribers``) and :class:`~.lockstep.Lockstep` (mixin: the short path);
* :mod:`.realtime`: :class:`~.realtime.Watchdog` and :class:`~.realtime.LagStop` (objects:
  an external controller's silence and its commands' lag) and :class:`~.realtime.RealTime`
  (mixin: pacing, the real-time warnings and stops);
* :mod:`.commands`: mixin, an external controller's commands checked, held or rejected;
* :mod:`.run_end`: :class:`~.run_end.RunEnd` (mixin: it reads every room's figures), the
  summary and ``run_end``, and :class:`~.run_end.Departure` (object: the flush and the
  linger);
* :mod:`.host_tuning`: a function, affinity, CPU latency, SCHED_FIFO;
* :mod:`.instrumentation`: ``profile:=1``, a hook over the node's own calls;
* :mod:`.codes`: the exit codes;
* :mod:`.fastpath`: optional, the lockstep FOM sample in compiled code, rcl called by
  address (:mod:`.fastpath.taking` is the node's side, a mixin).
"""
