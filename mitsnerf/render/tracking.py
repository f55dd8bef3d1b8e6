"""Free-flight tracking through a gridded medium under a coarse majorant grid (the pieces of ``mitsnerf_drt``).

The medium: an ``(R, R, R, C)`` grid (``C`` = 1, or 3 for a chromatic extinction), ``[z, y, x]``, filling the box
``[lo, lo + size]`` and looked up as Mitsuba's ``gridvolume`` does (trilinear, voxel ``i`` centred at
``(i + 0.5) / R``, indices clamped at the faces)::

    u = (p - lo) / size * R - 0.5,  i0 = floor(u),  f = u - i0
    v(p) = sum over the 8 corners c in {0, 1}^3 of prod_k (c_k f_k + (1 - c_k)(1 - f_k)) g[clamp(i0 + c)]

The majorant grid: ``M^3`` cells over the same box, cell ``m`` holding ``max(floor, MAJORANT_MARGIN x the
largest voxel that the trilinear lookup reads anywhere inside the cell)``, so ``sigma_bar(p) >= sigma_t(p)``
everywhere (a convex combination is at most its largest corner). Along a ray the majorant is then piecewise
constant, and the tentative collisions of delta and ratio tracking are a Poisson process of rate
``sigma_bar(t)``: a walk steps from cell to cell (a 3D DDA) and spends an exponential optical depth
``-log(1 - u)`` of majorant at each collision. Cells where every voxel is held at zero (``free`` false) keep
majorant 0 and are crossed in one step; elsewhere the floor keeps a rate > 0 where the density is 0, so that the
density there still gets a gradient.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np


def range_max(a: np.ndarray, axis: int, cells: int) -> np.ndarray:
    """``out[..., m, ...] = max of a[..., i, ...]`` over the voxels ``i`` that a trilinear lookup inside cell ``m``
    of ``cells`` equal cells reads along ``axis`` (length ``R``): ``floor(m R / M - 0.5)`` to
    ``floor((m + 1) R / M - 0.5) + 1``, clamped to ``[0, R - 1]``.

    >>> range_max(np.array([0., 5., 0., 0., 0., 0., 0., 1.]), 0, 2).tolist()   # cell 1 also reads voxel 3
    [5.0, 1.0]
    >>> range_max(np.array([0., 0., 0., 0., 2., 0., 0., 0.]), 0, 2).tolist()   # voxel 4 reaches into cell 0
    [2.0, 2.0]
    """
    r = a.shape[axis]
    out = []
    for m in range(cells):
        lo = max(int(np.floor(m * r / cells - 0.5)), 0)
        hi = min(int(np.floor((m + 1) * r / cells - 0.5)) + 1, r - 1)
        out.append(np.take(a, np.arange(lo, hi + 1), axis=axis).max(axis=axis))
    return np.stack(out, axis=axis)


#: The majorant's margin above the densest voxel a cell reads. Ratio tracking's factors ``1 - sigma_t / sigma_bar``
#: then stay >= 1 - 1 / MAJORANT_MARGIN (0.09): under a tight majorant (a constant start, where every cell's density
#: is its maximum) they are ~1e-5, the transmittance of a shadow ray is ~0 unless it meets no tentative point,
#: and its derivative ``-sum_i (1 / sigma_bar_i) prod_{j != i} (1 - r_j)`` is carried by the rare rays with a
#: single point: unbiased, but one camera seed in 16 held the gradient's whole variance on the default cloud
#: (docs/notes/mitsuba-inverse.md, "The estimators' gradient variance and time per step"). The cost: 10% more
#: tentative collisions where the majorant is tight.
MAJORANT_MARGIN = 1.1


def majorant_grid(sigma_t: np.ndarray, cells: int, floor: float, free: np.ndarray | None = None) -> np.ndarray:
    """The majorant ``(M, M, M)`` float32 of an extinction grid ``(R, R, R)`` or ``(R, R, R, C)`` (max over channels):
    per cell, ``max(floor, MAJORANT_MARGIN max_voxels_read)``; a cell none of whose read voxels is ``free``
    ((R, R, R) bool, None: all) keeps ``MAJORANT_MARGIN max_voxels_read`` without the floor.

    >>> g = np.zeros((4, 4, 4)); g[0, 0, 0] = 3.0
    >>> m = majorant_grid(g, 2, 0.5)
    >>> float(m[0, 0, 0]) > 3.0, float(m[1, 1, 1])
    (True, 0.5)
    >>> float(majorant_grid(g, 2, 0.5, free=g > 0)[1, 1, 1])          # frozen and empty: no floor
    0.0
    """
    g = np.asarray(sigma_t, dtype=np.float32)
    g = g.max(axis=-1) if g.ndim == 4 else g
    peak = g
    for axis in range(3):
        peak = range_max(peak, axis, cells)
    bound = peak * np.float32(MAJORANT_MARGIN)
    out = np.maximum(bound, np.float32(floor))
    if free is not None:
        reach = np.asarray(free, dtype=np.float32)
        for axis in range(3):
            reach = range_max(reach, axis, cells)
        out = np.where(reach > 0, out, bound)
    return np.ascontiguousarray(out, dtype=np.float32)


def trilinear(mi: Any, data, res: int, channels: int, p_local, active=True):
    """The grid ``data`` (flat, ``[z, y, x, c]``) at local points ``p_local`` in ``[0, 1]^3`` (Point3f): a Float
    (``channels`` = 1) or a Color3f (3); differentiable with respect to ``data``."""
    u = p_local * res - 0.5
    i0 = mi.Vector3i(dr.floor(u))
    f = u - mi.Vector3f(i0)
    lo = dr.clip(i0, 0, res - 1)
    hi = dr.clip(i0 + 1, 0, res - 1)
    kind = mi.Float if channels == 1 else mi.Color3f
    out = dr.zeros(kind)
    for c in range(8):
        cx, cy, cz = c & 1, (c >> 1) & 1, (c >> 2) & 1
        x = hi.x if cx else lo.x
        y = hi.y if cy else lo.y
        z = hi.z if cz else lo.z
        w = (f.x if cx else 1.0 - f.x) * (f.y if cy else 1.0 - f.y) * (f.z if cz else 1.0 - f.z)
        idx = mi.UInt32((z * res + y) * res + x)
        out += w * dr.gather(kind, data, idx, active)
    return out


@dataclass
class Walk:
    """The state of one walk along a ray through the majorant grid (a Dr.Jit PyTree: loop state)."""

    t: Any
    """Where the walk is (ray parameter)."""
    t_end: Any
    """Where it stops."""
    tau: Any
    """Majorant optical depth left before its next tentative collision."""
    cell: Any
    """Vector3i: the majorant cell it is in."""
    t_next: Any
    """Vector3f: where it crosses the cell's next face along each axis."""
    dt: Any
    """Vector3f: the ray parameter between two faces along each axis."""
    step: Any
    """Vector3i: +1 or -1 per axis."""


def walk_start(mi: Any, o, d, t0, t1, lo, size, cells: int, tau) -> Walk:
    """A walk of ``o + t d`` from ``t0`` to ``t1`` (both inside the box), spending ``tau`` before its first
    collision. Cell coordinates ``q(t) = (o + t d - lo) / size * M``; along each axis the next face is crossed at
    ``t_next`` and then every ``dt = 1 / |dq/dt|``."""
    q0 = (o + t0 * d - lo) / size * cells
    dq = d / size * cells
    cell = dr.clip(mi.Vector3i(dr.floor(q0)), 0, cells - 1)
    positive = dq > 0
    face = mi.Vector3f(cell) + dr.select(positive, 1.0, 0.0)
    rdq = dr.rcp(dq)
    t_next = dr.select(dq != 0, t0 + (face - q0) * rdq, dr.inf)
    dt = dr.select(dq != 0, dr.abs(rdq), dr.inf)
    step = dr.select(positive, mi.Vector3i(1), mi.Vector3i(-1))
    return Walk(mi.Float(t0), mi.Float(t1), mi.Float(tau), cell, t_next, dt, step)


def walk_step(mi: Any, w: Walk, majorant, cells: int, active):
    """One step of ``w``: to its next tentative collision if it lies in the current cell, else to the next cell
    (in place). Returns ``(hit, sigma_bar, done)``: a collision at ``w.t`` with majorant ``sigma_bar`` (its
    ``tau`` is then spent: draw the next), and whether the walk has reached ``t_end``."""
    flat = mi.UInt32((w.cell.z * cells + w.cell.y) * cells + w.cell.x)
    sigma_bar = dr.gather(mi.Float, majorant, flat, active)
    t_cell = dr.minimum(dr.minimum(dr.minimum(w.t_next.x, w.t_next.y), w.t_next.z), w.t_end)
    need = sigma_bar * dr.maximum(t_cell - w.t, 0.0)
    hit = active & (w.tau < need)
    move = active & ~hit
    w.t = dr.select(hit, w.t + w.tau / sigma_bar, dr.select(move, t_cell, w.t))
    w.tau = dr.select(hit, 0.0, dr.select(move, w.tau - need, w.tau))
    ax = (w.t_next.x <= w.t_next.y) & (w.t_next.x <= w.t_next.z)
    ay = ~ax & (w.t_next.y <= w.t_next.z)
    az = ~ax & ~ay
    for axis, m in ((0, ax), (1, ay), (2, az)):
        adv = move & m
        w.cell[axis] = dr.select(adv, w.cell[axis] + w.step[axis], w.cell[axis])
        w.t_next[axis] = dr.select(adv, w.t_next[axis] + w.dt[axis], w.t_next[axis])
    outside = dr.any((w.cell < 0) | (w.cell >= cells))
    done = move & ((t_cell >= w.t_end) | outside)
    return hit, sigma_bar, done


def exponential(u):
    """``-log(1 - u)``: an Exp(1) optical depth from a uniform ``u`` in [0, 1)."""
    return -dr.log(1.0 - u)
