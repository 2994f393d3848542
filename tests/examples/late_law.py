"""A deliberately late controller for the tests: eq. 31 that takes ``answer_delay`` seconds of
wall time to answer each state, so at a short control period its commands fall further and
further behind a real-time plant (tests/test_graph_hosted.py), and a lockstep run lasts in
wall time with few samples (test_graph_support.late_controller). Registered for the tests as the
plugin ``late_law`` (a dist-info with an entry point, as ``pip install`` would make)."""

import time
from collections.abc import Sequence
from dataclasses import dataclass

from fohssv_sim.control import Controller
from fohssv_sim.params import ParameterSpec, spec_field, validate_fields


@dataclass(frozen=True)
class LateLawParameters:
    answer_delay: float = spec_field(ParameterSpec(
        'answer_delay', '-', 0.005, 's', 'wall time each answer takes', low=0.0,
        low_open=False, high=1.0, high_open=False, needs_reset=False))

    def __post_init__(self) -> None:
        validate_fields(self)


class LateLaw(Controller):
    """delta_c = 15 z - 30 theta - 0.3 q (eq. 31), answered ``answer_delay`` s late."""

    name = 'late_law'
    Parameters = LateLawParameters

    def update(self, t: float, state: Sequence[float]) -> tuple[float, float]:
        time.sleep(self.params.answer_delay)
        z, w, theta, q = state
        return 0.0, 15.0 * z - 30.0 * theta - 0.3 * q
