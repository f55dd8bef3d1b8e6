"""Deterministic checks of the renderer's quadrature against formulas (case 1).

Each check renders one ray along +z through the box (``t_n = 1.5``, ``t_f = 2.5``, ``L = 1``)
with :func:`mitsnerf.render.volume.render_rays` at stratum midpoints (``h = L / N``) and
compares with a closed form. What is new here beyond tests/math/test_composite.py and
tests/render/test_volume.py is that the checks run through an injectable ``composite_fn``, so
the same code shows that the broken variants fail:

1. Homogeneous box, several optical depths ``tau = sigma_t L``: with midpoints the quadrature
   integrates exactly ``tau (1 - 1/(2N))`` (the last interval is ``h/2``), so::

       T_N = exp(-tau (1 - 1/(2N))),   opacity = 1 - T_N,   C = c (1 - T_N) + bg T_N

2. Piecewise-constant density and colour with breaks at stratum midpoints ``z_k = t_0 + k h``
   (and ``sigma_t = 0`` on the first half interval): every interval ``[t_i, t_{i+1}]`` lies in
   one piece, so the quadrature is exact::

       T_N = exp(-sum_k s_k L_k),   C = sum_k T(z_k) (1 - exp(-s_k L_k)) c_k + T_N bg

3. Order of convergence: ``tau_hat - tau = -(h/2) sigma_t(t_f) + O(h^2)``. For
   ``sigma_t(s) = A (1 - s)^2`` (``s`` the fraction of the way along the ray; zero at the exit)
   the error falls as ``h^2`` (observed order 2); for ``sigma_t(s) = A (1/2 + s)`` it falls as
   ``h`` with ``(tau_hat - tau) / h -> -sigma_t(t_f) / 2 = -3A/4``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from mitsnerf.math.composite import composite
from mitsnerf.render.volume import render_rays
from mitsnerf.verify.cases import ClosedFormCase
from mitsnerf.math.box import UNIT_BOX

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


def _render(field, n, composite_fn, background=0.0):
    o, d = _ray()
    with dr.suspend_grad():
        out = render_rays(field, o, d, n, background=background, composite_fn=composite_fn, box=UNIT_BOX)
    rgb = np.array([np.asarray(c, dtype=np.float64)[0] for c in out.rgb])
    return rgb, float(np.asarray(out.T_final, dtype=np.float64)[0])


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12)))


def homogeneous(case: ClosedFormCase, composite_fn=composite, n: int = 64) -> list[tuple[str, float]]:
    """(label, relative error) of colour and transmittance for each optical depth (check 1)."""
    import mitsuba as mi

    c = np.array([0.2, 0.5, 0.9])
    bg = np.array([0.3, 0.6, 0.1])
    errors = []
    for tau in case.optical_depths:
        field = lambda x, d, s=tau / L: (mi.Array3f(*c.tolist()) + 0.0 * x.x, s + 0.0 * x.x)  # noqa: E731
        rgb, T = _render(field, n, composite_fn, mi.Array3f(*bg.tolist()))
        T_exact = math.exp(-tau * (1.0 - 1.0 / (2 * n)))
        errors.append((f"tau={tau:g} T", _rel(T, T_exact)))
        errors.append((f"tau={tau:g} C", _rel(rgb, c * (1 - T_exact) + bg * T_exact)))
    return errors


def piecewise(composite_fn=composite, n: int = 40) -> list[tuple[str, float]]:
    """(label, relative error) of colour and transmittance through piecewise-constant pieces (check 2)."""
    import mitsuba as mi

    h = L / n
    # Pieces in units of h, starting at t_0 = h/2 (the half interval before it has sigma_t = 0).
    lengths = np.array([7, 5, 13, 9, 5.5]) * h  # sums to 39.5 h = L - h/2
    sigma = np.array([2.0, 0.0, 0.7, 6.0, 1.5])
    colour = np.array([[1.0, 0.2, 0.1], [0.0, 0.0, 0.0], [0.2, 0.9, 0.3], [0.4, 0.4, 1.0], [0.8, 0.8, 0.8]])
    edges = h / 2 + np.concatenate([[0.0], np.cumsum(lengths)])  # as fractions s of the ray
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

    rgb, T = _render(field, n, composite_fn, mi.Array3f(*bg.tolist()))
    tau = np.concatenate([[0.0], np.cumsum(sigma * lengths)])
    T_exact = math.exp(-tau[-1])
    C_exact = sum(math.exp(-tau[k]) * (1 - math.exp(-sigma[k] * lengths[k])) * colour[k] for k in range(len(lengths)))
    C_exact = C_exact + T_exact * bg
    return [("piecewise T", _rel(T, T_exact)), ("piecewise C", _rel(rgb, C_exact))]


def convergence(composite_fn=composite, amplitude: float = 3.0, ns=(8, 16, 32, 64)) -> dict[str, float]:
    """Observed orders and the first-order coefficient of the optical-depth error (check 3).

    Returns ``{"order_exit0": p, "order_linear": q, "coef_linear": (tau_hat - tau)/h at the
    largest N divided by its predicted limit -sigma_t(t_f)/2}``.
    """
    import mitsuba as mi

    A = amplitude
    quad = lambda x, d: (mi.Array3f(0.0), A * dr.square(1.0 - _fraction(x)))  # noqa: E731
    linear = lambda x, d: (mi.Array3f(0.0), A * (0.5 + _fraction(x)))  # noqa: E731
    out = {}
    for label, field, exact in (("exit0", quad, A / 3.0), ("linear", linear, A)):
        errs = []
        for n in ns:
            _, T = _render(field, n, composite_fn)
            errs.append(-math.log(T) - exact)
        errs = np.array(errs)
        mag = np.abs(errs)
        out[f"order_{label}"] = float(np.mean(np.log2(mag[:-1] / np.maximum(mag[1:], 1e-30))))
        if label == "linear":
            h = L / ns[-1]
            out["coef_linear"] = float(errs[-1] / h / (-0.75 * A))
    return out


def run_closed_form(case: ClosedFormCase, composite_fn=composite) -> ClosedFormResult:
    """All three checks; a failure is any formula off by more than ``case.rtol`` or an order off by ``order_tol``."""
    start = time.perf_counter()
    errors = homogeneous(case, composite_fn) + piecewise(composite_fn)
    failures = [f"{label}: relative error {err:.2e} > {case.rtol:g}" for label, err in errors if err > case.rtol]
    conv = convergence(composite_fn)
    for key, expected in (("order_exit0", 2.0), ("order_linear", 1.0), ("coef_linear", 1.0)):
        if not abs(conv[key] - expected) <= case.order_tol:
            failures.append(f"{key}: {conv[key]:.3f}, expected {expected:g} +/- {case.order_tol:g}")
    return ClosedFormResult(max(err for _, err in errors), conv, tuple(failures), time.perf_counter() - start)
