"""The physical domain of the model's state: |w| <= V, |theta| <= pi/2, and the error a state
beyond it raises (checked by the plants, the batch runner and the ROS plant, never inside the
compiled kernels' steps)."""

from __future__ import annotations

import math
from typing import Any

__all__ = ['MAX_PITCH', 'StateOutOfBounds', 'check_state']

#: Largest |theta| (rad) of a state the model describes: the nose pointing straight down or up.
MAX_PITCH = math.pi / 2


class StateOutOfBounds(FloatingPointError):
    """The state left the physical domain of the model although it is finite: |w| > V (the
    nose's vertical velocity above the forward speed, an angle of attack beyond 45 degrees,
    where the small-angle model no longer holds) or |theta| > pi/2. In practice this is a
    numerical blow-up (a step beyond the scheme's stability) or a vehicle out of control;
    either way the run is no longer a result. A ``FloatingPointError`` like the non-finite
    check, so whoever handles one handles both."""


def check_state(plant: Any) -> None:
    """Raise :class:`StateOutOfBounds` (and mark ``plant`` failed) when its state is beyond
    |w| <= V, |theta| <= pi/2. A few comparisons: the batch runner and the ROS plant call it
    once per control period (or per output sample), never inside the compiled kernels."""
    x = plant.x
    v = plant.params.speed
    if -v <= x[1] <= v and -MAX_PITCH <= x[2] <= MAX_PITCH:
        return
    plant.status = 'failed'
    raise StateOutOfBounds(
        f'state beyond physical bounds at t={plant.t:.9g} s: [z, w, theta, q] = '
        f'{[float(v) for v in x]} (|w| must stay <= V = {v:g} m/s and |theta| <= pi/2 rad; '
        f'step {plant.h:g} s: an unstable integration or a vehicle out of control)')
