"""Periodic orbits by continuation (pure: numpy and scipy, no rclpy).

* :mod:`.driver` -- pseudo-arclength continuation of F(u, p) = 0 with step control, folds and
  sign-change bifurcation tests;
* :mod:`.shooting` -- periodic orbits of ODEs (smooth or piecewise smooth) by shooting, Floquet
  multipliers from the monodromy matrix;
* :mod:`.harmonic` -- periodic orbits of fractional-order and delay-differential systems by
  harmonic balance (alternating frequency-time), where D^alpha e^{i w t} = (i w)^alpha
  e^{i w t} and x(t - tau) turns each harmonic by k w tau;
* :mod:`.vehicle` -- the vehicle's closed loop as fields and problems for the above;
* :mod:`.branch` -- the branch result, its JSON file and the bifurcation diagram;
* :mod:`.run` -- :func:`~.run.follow_orbits`, a branch of the vehicle's orbits for any of the
  three models (what ``fohssv continue`` runs).
"""
