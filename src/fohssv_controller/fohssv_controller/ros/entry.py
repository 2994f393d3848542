"""Entry points of the controller executables: a signal while the node still imports its
modules ends it quietly (see :mod:`fohssv_sim.ros.entry`)."""

from fohssv_sim.ros.entry import run

__all__ = ['controller', 'state_feedback', 'lqr', 'fractional_pid']

_NODE = 'fohssv_controller.ros.controller_node'
controller = run(_NODE)
state_feedback = run(_NODE, 'main_state_feedback')
lqr = run(_NODE, 'main_lqr')
fractional_pid = run(_NODE, 'main_fractional_pid')
