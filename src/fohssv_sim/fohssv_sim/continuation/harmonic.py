"""Periodic orbits of commensurate fractional-order systems D^alpha x = f(x, p) by harmonic
balance with alternating frequency-time (AFT) evaluation of f.

A Caputo system started at a fixed time has no exactly periodic solution; its solutions tend
to the periodic solutions of the same system with the derivative taken over the whole past
(Liouville-Weyl), for which D^alpha e^{i k w t} = (i k w)^alpha e^{i k w t} and the derivative
of a constant is zero. Writing each state as a truncated Fourier series

    x(t) = X_0 + sum_{k=1..H} (a_k cos k w t + b_k sin k w t),

the balance of harmonics 0..H is, with X_k = (a_k - i b_k)/2 and F_k the same coefficients
of f(x(t)) (from f at N equally spaced times, by FFT: the AFT step),

    (i k w)^alpha X_k - F_k = 0,      k = 0..H,

real and imaginary parts: n (2H + 1) real equations. The frequency w is unknown; the phase is
fixed by b_1 = 0 for the state ``phase_state`` (that coefficient is dropped from the unknowns),
so the unknowns u = (coefficients without that one, w) are n (2H + 1) as well. At alpha = 1
this is classical harmonic balance of an ODE.

Truncation: the method is exact for a system whose f maps H-harmonic signals into H-harmonic
signals (linear systems, the Hopf normal form); otherwise the error falls as H grows, fast
for smooth f. :func:`converge_harmonics` doubles H until the frequency stops changing.

Hopf points: where a branch's amplitude tends to zero. :func:`hopf_point` fixes the first
harmonic of the phase state at a small amplitude, solves for the parameter instead, and
extrapolates p(A) = p_H + c A^2 to A = 0.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .driver import ContinuationError, newton
from .monodromy import dde_multipliers, stage_slopes
from .shooting import floquet_tests

__all__ = ['HarmonicBalance', 'hopf_point', 'converge_harmonics', 'initial_guess']

Rhs = Callable[[np.ndarray, float], np.ndarray]


@dataclass
class HarmonicBalance:
    """The harmonic-balance problem of D^order(p) x = rhs(X, p) (``rhs`` maps an (n, N) array
    of states at N times to their derivatives), H harmonics, N = ``samples`` time points."""

    rhs: Rhs
    dim: int
    harmonics: int
    order: Callable[[float], float]
    phase_state: int = 0
    samples: int = 0
    #: the delay tau(p) of a delay-differential system: ``rhs(X, p, X_delayed)`` then gets
    #: the states at t - tau too (their coefficients rotated by k omega tau)
    delay: Callable[[float], float] | None = None
    #: ``switch(x, p, xd)``: values whose sign changes where rhs's formula changes (a kink)
    switch: Callable[[np.ndarray, float, np.ndarray], np.ndarray] | None = None

    def __post_init__(self) -> None:
        self.samples = max(self.samples, 4 * self.harmonics + 4)
        #: index in u of a_1 of the phase state (its first-harmonic amplitude)
        self.amplitude_index = self.dim + self.phase_state
        self._drop = 2 * self.dim + self.phase_state     # b_1 of the phase state

    # -- packing ---------------------------------------------------------------------------
    def coefficients(self, u: np.ndarray) -> np.ndarray:
        """(n, 2H + 1) real coefficients [X_0, a_1, b_1, ..., a_H, b_H] per state from u."""
        c = np.insert(np.asarray(u[:-1], dtype=float), self._drop, 0.0)
        return c.reshape(2 * self.harmonics + 1, self.dim).T

    def pack(self, coefficients: np.ndarray, omega: float) -> np.ndarray:
        c = np.asarray(coefficients, dtype=float).T.ravel()
        return np.append(np.delete(c, self._drop), omega)

    def signal(self, u: np.ndarray, count: int | None = None, lag: float = 0.0) -> np.ndarray:
        """x at ``count`` equally spaced times over one period, shape (n, count); with ``lag``
        (s), x at those times minus ``lag``."""
        count = count or self.samples
        c = self.coefficients(u)
        H = self.harmonics
        if lag:
            phi = np.arange(1, H + 1) * float(u[-1]) * lag
            a, b = c[:, 1::2].copy(), c[:, 2::2].copy()
            c[:, 1::2] = a * np.cos(phi) - b * np.sin(phi)
            c[:, 2::2] = a * np.sin(phi) + b * np.cos(phi)
        spec = np.zeros((self.dim, count // 2 + 1), dtype=complex)
        spec[:, 0] = c[:, 0] * count
        spec[:, 1:H + 1] = (c[:, 1::2] - 1j * c[:, 2::2]) * count / 2.0
        return np.fft.irfft(spec, n=count, axis=1)

    def evaluate(self, u: np.ndarray, p: float, x: np.ndarray | None = None,
                 xd: np.ndarray | None = None) -> np.ndarray:
        """The right-hand side at the N sample times (at the states ``x`` / delayed states
        ``xd`` if given, else those of u)."""
        x = self.signal(u, self.samples) if x is None else x
        if self.delay is None:
            return self.rhs(x, p)
        xd = self.signal(u, self.samples, self.delay(p)) if xd is None else xd
        return self.rhs(x, p, xd)

    def residual(self, u: np.ndarray, p: float) -> np.ndarray:
        H, N = self.harmonics, self.samples
        omega = float(u[-1])
        c = self.coefficients(u)
        X = np.empty((self.dim, H + 1), dtype=complex)
        X[:, 0] = c[:, 0]
        X[:, 1:] = (c[:, 1::2] - 1j * c[:, 2::2]) / 2.0
        F = np.fft.rfft(self.evaluate(u, p), axis=1)[:, :H + 1] / N
        k = np.arange(H + 1)
        D = np.zeros(H + 1, dtype=complex)
        D[1:] = (1j * k[1:] * omega) ** self.order(p)
        R = D * X - F
        out = np.empty((2 * H + 1, self.dim))
        out[0] = R[:, 0].real
        out[1::2] = R[:, 1:].real.T
        out[2::2] = R[:, 1:].imag.T
        return out.ravel()

    def amplitude(self, u: np.ndarray) -> float:
        """First-harmonic amplitude of the phase state (its a_1; b_1 = 0)."""
        return abs(float(u[self.amplitude_index]))

    def valid(self, previous: np.ndarray, u: np.ndarray) -> bool:
        """Refuse a step that collapses the orbit: the constant solutions solve the balance
        for every omega (a degenerate family the corrector can fall onto)."""
        return self.amplitude(u) > 0.25 * self.amplitude(previous)

    def scale(self, state_scale: np.ndarray, omega: float, p_scale: float) -> np.ndarray:
        """The ``scale`` of :func:`.driver.continue_branch`: each coefficient by its state's
        typical size, omega and p by theirs."""
        c = np.tile(np.asarray(state_scale, dtype=float)[:, None], 2 * self.harmonics + 1)
        return np.append(self.pack(c, omega), p_scale)

    def jacobian(self, u: np.ndarray, p: float) -> np.ndarray:
        """dR/d(u, p). The coefficient columns are exact in the Fourier algebra: with Phi the
        synthesis basis (N x (2H + 1)) and E its analysis inverse, the coefficients of f_i
        move with those of x_j by E diag(df_i/dx_j(t)) Phi (df/dx at the N times by central
        differences); omega and p by central differences of the residual."""
        n, H, N = self.dim, self.harmonics, self.samples
        M = 2 * H + 1
        x = self.signal(u, N)
        theta = 2.0 * np.pi * np.arange(N) / N
        k = np.arange(1, H + 1)
        Phi = np.ones((N, M))
        Phi[:, 1::2] = np.cos(np.outer(theta, k))
        Phi[:, 2::2] = np.sin(np.outer(theta, k))
        E = Phi.T * (2.0 / N)
        E[0] /= 2.0
        G = _sandwich(E, self._slopes(u, p, x, None), Phi)
        if self.delay is not None:     # the delayed states: the basis at t - tau
            lagged = theta - float(u[-1]) * self.delay(p)
            Phi_d = np.ones((N, M))
            Phi_d[:, 1::2] = np.cos(np.outer(lagged, k))
            Phi_d[:, 2::2] = np.sin(np.outer(lagged, k))
            xd = self.signal(u, N, self.delay(p))
            G += _sandwich(E, self._slopes(u, p, x, xd), Phi_d)
        sign = np.full(M, -0.5)
        sign[0] = -1.0
        sign[2::2] = 0.5
        J = (sign[:, None, None, None] * G).reshape(M * n, M * n)
        D = (1j * k * float(u[-1])) ** self.order(p)
        for kk in range(1, H + 1):
            dr, di = D[kk - 1].real / 2.0, D[kk - 1].imag / 2.0
            for i in range(n):
                re, im = (2 * kk - 1) * n + i, 2 * kk * n + i
                J[re, re] += dr
                J[re, im] += di
                J[im, re] += di
                J[im, im] -= dr
        J = np.delete(J, self._drop, axis=1)
        d = 1e-7 * max(1.0, abs(float(u[-1])))
        up, um = u.copy(), u.copy()
        up[-1] += d
        um[-1] -= d
        d_omega = (self.residual(up, p) - self.residual(um, p)) / (2.0 * d)
        d = 1e-7 * max(1.0, abs(p))
        d_p = (self.residual(u, p + d) - self.residual(u, p - d)) / (2.0 * d)
        return np.column_stack([J, d_omega, d_p])

    def _slopes(self, u: np.ndarray, p: float, x: np.ndarray, xd: np.ndarray | None
                ) -> np.ndarray:
        """df_i/dx_j (n, n, N) at the sample times by central differences: with respect to
        the current states, or with ``xd`` to the delayed ones."""
        n = self.dim
        out = np.empty((n, n, x.shape[1]))
        moved = x if xd is None else xd
        for j in range(n):
            d = 1e-7 * max(1.0, float(np.max(np.abs(moved[j]))))
            plus, minus = moved.copy(), moved.copy()
            plus[j] += d
            minus[j] -= d
            if xd is None:
                f1, f2 = self.evaluate(u, p, plus), self.evaluate(u, p, minus)
            else:
                f1, f2 = self.evaluate(u, p, x, plus), self.evaluate(u, p, x, minus)
            out[:, j] = (f1 - f2) / (2.0 * d)
        return out

    def monitors(self, u: np.ndarray, p: float) -> dict[str, float]:
        """A delayed system's Floquet test functions (:func:`.shooting.floquet_tests` of
        :meth:`multipliers`, kept for :meth:`stability`); none for an ODE or FOM."""
        if self.delay is None:
            return {}
        mu = self.multipliers(u, p)
        self._multipliers = (np.asarray(u, dtype=float).tobytes(), float(p), mu)
        return floquet_tests(mu[1:])

    def stability(self, u: np.ndarray, p: float) -> tuple[bool | None, np.ndarray | None]:
        """(stable, multipliers) of a delayed system's orbit (the last monitored ones when at
        the same point); (None, None) for a system without delay (harmonic balance gives no
        multipliers)."""
        if self.delay is None:
            return None, None
        got = getattr(self, '_multipliers', None)
        if got is not None and got[0] == np.asarray(u, dtype=float).tobytes() and \
                got[1] == float(p):
            mu = got[2]
        else:
            mu = self.multipliers(u, p)
        return bool(np.max(np.abs(mu[1:])) < 1.0), mu

    def values(self, u: np.ndarray, times: np.ndarray) -> np.ndarray:
        """x at the given times (s), shape (n, len(times)), from the Fourier series."""
        c = self.coefficients(u)
        phase = np.outer(np.arange(1, self.harmonics + 1), float(u[-1]) * np.asarray(times))
        return c[:, :1] + c[:, 1::2] @ np.cos(phase) + c[:, 2::2] @ np.sin(phase)

    def multipliers(self, u: np.ndarray, p: float, steps: int = 256) -> np.ndarray:
        """Floquet multipliers of a delayed system's orbit u (the one nearest 1 first), from
        the monodromy operator discretised on ``steps`` RK4 steps per period
        (:mod:`.monodromy`), linearised about the orbit's Fourier series; with ``switch``,
        grid nodes on its sign changes (found on 4096 samples, linearly interpolated)."""
        if self.delay is None:
            raise ValueError('multipliers: only for a delay-differential system')
        tau = self.delay(p)
        T = 2.0 * np.pi / float(u[-1])

        def coefficients(times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            x, xd = self.values(u, times), self.values(u, times - tau)
            return stage_slopes(lambda a, b: self.rhs(a, p, b), x, xd)

        breaks: np.ndarray = np.zeros(0)
        if self.switch is not None:
            t = T * np.arange(4097) / 4096
            g = self.switch(self.values(u, t), p, self.values(u, t - tau))
            i = np.where(np.sign(g[:-1]) != np.sign(g[1:]))[0]
            breaks = t[i] + g[i] / (g[i] - g[i + 1]) * (t[i + 1] - t[i])
        return dde_multipliers(coefficients, self.dim, T, tau, steps, breaks)

    def frequency_hz(self, u: np.ndarray) -> float:
        return float(u[-1]) / (2.0 * np.pi)

    def with_harmonics(self, harmonics: int) -> HarmonicBalance:
        return HarmonicBalance(self.rhs, self.dim, harmonics, self.order, self.phase_state,
                               delay=self.delay, switch=self.switch)

    def resized(self, u: np.ndarray, harmonics: int) -> np.ndarray:
        """u of this problem as the unknowns of ``with_harmonics(harmonics)`` (zero-padded or
        truncated)."""
        c = self.coefficients(u)
        out = np.zeros((self.dim, 2 * harmonics + 1))
        m = min(c.shape[1], out.shape[1])
        out[:, :m] = c[:, :m]
        return self.with_harmonics(harmonics).pack(out, float(u[-1]))


def _sandwich(E: np.ndarray, slopes: np.ndarray, Phi: np.ndarray) -> np.ndarray:
    """G[r, i, m, j] = sum_t E[r, t] slopes[i, j, t] Phi[t, m] (as einsum 'rt,ijt,tm->rimj'),
    by one matrix product per factor (einsum's loop over all five indices costs 10x)."""
    n, N = slopes.shape[0], slopes.shape[2]
    left = E @ (slopes.transpose(2, 0, 1).reshape(N, n * n)[:, :, None] * Phi[:, None, :]
                ).reshape(N, -1)                                   # (r, (i j m))
    M = E.shape[0]
    return left.reshape(M, n, n, Phi.shape[1]).transpose(0, 1, 3, 2)


def initial_guess(problem: HarmonicBalance, equilibrium: np.ndarray, jacobian: np.ndarray,
                  alpha: float, amplitude: float) -> np.ndarray:
    """u for a small orbit about ``equilibrium`` along the eigenvector of ``jacobian`` whose
    eigenvalue lies nearest the Matignon boundary |arg lambda| = alpha pi / 2, scaled so the
    phase state's first harmonic is ``amplitude``; omega = |lambda|^(1/alpha)."""
    lam, vec = np.linalg.eig(jacobian)
    upper = np.where(lam.imag > 0)[0]
    if upper.size == 0:
        raise ContinuationError('the equilibrium has no complex eigenvalue: no Hopf point')
    j = upper[np.argmin(np.abs(np.angle(lam[upper]) - alpha * np.pi / 2.0))]
    v = vec[:, j] / vec[problem.phase_state, j] * amplitude   # phase state: real, = amplitude
    c = np.zeros((problem.dim, 2 * problem.harmonics + 1))
    c[:, 0] = equilibrium
    c[:, 1] = v.real
    c[:, 2] = -v.imag
    return problem.pack(c, abs(lam[j]) ** (1.0 / alpha))


def _at_amplitude(problem: HarmonicBalance, u: np.ndarray, p: float, amplitude: float,
                  tol: float) -> tuple[np.ndarray, float] | None:
    """Solve with the phase state's first harmonic fixed at ``amplitude`` and p free."""
    i = problem.amplitude_index

    def fun(y):
        uu = y.copy()
        uu[i] = amplitude
        return problem.residual(uu, y[i])

    y = np.array(u, dtype=float)
    y[i] = p
    def jac(y):
        uu = y.copy()
        uu[i] = amplitude
        J = problem.jacobian(uu, y[i])
        J[:, i] = J[:, -1]
        return J[:, :-1]

    got = newton(fun, jac, y, tol, 30)
    if got is None:
        return None
    y = got[0]
    out = y.copy()
    out[i] = amplitude
    return out, float(y[i])


def hopf_point(problem: HarmonicBalance, u: np.ndarray, p: float, amplitude: float,
               tol: float = 1e-14) -> tuple[float, np.ndarray, float, np.ndarray, float]:
    """``(p_H, u_A, p_A, u_2A, p_2A)``: the Hopf point by Richardson extrapolation of the
    parameter at first-harmonic amplitudes A and 2A of the phase state, and those two orbits
    (the first points of the branch leaving the Hopf point). ``tol`` bounds the residual:
    a small orbit fixes p only weakly (dR/dp ~ A), hence the tight default; Newton stops on
    its step size where round-off keeps the residual above it.

    Raises:
        ContinuationError: no orbit of that amplitude near the guess.
    """
    first = _at_amplitude(problem, u, p, amplitude, tol)
    if first is None:
        raise ContinuationError(f'no periodic orbit of amplitude {amplitude:g} near the '
                                f'guess p = {p:g}: harmonic balance did not converge')
    u1, p1 = first
    second = _at_amplitude(problem, u1, p1, 2.0 * amplitude, tol)
    if second is None:
        raise ContinuationError(f'no periodic orbit of amplitude {2 * amplitude:g} near '
                                f'p = {p1:g}: harmonic balance did not converge')
    u2, p2 = second
    return (4.0 * p1 - p2) / 3.0, u1, p1, u2, p2


def converge_harmonics(problem: HarmonicBalance, u: np.ndarray, p: float, *,
                       rtol: float = 1e-6, start: int = 4, most: int = 256, tol: float = 1e-9
                       ) -> tuple[HarmonicBalance, np.ndarray, list[tuple[int, float]]]:
    """Double the harmonic count from ``start`` until the frequency changes by less than
    ``rtol`` (relative) between two counts; ``(problem, u, [(H, frequency_hz), ...])`` at the
    last count.

    Raises:
        ContinuationError: no convergence of Newton, or of the frequency by ``most``.
    """
    H = start
    history: list[tuple[int, float]] = []
    current = problem.resized(u, H)
    while True:
        prob = problem.with_harmonics(H)
        got = newton(lambda v, prob=prob: prob.residual(v, p),
                     lambda v, prob=prob: prob.jacobian(v, p)[:, :-1],
                     current, tol, 30)
        if got is None:
            raise ContinuationError(f'harmonic balance with H = {H} did not converge at '
                                    f'p = {p:g}')
        current = got[0]
        history.append((H, prob.frequency_hz(current)))
        if len(history) > 1 and abs(history[-1][1] - history[-2][1]) <= rtol * abs(
                history[-1][1]):
            return prob, current, history
        if 2 * H > most:
            raise ContinuationError(f'the frequency did not converge to {rtol:g} with up to '
                                    f'{H} harmonics at p = {p:g}')
        current = prob.resized(current, 2 * H)
        H *= 2
