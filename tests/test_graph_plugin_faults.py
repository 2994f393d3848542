"""A plugin whose constructor raises, in a node process: one line naming it, exit 2, no
traceback (the plant hosting it and the controller node)."""

from __future__ import annotations

import pytest
from faulty_plugins import register
from test_graph_support import finish

import rosproc

pytestmark = pytest.mark.graph


@pytest.mark.parametrize(('package', 'executable'), [('fohssv_sim', 'plant'),
                                                     ('fohssv_controller', 'controller')])
def test_a_constructor_that_raises_is_one_line_and_exit_2(tmp_path, package, executable):
    env = rosproc.ros_env()
    env['PYTHONPATH'] = f"{register(tmp_path)}:{env.get('PYTHONPATH', '')}"
    proc = rosproc.start(package, executable, ['--ros-args', '-p', 'controller:=bad_init'],
                         env=env)
    code, out = finish(proc, 30)
    assert code == 2, out
    assert ("controller 'bad_init' could not be built: its constructor raised RuntimeError: "
            'no gains file') in out
    assert 'Traceback' not in out, out
