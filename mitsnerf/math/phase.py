"""Phase functions, and what they do to radiance expanded in spherical harmonics.

Directions follow the oracle's convention: ``w`` is where light arrives *from* (a ray from ``x`` in
direction ``w`` meets it), ``d`` is a camera ray's direction. Light arriving from ``w`` travels along
``-w``; scattered towards the camera it travels along ``-d``; the scattering angle's cosine is therefore
``(-w) . (-d) = w . d``, and Henyey-Greenstein's phase function is::

    p(w . d) = (1 - g^2) / (4 pi (1 + g^2 - 2 g (w . d))^(3/2))

(Mitsuba's ``hg``: ``eval_hg(dot(wo, wi))`` with ``wi = -d`` and ``1 + g^2 + 2 g cos``, the same thing).
``g > 0`` scatters forward: a camera looking towards the sun (``d = w_sun``) sees the most. ``g = 0`` is
isotropic, ``p = 1 / (4 pi)``.

The radiance scattered towards the camera, ``c(x, d) = albedo int p(w . d) L(x, w) dw``, is a convolution on
the sphere: with ``L(x, w) = sum_lm L_lm(x) Y_lm(w)`` in orthonormal real spherical harmonics, the Funk-Hecke
theorem gives ``int p(w . d) Y_lm(w) dw = g^l Y_lm(d)`` for Henyey-Greenstein, so::

    c(x, d) = albedo sum_l sum_m g^l L_lm(x) Y_lm(d)

:func:`band_factors` gives the ``g^l`` of orders ``0..L``, times a window that tames the ringing of a
truncated series.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

FOUR_PI = 4.0 * math.pi
WINDOWS = ("none", "lanczos")


def hg(cos_theta: Any, g: float) -> Any:
    """Henyey-Greenstein's phase function at ``cos_theta = w . d`` (module docstring), for numpy arrays,
    Dr.Jit arrays and floats alike; ``g = 0`` gives ``1 / (4 pi)``.

    >>> round(hg(1.0, 0.0) * FOUR_PI, 12), round(hg(1.0, 0.5) * FOUR_PI, 6), round(hg(-1.0, 0.5) * FOUR_PI, 6)
    (1.0, 6.0, 0.222222)
    >>> t = np.linspace(-1.0, 1.0, 200001)            # normalised: 2 pi int p dt = 1
    >>> round(float(2 * np.pi * np.trapezoid(hg(t, 0.85), t)), 4)
    1.0
    """
    denom = 1.0 + g * g - 2.0 * g * cos_theta
    return (1.0 - g * g) / (FOUR_PI * denom * _sqrt(denom))


def sample_hg(d: np.ndarray, u: np.ndarray, g: float) -> np.ndarray:
    """Directions ``w`` (..., 3) distributed as Henyey-Greenstein's ``p(w . d)`` around unit directions ``d``
    (..., 3) from uniform numbers ``u`` (..., 2): the inverse of its cumulative distribution in the cosine,
    ``w . d = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g u_0))^2) / (2 g)`` (uniform for ``g = 0``), and the
    azimuth ``2 pi u_1`` about ``d``. So ``E_w[L(w)] = int p(w . d) L(w) dw`` with weight 1.

    >>> rng = np.random.default_rng(0); d = np.tile([0.0, 0.0, 1.0], (200000, 1))
    >>> w = sample_hg(d, rng.random((200000, 2)), 0.85)
    >>> round(float(scattering_cosine(w, d).mean()), 2)   # E[cos theta] = g
    0.85
    >>> bool(np.allclose(np.linalg.norm(w, axis=-1), 1.0))
    True
    """
    d = np.asarray(d, dtype=np.float64)
    u0, u1 = u[..., 0], u[..., 1]
    if g == 0.0:
        cos = 1.0 - 2.0 * u0
    else:
        cos = (1.0 + g * g - ((1.0 - g * g) / (1.0 - g + 2.0 * g * u0)) ** 2) / (2.0 * g)
    cos = np.clip(cos, -1.0, 1.0)
    sin, phi = np.sqrt(1.0 - cos * cos), 2.0 * np.pi * u1
    helper = np.where(np.abs(d[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t = np.cross(d, helper)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    b = np.cross(d, t)
    return (cos[..., None] * d + (sin * np.cos(phi))[..., None] * t + (sin * np.sin(phi))[..., None] * b)


def scattering_cosine(w: Any, d: Any) -> Any:
    """``cos theta = w . d``: the scattering angle's cosine for light arriving from ``w`` scattered towards a
    camera looking along ``d`` (module docstring); numpy arrays (last axis xyz, broadcast) or Dr.Jit vectors.

    >>> float(scattering_cosine(np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])))   # camera facing the light
    1.0
    """
    return sum(a * b for a, b in zip(_xyz(w), _xyz(d)))


def _xyz(v: Any) -> tuple[Any, Any, Any]:
    """The components of a vector: a numpy array's last axis, or a Dr.Jit Array3f's ``x, y, z``."""
    if isinstance(v, np.ndarray):
        return v[..., 0], v[..., 1], v[..., 2]
    return v.x, v.y, v.z


def _sqrt(x: Any) -> Any:
    if isinstance(x, (float, int)):
        return math.sqrt(x)
    if isinstance(x, (np.ndarray, np.floating)):
        return np.sqrt(x)
    import drjit as dr

    return dr.sqrt(x)


def band_factors(g: float, order: int, window: str = "lanczos") -> np.ndarray:
    """Per coefficient ``(order + 1)^2`` factors ``g^l h_l`` (index ``l (l + 1) + m``): Henyey-Greenstein's
    Funk-Hecke eigenvalue ``g^l`` times the window ``h_l``: ``"none"`` (1) or ``"lanczos"``, ``h_l =
    sinc(l / (order + 1))`` with ``sinc(t) = sin(pi t) / (pi t)``, which damps the highest orders to cut the
    truncated series' ringing (negative lobes) at the cost of a slightly wider lobe.

    >>> band_factors(0.5, 1, "none").tolist()
    [1.0, 0.5, 0.5, 0.5]
    >>> [round(float(v), 4) for v in band_factors(0.5, 1)]     # h_1 = sinc(1/2) = 2 / pi
    [1.0, 0.3183, 0.3183, 0.3183]
    """
    if window not in WINDOWS:
        raise ValueError(f"window: must be one of {', '.join(WINDOWS)}, got {window!r}")
    degree = np.floor(np.sqrt(np.arange((order + 1) ** 2))).astype(np.int64)
    h = np.sinc(degree / (order + 1)) if window == "lanczos" else np.ones(len(degree))
    return np.power(float(g), degree) * h
