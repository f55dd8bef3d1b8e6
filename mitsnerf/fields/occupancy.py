"""An occupancy grid: which parts of the box hold medium, to skip empty space and stop rays early.

As in instant-ngp and nerfacc, a coarse ``R^3`` grid over the scene box keeps a
running estimate of each cell's largest density, refreshed every ``update_every``
training steps by evaluating the field at one jittered point per cell::

    s_c      = sigma(x_c + (u - 1/2) h)              h = cell size, u ~ U[0, 1)^3
    rho_c   <- max(decay * rho_c, s_c)               (an exponentially forgotten maximum)
    occ_c    = rho_c >= min(threshold, mean_c rho_c)
    occ      = dilate(occ)                           (a cell next to an occupied one is occupied)

instant-ngp forgets with ``decay = 0.95`` every 16 steps over tens of thousands of
GPU steps; a CPU run here has about a thousand, and a cell whose density fell from
the initial ~1 must drop below the threshold within a hundred steps or so, hence the
defaults ``decay = 0.6`` every 8 steps (a factor 100 in 9 updates, 72 steps); the
dilation, not the memory, is what keeps the grid conservative.

What skipping costs, exactly: zeroing sigma on a set S of a ray's samples moves its colour by
at most ``(1 - exp(-tau_S)) * (c_max - c_min)``, ``tau_S`` the optical depth of the skipped
samples and ``[c_min, c_max]`` the range of the colours and the background (the two renders
differ only when a sample of S would have absorbed; tests/fields/test_occupancy.py checks the
bound). Skipping cells below the threshold makes ``tau_S <= threshold * chord``, and only where
the medium is that thin all along the ray: on
the default cloud (sigma_t up to 30) the grid of its true density at the default
threshold 0.5 leaves 5% of the samples of the test views and renders them 90 dB from
the full render, while a learned field's faint haze (which a lower threshold keeps
evaluating: 65% of samples after 120 steps at 0.05, 27% at 0.5) is skipped. The network
is trained with the same skipping, so it does not learn on, or need, haze there. The
``min(threshold, mean)`` rule lowers the threshold for thin media.

The dilation by one cell makes the grid conservative: on a smooth field, every point
whose true density exceeds the threshold lies in, or next to, a cell where a
jittered sample found it (tests/fields/test_occupancy.py checks this on a
ground-truth grid).

The renderer then evaluates the network only where it matters (:meth:`OccupancyGrid.sample_mask`):
samples in occupied cells whose transmittance, estimated from the grid's own densities
``T_i ~ exp(-sum_{j<i} rho(x_j) delta_j)``, is still above ``early_stop_T``.
:func:`eval_masked` compacts those samples (``dr.compress``), evaluates the field on
them only, and scatters the results back; the others get ``sigma = 0``.

Before its first update the grid marks every cell occupied and estimates no
extinction (nothing is skipped).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import drjit as dr
import numpy as np

from mitsnerf.config import check_fields, param
from mitsnerf.math.box import Box
from mitsnerf.math.composite import is_chromatic

_STREAM = 0x9E3779B97F4A7C15


@dataclass(frozen=True)
class OccupancyConfig:
    """Settings of the occupancy grid."""

    resolution: int = param(64, lo=2, hi=512)
    """Cells per axis R (the grid is R^3)."""
    update_every: int = param(8, lo=1)
    """Training steps between updates."""
    decay: float = param(0.6, lo=0.0, hi=1.0)
    """Factor applied to each cell's kept maximum at each update."""
    threshold: float = param(0.5, lo=0.0)
    """Density (1/length) above which a cell counts as occupied (lowered to the grid's mean for thin media)."""
    dilate: int = param(1, lo=0)
    """Cells by which occupancy is grown (0: none)."""
    early_stop_T: float = param(1e-4, lo=0.0, hi=1.0, hi_open=True)
    """Samples behind this estimated transmittance are skipped (0: off)."""

    def __post_init__(self) -> None:
        check_fields(self)


class OccupancyGrid:
    """The grid's state (``rho``: Float (R^3,), ``occupied``: Bool (R^3,), indexed [z, y, x]).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> grid = OccupancyGrid(OccupancyConfig(resolution=4), mi.Float, UNIT_BOX)
    >>> grid.update(lambda x: dr.select(x.x > 0.0, 5.0, 0.0) + 0.0 * x.y, seed=0, step=0)
    >>> grid.occupied_fraction()  # half the box holds medium, dilated by one cell
    0.75
    >>> grid.is_occupied(mi.Array3f([-0.4, 0.4], 0.0, 0.0))
    [False, True]
    """

    def __init__(self, config: OccupancyConfig, Float, box: Box) -> None:
        self.config = config
        self.Float = Float
        self.UInt32 = dr.uint32_array_t(Float)
        self.Bool = dr.mask_t(Float)
        self.Array3f = sys.modules[Float.__module__].Array3f
        self.box = box
        n = config.resolution**3
        self.rho = dr.zeros(Float, n)
        self.occupied = dr.full(self.Bool, True, n)
        self.updates = 0

    # -- lookups -----------------------------------------------------------------

    def cell_index(self, x):
        """Flat index ``(k R + j) R + i`` of the cell holding each point (clamped to the grid)."""
        R = self.config.resolution
        p = self.box.to_unit(dr.detach(x))
        i = dr.clip(self.UInt32(dr.clip(p.x * R, 0.0, R - 1)), 0, R - 1)
        j = dr.clip(self.UInt32(dr.clip(p.y * R, 0.0, R - 1)), 0, R - 1)
        k = dr.clip(self.UInt32(dr.clip(p.z * R, 0.0, R - 1)), 0, R - 1)
        return (k * R + j) * R + i

    def is_occupied(self, x):
        """Bool (M,): whether each point lies in an occupied cell."""
        return dr.gather(self.Bool, self.occupied, self.cell_index(x))

    def density_estimate(self, x):
        """Float (M,): the grid's density estimate ``rho`` of the cell holding each point."""
        return dr.gather(self.Float, self.rho, self.cell_index(x))

    def occupied_fraction(self) -> float:
        """Share of cells marked occupied."""
        return float(dr.mean(self.Float(self.occupied))[0])

    def sample_mask(self, x, delta, n: int):
        """Bool (R*N,): samples worth evaluating (occupied cell, estimated ``T_i > early_stop_T``).

        ``x``, ``delta``: the samples' positions and interval lengths, N per ray (flat, ray-major).
        """
        keep = self.is_occupied(x) & (delta > 0.0)
        T_min = self.config.early_stop_T
        if T_min > 0.0 and self.updates > 0:
            tau = dr.block_prefix_sum(self.density_estimate(x) * dr.detach(delta), n, exclusive=True)
            keep &= tau < -math.log(T_min)
        return keep

    def stop_depth(self) -> float | None:
        """The estimated optical depth from which :meth:`sample_mask` keeps nothing more on a ray (early
        stopping), or None when it does not stop rays."""
        T_min = self.config.early_stop_T
        return -math.log(T_min) if T_min > 0.0 and self.updates > 0 else None

    def march_keep(self, x, delta, tau):
        """:meth:`sample_mask` for one sample of each ray inside a march: ``(keep, tau')``.

        ``tau`` is the grid's optical-depth estimate in front of the sample (the exclusive prefix sum of
        :meth:`sample_mask`, carried by the loop from 0); ``tau' = tau + rho(x) delta``. ``x``, ``delta``:
        Array3f (R,), Float (R,)."""
        keep = self.is_occupied(x) & (delta > 0.0)
        stop = self.stop_depth()
        if stop is not None:
            keep &= tau < stop
            tau = tau + self.density_estimate(x) * dr.detach(delta)
        return keep, tau

    # -- updates -----------------------------------------------------------------

    def cell_points(self, seed: int, step: int, jitter: bool = True):
        """One point per cell (Array3f (R^3,)): its centre, or uniformly jittered inside it."""
        R = self.config.resolution
        idx = dr.arange(self.UInt32, R**3)
        i = idx % R
        j = (idx // R) % R
        k = idx // (R * R)
        Float = self.Float
        if jitter:
            # a stream of its own, apart from the trainer's (seed, step) generator
            rng = dr.rng(seed=((int(seed) & 0xFFFFFFFF) << 32 | (int(step) & 0xFFFFFFFF)) ^ _STREAM)
            u = [rng.random(Float, R**3) for _ in range(3)]
        else:
            u = [dr.full(Float, 0.5, R**3)] * 3
        return self.box.from_unit(self.Array3f(*((Float(c) + u[a]) / R for a, c in enumerate((i, j, k)))))

    def update(self, density: Callable[[Any], Any], seed: int, step: int, chunk: int = 1 << 18) -> None:
        """Refresh the grid from ``density(x) -> Float`` (evaluated without gradients, in chunks)."""
        cfg = self.config
        n = cfg.resolution**3
        points = self.cell_points(seed, step)
        dr.eval(points)
        with dr.suspend_grad():
            sigma = dr.zeros(self.Float, n)
            for start in range(0, n, chunk):
                idx = dr.arange(self.UInt32, start, min(n, start + chunk))
                s = density(dr.gather(self.Array3f, points, idx))
                if is_chromatic(s):  # one density per colour: a cell is empty only if every channel is
                    s = dr.maximum(dr.maximum(s[0], s[1]), s[2])
                dr.scatter(sigma, dr.detach(s), idx)
                dr.eval(sigma)
            rho = dr.maximum(cfg.decay * self.rho, dr.maximum(sigma, 0.0))
            # min(threshold, mean) stays on the device: a Python float would be a new literal,
            # and so a new kernel to compile, at every update
            # (>=: a uniform field, e.g. at initialisation, stays occupied)
            occupied = rho >= dr.minimum(dr.opaque(self.Float, cfg.threshold), dr.mean(rho))
            for _ in range(cfg.dilate):
                occupied = self._dilate(occupied)
            dr.eval(rho, occupied)
        self.rho = rho
        self.occupied = occupied
        self.updates += 1

    def _dilate(self, occ):
        """Grow a Bool (R^3,) grid by one cell along each axis (a 3x3x3 max filter, separably)."""
        R = self.config.resolution
        idx = dr.arange(self.UInt32, R**3)
        coord = [idx % R, (idx // R) % R, idx // (R * R)]
        for axis, stride in enumerate((1, R, R * R)):
            c = coord[axis]
            lo = dr.gather(self.Bool, occ, idx - stride, c > 0)
            hi = dr.gather(self.Bool, occ, idx + stride, c + 1 < R)
            occ = occ | lo | hi
            dr.eval(occ)
        return occ

    # -- checkpoints -------------------------------------------------------------

    def state(self) -> dict:
        """The grid's state for a checkpoint: the current arrays themselves (no copy; :meth:`update`
        replaces them rather than writing into them, so the values stay those of this moment)."""
        return {"occupancy.rho": self.rho, "occupancy.occupied": self.occupied,
                "occupancy.updates": np.asarray(self.updates, dtype=np.int64)}

    def load_state(self, state) -> None:
        n = self.config.resolution**3
        rho = np.asarray(state["occupancy.rho"], dtype=np.float32).ravel()
        if rho.size != n:
            raise ValueError(f"occupancy.rho: {rho.size} cells, expected {n} (resolution {self.config.resolution})")
        self.rho = self.Float(rho)
        self.occupied = self.Bool(np.asarray(state["occupancy.occupied"], dtype=bool).ravel())
        self.updates = int(np.asarray(state.get("occupancy.updates", 1)))


def padded_size(k: int, steps_per_octave: int = 8, multiple: int = 256) -> int:
    """``k`` rounded up to one of a few sizes: ``2^(j / steps_per_octave)``, then to a multiple of ``multiple``.

    Kernels over tensors of a compacted batch embed its size; rounding it up to one of
    about 8 sizes per octave lets Dr.Jit reuse compiled kernels (each new size costs
    ~150 ms of compilation in the ngp field) at under 10% of padding.

    >>> [padded_size(k) for k in (1, 1000, 70000, 70001)]
    [256, 1024, 71680, 71680]
    """
    if k <= 0:
        return 0
    j = math.ceil(steps_per_octave * math.log2(k) - 1e-9)
    size = math.ceil(2.0 ** (j / steps_per_octave))
    return max(multiple, -(-max(size, k) // multiple) * multiple)


def eval_masked(field: Callable[[Any, Any], tuple[Any, Any]], x, d, mask, pad: bool = True):
    """Evaluate ``field(x, d) -> (rgb, sigma)`` only where ``mask``; zeros elsewhere.

    The active samples are compacted (``dr.compress``: one synchronisation), gathered,
    evaluated, and scattered back into zero-filled outputs, so gradients reach the
    field through the active samples only. With ``pad``, the compacted batch is padded
    (repeating sample 0, results discarded) to :func:`padded_size`, so that varying
    batch sizes reuse compiled kernels. Shapes: x, d Array3f (M,), mask Bool (M,)
    -> (Array3f (M,), Float (M,)) (sigma an Array3f for a field with ``sigma_channels = 3``).

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> f = lambda x, d: (mi.Array3f(1.0, 2.0, 3.0) + 0.0 * x.x, x.x + 10.0)
    >>> x, d = mi.Array3f([1.0, 2.0, 3.0], 0, 0), mi.Array3f(0, 0, 1)
    >>> rgb, sigma = eval_masked(f, x, d, mi.Bool([True, False, True]))
    >>> sigma, rgb.y
    ([11, 0, 13], [2, 0, 2])
    """
    Array3f = type(x)
    Float = type(x.x)
    UInt32 = dr.uint32_array_t(Float)
    m = dr.width(mask)
    if dr.width(d) != m:
        d = d + dr.zeros(Array3f, m)
    idx = dr.compress(mask)
    k = dr.width(idx)
    sigma = dr.zeros(Array3f if getattr(field, "sigma_channels", 1) == 3 else Float, m)  # chromatic: per colour
    rgb = dr.zeros(Array3f, m)
    if k == 0 and not pad:
        return rgb, sigma
    valid = True
    if pad and padded_size(max(k, 1)) > k:
        slot = dr.arange(UInt32, padded_size(max(k, 1)))
        valid = slot < dr.opaque(UInt32, k)  # opaque: k changes every call, the kernel must not
        # (with nothing active the field still runs on padding, so a loss keeps its gradient path)
        idx = dr.gather(UInt32, idx, slot, valid) if k else dr.zeros(UInt32, dr.width(slot))
    rgb_k, sigma_k = field(dr.gather(Array3f, x, idx), dr.gather(Array3f, d, idx))
    dr.scatter(sigma, sigma_k, idx, valid)
    dr.scatter(rgb, rgb_k, idx, valid)
    return rgb, sigma


class OccupancyMaskedField:
    """``field`` with its density set to 0 outside the grid's occupied cells.

    What a model trained with skipping actually renders (up to early stopping): the
    network is free to leave haze in skipped cells, which an export of the bare field
    would show. Callable as a field, with ``density(x)``.

    >>> import mitsuba as mi
    >>> from mitsnerf.env import set_variant; _ = set_variant("llvm_ad_rgb")
    >>> from mitsnerf.math.box import UNIT_BOX
    >>> grid = OccupancyGrid(OccupancyConfig(resolution=4, dilate=0), mi.Float, UNIT_BOX)
    >>> grid.update(lambda x: dr.select(x.x > 0.0, 5.0, 0.0) + 0.0 * x.y, seed=0, step=0)
    >>> haze = lambda x, d: (mi.Array3f(1.0) + 0.0 * x.x, mi.Float(0.1) + 0.0 * x.x)
    >>> OccupancyMaskedField(haze, grid)(mi.Array3f([-0.4, 0.4], 0.0, 0.0), mi.Array3f(0, 0, 1))[1]
    [0, 0.1]
    """

    def __init__(self, field, grid: OccupancyGrid) -> None:
        self.field = field
        self.grid = grid

    @property
    def sigma_channels(self) -> int:
        """The wrapped field's density channels (3: one per colour)."""
        return getattr(self.field, "sigma_channels", 1)

    def density(self, x):
        return dr.select(self.grid.is_occupied(x), self.field.density(x), 0.0)

    def __call__(self, x, d):
        rgb, sigma = self.field(x, d)
        return rgb, dr.select(self.grid.is_occupied(x), sigma, 0.0)
