"""The lockstep FOM sample in compiled code, rcl called by address (optional: the node keeps
its interpreted path where this cannot be built). :mod:`.sample` is the node's side,
:mod:`.entries` the compiled code."""
