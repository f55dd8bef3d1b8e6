"""Seeded gradient (Perlin) noise and its fractal sum (fBm), vectorised over numpy arrays.

Gradient noise at a point ``p`` in the lattice cell with corner ``c0 = floor(p)``::

    n(p) = sum_{c in corners} dot(g[h(c)], p - c) * prod_a (1 - s(|p_a - c_a|)),
    s(t) = 6 t^5 - 15 t^4 + 10 t^3            (quintic fade: n is C2)

with 256 unit gradients ``g`` drawn from the seeded generator and ``h`` a seeded permutation hash of
the integer corner, so the lattice repeats every 256 cells. ``n`` is 0 at lattice points, has
mean 0, and ``|n| <= sqrt(3) / 2`` (the bound for unit gradients in 3-D).

Fractal Brownian motion sums octaves of it::

    fbm(p) = sum_{o < O} a^o n(f L^o p + s_o) / sum_{o < O} a^o,      |fbm| <= sqrt(3) / 2

(``f`` base frequency in lattice cells per world unit, ``L`` lacunarity, ``a`` persistence, ``s_o``
a seeded shift per octave that decorrelates octaves and moves the zeros off the origin).

Inputs broadcast: passing the per-axis voxel centres of :func:`mitsnerf.volumes.base.voxel_centres`
does the hashing per axis and only the blend on the full grid.

>>> rng = np.random.default_rng(0)
>>> noise = GradientNoise(rng)
>>> float(noise(np.float32(3.0), np.float32(-7.0), np.float32(1.0)))  # a lattice point
0.0
>>> from mitsnerf.volumes.base import voxel_centres
>>> v = fbm(noise, *voxel_centres(16)[::-1], frequency=4.0, octaves=3)
>>> v.shape, v.dtype, bool(np.abs(v).max() <= 0.87)
((16, 16, 16), dtype('float32'), True)
"""

from __future__ import annotations

from typing import Any

import numpy as np

PERIOD = 256  # lattice cells after which the noise repeats
_MASK = PERIOD - 1
MAX_OCTAVES = 32
NOISE_BOUND = 0.8660254  # sqrt(3) / 2: |noise| and |fbm| never exceed it


def _fade(t: np.ndarray) -> np.ndarray:
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


class GradientNoise:
    """One seeded instance of 3-D gradient noise; call it as ``noise(x, y, z)``.

    Draws, in order, a permutation of 256, 256 unit gradients and ``MAX_OCTAVES`` octave shifts
    from ``rng``: two instances made one after the other from the same generator differ.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        perm = rng.permutation(PERIOD).astype(np.int32)
        g = rng.normal(size=(PERIOD, 3))
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        self.shifts = rng.uniform(0.0, PERIOD, size=(MAX_OCTAVES, 3)).astype(np.float32)
        # Tables doubled to length 2 * PERIOD so that perm[i] + j (i, j < PERIOD, plus a corner's 0/1)
        # needs no wrap; the last hash step folds into the gradient tables: G[i] = g[perm[i]].
        self.perm = np.tile(perm, 2)
        self.gx, self.gy, self.gz = (np.tile(g[perm, a], 2).astype(np.float32) for a in range(3))

    def __call__(self, x, y, z) -> np.ndarray:
        """Noise at points ``(x, y, z)`` (broadcastable float arrays, lattice units); float32."""
        x, y, z = (np.asarray(a, dtype=np.float32) for a in (x, y, z))
        cells, fracs = [], []
        for a in (x, y, z):
            fl = np.floor(a)
            cells.append(fl.astype(np.int32) & _MASK)
            fracs.append(a - fl)
        (ix, iy, iz), (tx, ty, tz) = cells, fracs
        u, v, w = _fade(tx), _fade(ty), _fade(tz)
        perm = self.perm
        px = (perm[ix], perm[ix + 1])
        out = None
        for dz in (0, 1):
            # blend along x then y inside this z slab, then blend the slabs along z
            rows = []
            for dy in (0, 1):
                ends = []
                for dx in (0, 1):
                    h = perm[px[dx] + iy + dy] + iz + dz
                    ends.append(self.gx[h] * (tx - dx) + self.gy[h] * (ty - dy) + self.gz[h] * (tz - dz))
                rows.append(ends[0] + u * (ends[1] - ends[0]))
            slab = rows[0] + v * (rows[1] - rows[0])
            out = slab if out is None else out + w * (slab - out)
        assert out is not None  # the loop over (0, 1) ran
        return out


def fbm(
    noise: GradientNoise,
    x,
    y,
    z,
    *,
    frequency: float,
    octaves: int,
    persistence: float = 0.5,
    lacunarity: float = 2.0,
) -> np.ndarray:
    """Normalised fractal sum of ``octaves`` octaves of ``noise`` at world points ``(x, y, z)``.

    ``fbm(p) = sum_o a^o n(f L^o p + s_o) / sum_o a^o`` (see the module docstring); float32 of the
    broadcast shape of the inputs, in ``[-sqrt(3)/2, sqrt(3)/2]``, standard deviation about 0.2.
    """
    if not 1 <= octaves <= MAX_OCTAVES:
        raise ValueError(f"octaves: must be an integer in [1, {MAX_OCTAVES}], got {octaves!r}")
    total: Any = None
    amplitude, norm, f = 1.0, 0.0, float(frequency)
    for o in range(octaves):
        s = noise.shifts[o]
        n = noise(np.float32(f) * x + s[0], np.float32(f) * y + s[1], np.float32(f) * z + s[2])
        total = n * np.float32(amplitude) if total is None else total + n * np.float32(amplitude)
        norm += amplitude
        amplitude *= persistence
        f *= lacunarity
    return total * np.float32(1.0 / norm)
