"""Linear time-invariant helpers: exact discretisation and the discrete algebraic Riccati equation.

Pure numpy (no SciPy in the project's environment). Shapes in the comments.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np

from roadbev_core.errors import RoadbevError

__all__ = ["LtiError", "discretise", "expm_integral", "solve_dare"]


class LtiError(RoadbevError, ValueError):
    """A system the helpers cannot handle (non-finite matrices, a Riccati equation that does not converge)."""


def expm_integral(A: np.ndarray, terms: int = 18) -> tuple[np.ndarray, np.ndarray]:
    """exp(A) and the integral of exp(A s) over s in [0, 1].

    Taylor series with scaling and squaring; A is a system matrix times a small step, so the
    series of the scaled matrix converges in a few terms.

    Args:
        A: [n, n].

    Returns:
        (exp(A) [n, n], integral [n, n]).
    """
    A = np.asarray(A, np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or not np.all(np.isfinite(A)):
        raise LtiError(f"need a finite square matrix, got shape {A.shape}")
    n = A.shape[0]
    squarings = max(0, int(math.ceil(math.log2(max(np.abs(A).sum(axis=1).max(), 1e-12)))) + 1)
    As = A / 2**squarings
    E, I_ = np.eye(n), np.eye(n)  # exp and its integral over [0, 1] at the scaled step
    term = np.eye(n)
    for k in range(1, terms):
        term = term @ As / k  # As^k / k!
        E = E + term
        I_ = I_ + term / (k + 1)
    h = 1.0 / 2**squarings
    integral = I_ * h
    for _ in range(squarings):  # int_0^{2h} = int_0^h + exp(Ah) int_0^h
        integral = integral + E @ integral
        E = E @ E
    return E, integral


def discretise(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretisation of x' = A x + B u at step ``dt``.

    Args:
        A: [n, n]; B: [n, m]; dt: step (s, > 0).

    Returns:
        (Phi [n, n], Gamma [n, m]) with x[k+1] = Phi x[k] + Gamma u[k] exactly for u held
        constant over the step.
    """
    if not (math.isfinite(dt) and dt > 0):
        raise LtiError(f"the time step must be positive, got {dt}")
    Phi, integral = expm_integral(np.asarray(A, np.float64) * dt)
    return Phi, integral * dt @ np.asarray(B, np.float64)


def solve_dare(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, N: np.ndarray | None = None,
               *, tol: float = 1e-12, max_iter: int = 100) -> np.ndarray:
    """The stabilising solution P of the discrete algebraic Riccati equation with a cross term.

    ``P = A'PA - (A'PB + N)(R + B'PB)^-1 (B'PA + N') + Q``, the cost
    ``sum x'Qx + 2 x'N u + u'R u``. Solved by the structure-preserving doubling algorithm
    (E. K.-W. Chu, H.-Y. Fan, W.-W. Lin, "A structure-preserving doubling algorithm for
    continuous-time algebraic Riccati equations", Linear Algebra Appl. 396, 2005; the
    discrete-time form: W.-W. Lin, S.-F. Xu, SIAM J. Matrix Anal. Appl. 28(1), 2006), after
    removing the cross term (A - B R^-1 N', Q - N R^-1 N').

    Args:
        A: [n, n]; B: [n, m]; Q: [n, n] symmetric >= 0; R: [m, m] symmetric > 0; N: [n, m].

    Raises:
        LtiError: when the iteration does not converge (no stabilising solution).
    """
    A, B, Q, R = (np.asarray(v, np.float64) for v in (A, B, Q, R))
    n, m = B.shape
    N = np.zeros((n, m)) if N is None else np.asarray(N, np.float64)
    Rinv = np.linalg.inv(R)
    Ak = A - B @ Rinv @ N.T
    Gk = B @ Rinv @ B.T
    Hk = Q - N @ Rinv @ N.T
    eye = np.eye(n)
    for _ in range(max_iter):
        W = np.linalg.solve(eye + Gk @ Hk, np.hstack([Ak, Gk]))  # (I + G H)^-1 [A, G]
        WA, WG = W[:, :n], W[:, n:]
        H_next = Hk + Ak.T @ Hk @ WA
        G_next = Gk + Ak @ WG @ Ak.T
        Ak = Ak @ WA
        if not np.all(np.isfinite(H_next)):
            raise LtiError("the Riccati iteration diverged (is (A, B) stabilisable?)")
        done = np.abs(H_next - Hk).max() <= tol * max(1.0, np.abs(H_next).max())
        Hk, Gk = H_next, G_next
        if done:
            P = 0.5 * (Hk + Hk.T)
            return cast("np.ndarray", P)
    raise LtiError(f"the Riccati iteration did not converge in {max_iter} doublings")
