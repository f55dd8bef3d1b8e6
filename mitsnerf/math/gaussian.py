"""Anisotropic kernels, Gaussian or constant-density ellipsoids: their value at a point and their closed-form
integral along a ray.

A kernel of mean ``mu``, rotation ``R`` (a unit quaternion) and scales ``s`` (standard deviations along
``R``'s columns) is, truncated to the ellipsoid shell of Mahalanobis radius ``r`` (0 outside)::

    g(x) = exp(-m^2 / 2)  where  m^2 = |M (x - mu)|^2 <= r^2,     M = S^-1 R^T  (S = diag(s))

Along a ray ``x(t) = o + t d``, with ``u = M (o - mu)`` and ``v = M d``, ``m^2`` is the quadratic
``|u + t v|^2``, smallest at ``t* = -(u . v) / a`` (``a = v . v``) where it is ``m*^2 = |u + t* v|^2``
(computed from that vector, not as ``|u|^2 - (u . v)^2 / a``, which cancels far from the kernel)::

    g(t)  = exp(-m*^2 / 2) exp(-a (t - t*)^2 / 2)       on  |t - t*| <= h,  h = sqrt((r^2 - m*^2) / a)

    int_{t0}^{t1} g dt = exp(-m*^2 / 2) sqrt(pi / (2 a)) [erf(sqrt(a/2) (hi - t*)) - erf(sqrt(a/2) (lo - t*))]

with ``lo = max(t0, t* - h)``, ``hi = min(t1, t* + h)`` (0 where ``hi <= lo``). So the optical depth a kernel of
peak density ``sigma`` adds to any ray segment is ``sigma`` times that integral: exact whatever the segment,
and consistent with ``g(x)`` at points (the same truncation).

The constant-density ellipsoid of EVER (Mai et al. 2024) in the same frame is ``e(x) = 1`` where ``m <= sqrt 5``
(0 outside): of the covariance of the Gaussian of scales ``s``, since a uniform ellipsoid of semi-axis ``A`` has
variance ``A^2 / 5`` along it. Its integral over a segment is the length of the segment inside it::

    int_{t0}^{t1} e dt = max(0, hi - lo)      (lo, hi as above with the radius sqrt 5 for the cutoff)

The functions take Dr.Jit arrays of any backend (Array3f points, rays and means, Matrix3f ``M``, Float the
rest), of one width or broadcast, and are differentiable with Dr.Jit's AD.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any

import drjit as dr


def inverse_frame(quaternion, log_scale):
    """``M = S^-1 R^T`` from a (not necessarily unit) quaternion and log scales.

    Args:
        quaternion: Array4f (N,), ``(x, y, z, w)``: the imaginary part first, as Dr.Jit's ``Quaternion4f``;
            normalised here.
        log_scale: Array3f (N,): ``log s`` along the rotated axes.

    Returns Matrix3f (N,) whose row ``i`` is ``R``'s column ``i`` over ``s_i``.

    >>> import drjit as dr
    >>> from drjit.llvm.ad import Array3f, Array4f
    >>> M = inverse_frame(Array4f(0, 0, 0, 2), Array3f(dr.log(2.0), 0, 0))  # no rotation, s = (2, 1, 1)
    >>> M[0][0], M[1][1], M[0][1]
    ([0.5], [1], [0])
    """
    module = sys.modules[type(log_scale).__module__]
    q = dr.normalize(quaternion)
    R = dr.quat_to_matrix(module.Matrix3f, module.Quaternion4f(q[0], q[1], q[2], q[3]))
    inv = dr.exp(-log_scale)
    return module.Matrix3f(*(R[j][i] * inv[i] for i in range(3) for j in range(3)))


def mahalanobis2(x, mean, M):
    """``m^2 = |M (x - mu)|^2``, Float (N,).

    >>> from drjit.llvm.ad import Array3f, Matrix3f
    >>> mahalanobis2(Array3f(1, 2, 0), Array3f(0, 0, 0), Matrix3f(1, 0, 0, 0, 0.5, 0, 0, 0, 1))
    [2]
    """
    return dr.squared_norm(M @ (x - mean))


def kernel_value(x, mean, M, cutoff: float):
    """``g(x) = exp(-m^2 / 2)`` inside the shell ``m <= cutoff``, else 0 (module docstring), Float (N,).

    >>> from drjit.llvm.ad import Array3f, Matrix3f
    >>> I = Matrix3f(1, 0, 0, 0, 1, 0, 0, 0, 1)
    >>> kernel_value(Array3f([0, 1, 4], 0, 0), Array3f(0, 0, 0), I, 3.0)  # doctest: +ELLIPSIS
    [1, 0.6065..., 0]
    """
    m2 = mahalanobis2(x, mean, M)
    return dr.select(m2 <= cutoff * cutoff, dr.exp(-0.5 * m2), 0.0)


@dataclass(frozen=True)
class RayProfile:
    """A kernel seen along a ray ``o + t d``: ``g(t) = peak exp(-a (t - t_peak)^2 / 2)`` on
    ``[t_peak - half, t_peak + half]`` (``half`` 0 where the ray misses the shell)."""

    t_peak: Any
    a: Any
    peak: Any
    """``exp(-m*^2 / 2)``: the kernel's largest value on the ray."""
    half: Any
    hit: Any
    """Whether the ray crosses the shell (``m*^2 < cutoff^2``)."""


def ray_profile(o, d, mean, M, cutoff: float) -> RayProfile:
    """The kernel's profile along rays ``o + t d`` (module docstring): ``t*``, ``a``, ``exp(-m*^2/2)``, ``h``.

    >>> from drjit.llvm.ad import Array3f, Matrix3f
    >>> I = Matrix3f(1, 0, 0, 0, 1, 0, 0, 0, 1)
    >>> p = ray_profile(Array3f(0, 1, -5), Array3f(0, 0, 1), Array3f(0, 0, 0), I, 3.0)
    >>> p.t_peak, p.a, p.peak, p.half  # doctest: +ELLIPSIS
    ([5], [1], [0.6065...], [2.8284...])
    """
    u = M @ (o - mean)
    v = M @ d
    a = dr.squared_norm(v)
    t_peak = -dr.dot(u, v) / a
    m2 = dr.squared_norm(dr.fma(v, t_peak, u))
    r2 = cutoff * cutoff
    hit = m2 < r2
    half = dr.select(hit, dr.sqrt(dr.maximum(r2 - m2, 0.0) / a), 0.0)
    return RayProfile(t_peak, a, dr.exp(-0.5 * m2), half, hit)


def segment_integral(profile: RayProfile, t0, t1):
    """``int_{t0}^{t1} g(o + t d) dt`` in closed form (module docstring), Float (N,): 0 where the segment and the
    shell do not overlap.

    Example: a unit kernel on the ray through its centre integrates to ``sqrt(2 pi) erf(3 / sqrt 2)`` over its
    whole shell, and half of it up to the centre::

        >>> import math
        >>> from drjit.llvm.ad import Array3f, Matrix3f, Float
        >>> I = Matrix3f(1, 0, 0, 0, 1, 0, 0, 0, 1)
        >>> p = ray_profile(Array3f(0, 0, -5), Array3f(0, 0, 1), Array3f(0, 0, 0), I, 3.0)
        >>> segment_integral(p, Float(0.0, 0.0), Float(10.0, 5.0))  # doctest: +ELLIPSIS
        [2.499..., 1.249...]
        >>> round(math.sqrt(2 * math.pi) * math.erf(3 / math.sqrt(2)), 4)
        2.4999
    """
    lo = dr.maximum(t0, profile.t_peak - profile.half)
    hi = dr.minimum(t1, profile.t_peak + profile.half)
    k = dr.sqrt(0.5 * profile.a)
    width = dr.erf(k * (hi - profile.t_peak)) - dr.erf(k * (lo - profile.t_peak))
    value = profile.peak * (0.5 * math.sqrt(math.pi)) / k * width
    return dr.select(profile.hit & (hi > lo), value, 0.0)


#: Mahalanobis radius of the constant-density ellipsoid whose covariance is the Gaussian's of the same scales.
ELLIPSOID_RADIUS = math.sqrt(5.0)


def ellipsoid_value(x, mean, M):
    """``e(x)``: 1 inside the ellipsoid ``|M (x - mu)| <= sqrt 5``, else 0, Float (N,).

    >>> from drjit.llvm.ad import Array3f, Matrix3f
    >>> ellipsoid_value(Array3f([0, 2.2, 2.3], 0, 0), Array3f(0, 0, 0), Matrix3f(1, 0, 0, 0, 1, 0, 0, 0, 1))
    [1, 1, 0]
    """
    return dr.select(mahalanobis2(x, mean, M) <= 5.0, 1.0, 0.0)


def segment_length(profile: RayProfile, t0, t1):
    """``int_{t0}^{t1} e dt``: the length of the segment inside the ellipsoid (``profile`` from :func:`ray_profile`
    with the cutoff :data:`ELLIPSOID_RADIUS`), Float (N,).

    >>> from drjit.llvm.ad import Array3f, Matrix3f, Float
    >>> I = Matrix3f(1, 0, 0, 0, 1, 0, 0, 0, 1)
    >>> p = ray_profile(Array3f(0, 0, -5), Array3f(0, 0, 1), Array3f(0, 0, 0), I, ELLIPSOID_RADIUS)
    >>> segment_length(p, Float(0.0, 0.0), Float(10.0, 5.0))  # doctest: +ELLIPSIS
    [4.4721..., 2.2360...]
    """
    lo = dr.maximum(t0, profile.t_peak - profile.half)
    hi = dr.minimum(t1, profile.t_peak + profile.half)
    return dr.select(profile.hit, dr.maximum(hi - lo, 0.0), 0.0)


def full_integral(log_scale_max, cutoff: float) -> float:
    """The largest integral of a kernel along any ray, as a Python float: through its centre along its
    longest axis, ``sqrt(2 pi) s_max erf(cutoff / sqrt 2)``; ``log_scale_max``: ``log s_max`` (a float).

    >>> round(full_integral(0.0, 3.0), 4)
    2.4999
    """
    return math.sqrt(2.0 * math.pi) * math.exp(log_scale_max) * math.erf(cutoff / math.sqrt(2.0))
