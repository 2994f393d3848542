"""Write your own controller: a complete minimal example (the README shows it;
tests/test_graph_controllers.py runs it against the real plant; docs/controllers.md packages it).

Eq. 31 with a stronger pitch-rate term and fins that damp the pitch rate too. Run it as a node
without any packaging::

    python pitch_damper.py --ros-args -p pitch_damping:=0.6

or register it as a plugin in your package's setup.py and host it by name::

    entry_points={'fohssv.controllers': ['pitch_damper = pitch_damper:PitchDamper']}
    ros2 run fohssv_controller controller --ros-args -p controller:=pitch_damper
"""

from collections.abc import Sequence
from dataclasses import dataclass

from fohssv_sim.control import Controller
from fohssv_sim.params import ParameterSpec, spec_field, validate_fields


@dataclass(frozen=True)
class PitchDamperParameters:
    """Each field: name, symbol, default, unit, description, range; needs_reset=False makes it
    changeable on the running node (ros2 param set)."""

    pitch_damping: float = spec_field(ParameterSpec(
        'pitch_damping', '-', 0.6, 'rad s/rad', 'delta_c per rad/s of q (eq. 31 has 0.3)',
        low=0.0, low_open=False, high=10.0, high_open=False, needs_reset=False))
    fin_damping: float = spec_field(ParameterSpec(
        'fin_damping', '-', 0.05, 'rad s/rad', 'delta_f per rad/s of q',
        low=0.0, low_open=False, high=10.0, high_open=False, needs_reset=False))
    max_cavitator_deflection: float = spec_field(ParameterSpec(
        'max_cavitator_deflection', '-', 0.5, 'rad', '|delta_c| is clamped to this',
        low=0.0, high=1.5708, high_open=False, needs_reset=False))
    max_fin_deflection: float = spec_field(ParameterSpec(
        'max_fin_deflection', '-', 0.5, 'rad', '|delta_f| is clamped to this',
        low=0.0, high=1.5708, high_open=False, needs_reset=False))

    def __post_init__(self) -> None:
        validate_fields(self)


class PitchDamper(Controller):
    """delta_c = 15 z - 30 theta - pitch_damping q,  delta_f = -fin_damping q."""

    name = 'pitch_damper'
    Parameters = PitchDamperParameters

    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        z, w, theta, q = state
        p = self.params
        return -p.fin_damping * q, 15.0 * z - 30.0 * theta - p.pitch_damping * q


if __name__ == '__main__':
    from fohssv_controller.ros.controller_node import main

    main(default_controller=PitchDamper)
