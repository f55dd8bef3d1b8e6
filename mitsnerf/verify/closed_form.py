"""Deterministic checks of the renderer's quadrature rules against formulas (no Monte Carlo).

Each check renders one ray along +z through the box (``t_n = 1.5``, ``t_f = 2.5``, ``L = 1``)
with :func:`mitsnerf.render.volume.render_rays` at stratum midpoints (``h = L / N``) and
compares with a closed form, for the seed's rule and for ``quadrature="midpoint"``:

1. Homogeneous box, several optical depths ``tau = sigma_t L``: with midpoints the seed's rule
   integrates exactly ``tau (1 - 1/(2N))`` (the last interval is ``h/2``), the midpoint rule
   exactly ``tau``; with ``T_N`` that value::

       T_N = exp(-tau_hat),   opacity = 1 - T_N,   C = c (1 - T_N) + bg T_N

2. Piecewise-constant density and colour, every interval inside one piece, so the
   quadrature is exact::

       T_N = exp(-sum_k s_k L_k),   C = sum_k T(z_k) (1 - exp(-s_k L_k)) c_k + T_N bg

   For the seed's rule the breaks are at stratum midpoints ``z_k = t_0 + k h`` (and
   ``sigma_t = 0`` on the first half interval); for the midpoint rule at stratum edges.

3. Order of convergence. Seed: ``tau_hat - tau = -(h/2) sigma_t(t_f) + O(h^2)``. For
   ``sigma_t(s) = A (1 - s)^2`` (``s`` the fraction of the way along the ray; zero at the exit)
   the error falls as ``h^2`` (observed order 2); for ``sigma_t(s) = A (1/2 + s)`` it falls as
   ``h`` with ``(tau_hat - tau) / h -> -sigma_t(t_f) / 2 = -3A/4``. Midpoint rule: for
   ``sigma_t(s) = A (1/2 + s)^2`` (dense at the exit) the error is ``-(h^2 / 24) int sigma_t''``,
   order 2.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from mitsnerf.math.box import UNIT_BOX
from mitsnerf.render.volume import render_rays
from mitsnerf.verify.cases import ClosedFormCase

RAY_O = (0.0, 0.0, -2.0)
RAY_D = (0.0, 0.0, 1.0)
L = 1.0


@dataclass(frozen=True)
class ClosedFormResult:
    """Largest relative error among the formula checks, observed orders, and what failed."""

    max_rel_error: float
    orders: dict[str, float]
    failures: tuple[str, ...]
    seconds: float

    @property
    def passed(self) -> bool:
        return not self.failures


def _ray():
    import mitsuba as mi

    return mi.Array3f(*RAY_O), mi.Array3f(*RAY_D)


def _fraction(x):
    """Fraction ``s`` of the way along the test ray at world point ``x`` (z from -0.5 to 0.5)."""
    return x.z + 0.5


def _render(field, n, background=0.0, quadrature="seed"):
    o, d = _ray()
    with dr.suspend_grad():
        out = render_rays(field, o, d, n, box=UNIT_BOX, background=background, quadrature=quadrature)
    rgb = np.array([np.asarray(c, dtype=np.float64)[0] for c in out.rgb])
    return rgb, float(np.asarray(out.T_final, dtype=np.float64)[0])


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12)))


def homogeneous(case: ClosedFormCase, n: int = 64, quadrature: str = "seed") -> list[tuple[str, float]]:
    """(label, relative error) of colour and transmittance for each optical depth (check 1)."""
    import mitsuba as mi

    c = np.array([0.2, 0.5, 0.9])
    bg = np.array([0.3, 0.6, 0.1])
    covered = 1.0 - 1.0 / (2 * n) if quadrature == "seed" else 1.0  # fraction of tau the rule integrates
    errors = []
    for tau in case.optical_depths:
        field = lambda x, d, s=tau / L: (mi.Array3f(*c.tolist()) + 0.0 * x.x, s + 0.0 * x.x)  # noqa: E731
        rgb, T = _render(field, n, mi.Array3f(*bg.tolist()), quadrature)
        T_exact = math.exp(-tau * covered)
        errors.append((f"{quadrature} tau={tau:g} T", _rel(T, T_exact)))
        errors.append((f"{quadrature} tau={tau:g} C", _rel(rgb, c * (1 - T_exact) + bg * T_exact)))
    return errors


def piecewise(n: int = 40, quadrature: str = "seed") -> list[tuple[str, float]]:
    """(label, relative error) of colour and transmittance through piecewise-constant pieces (check 2)."""
    import mitsuba as mi

    h = L / n
    if quadrature == "seed":
        # Pieces in units of h, starting at t_0 = h/2 (the half interval before it has sigma_t = 0).
        lengths, start = np.array([7, 5, 13, 9, 5.5]) * h, h / 2  # sums to 39.5 h = L - h/2
    else:
        lengths, start = np.array([7, 5, 13, 9, 6]) * h, 0.0  # whole strata: sums to 40 h = L
    sigma = np.array([2.0, 0.0, 0.7, 6.0, 1.5])
    colour = np.array([[1.0, 0.2, 0.1], [0.0, 0.0, 0.0], [0.2, 0.9, 0.3], [0.4, 0.4, 1.0], [0.8, 0.8, 0.8]])
    edges = start + np.concatenate([[0.0], np.cumsum(lengths)])  # as fractions s of the ray
    bg = np.array([0.25, 0.5, 0.75])

    def field(x, d):
        s = _fraction(x)
        sig = 0.0 * s
        col = [0.0 * s, 0.0 * s, 0.0 * s]
        for k in range(len(lengths)):
            inside = (s >= edges[k] - 1e-6) & (s < edges[k + 1] - 1e-6)
            sig = dr.select(inside, float(sigma[k]), sig)
            col = [dr.select(inside, float(colour[k, j]), col[j]) for j in range(3)]
        return mi.Array3f(*col), sig

    rgb, T = _render(field, n, mi.Array3f(*bg.tolist()), quadrature)
    tau = np.concatenate([[0.0], np.cumsum(sigma * lengths)])
    T_exact = math.exp(-tau[-1])
    C_exact = sum(math.exp(-tau[k]) * (1 - math.exp(-sigma[k] * lengths[k])) * colour[k] for k in range(len(lengths)))
    C_exact = C_exact + T_exact * bg
    return [(f"{quadrature} piecewise T", _rel(T, T_exact)), (f"{quadrature} piecewise C", _rel(rgb, C_exact))]


def _order(field, exact: float, ns, quadrature: str) -> tuple[float, np.ndarray]:
    """Observed order of the optical-depth error over ``ns``, and the errors."""
    errs = np.array([-math.log(_render(field, n, quadrature=quadrature)[1]) - exact for n in ns])
    mag = np.abs(errs)
    return float(np.mean(np.log2(mag[:-1] / np.maximum(mag[1:], 1e-30)))), errs


def convergence(amplitude: float = 3.0, ns=(8, 16, 32, 64)) -> dict[str, float]:
    """Observed orders and the first-order coefficient of the optical-depth error (check 3).

    Returns ``{"order_exit0": p, "order_linear": q, "coef_linear": (tau_hat - tau)/h at the
    largest N divided by its predicted limit -sigma_t(t_f)/2, "order_midpoint": r}``.
    """
    import mitsuba as mi

    A = amplitude
    exit0 = lambda x, d: (mi.Array3f(0.0), A * dr.square(1.0 - _fraction(x)))  # noqa: E731
    linear = lambda x, d: (mi.Array3f(0.0), A * (0.5 + _fraction(x)))  # noqa: E731
    dense_exit = lambda x, d: (mi.Array3f(0.0), A * dr.square(0.5 + _fraction(x)))  # noqa: E731
    out = {"order_exit0": _order(exit0, A / 3.0, ns, "seed")[0]}
    out["order_linear"], errs = _order(linear, A, ns, "seed")
    out["coef_linear"] = float(errs[-1] / (L / ns[-1]) / (-0.75 * A))
    out["order_midpoint"] = _order(dense_exit, A * 13.0 / 12.0, ns, "midpoint")[0]  # int_0^1 (1/2 + s)^2 = 13/12
    return out


EXPECTED_ORDERS = {"order_exit0": 2.0, "order_linear": 1.0, "coef_linear": 1.0, "order_midpoint": 2.0}


def run_closed_form(case: ClosedFormCase) -> ClosedFormResult:
    """All three checks for both rules; a failure is any formula off by more than ``case.rtol`` or an order off by
    ``order_tol``."""
    start = time.perf_counter()
    errors = []
    for quadrature in ("seed", "midpoint"):
        errors += homogeneous(case, quadrature=quadrature) + piecewise(quadrature=quadrature)
    failures = [f"{label}: relative error {err:.2e} > {case.rtol:g}" for label, err in errors if err > case.rtol]
    conv = convergence()
    for key, expected in EXPECTED_ORDERS.items():
        if not abs(conv[key] - expected) <= case.order_tol:
            failures.append(f"{key}: {conv[key]:.3f}, expected {expected:g} +/- {case.order_tol:g}")
    return ClosedFormResult(max(err for _, err in errors), conv, tuple(failures), time.perf_counter() - start)
