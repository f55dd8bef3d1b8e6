"""Real spherical harmonics of a unit direction, bands ``l = 0 .. L`` (``(L+1)^2`` functions).

The orthonormal real basis used by Plenoxels and instant-ngp (same signs and order)::

    Y_0     = 1 / (2 sqrt(pi))                                        l = 0
    Y_1..3  = sqrt(3 / 4pi) * (-y, z, -x)                             l = 1
    Y_4..8  = (C xy, -C yz, C' (2z^2 - x^2 - y^2), -C xz, C/2 (x^2 - y^2))   l = 2
    ...                                                               l = 3 (7 more)

with ``integral Y_i Y_j dOmega = delta_ij`` over the unit sphere. A colour is then
``c(d) = sum_k k_k Y_k(d)`` per channel (``k_k`` the coefficients), optionally through
an activation.
"""

from __future__ import annotations

from mitsnerf.math.activations import colour_bias

MAX_DEGREE = 3

_C0 = 0.28209479177387814
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (
    -0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
    -0.4570457994644658, 1.445305721320277, -0.5900435899266435,
)


def num_coefficients(degree: int) -> int:
    """``(degree + 1)^2`` basis functions for bands ``0 .. degree``.

    >>> [num_coefficients(l) for l in range(4)]
    [1, 4, 9, 16]
    """
    _check_degree(degree)
    return (degree + 1) ** 2


def colour_start(degree: int, c_max: float, c_0: float = 0.5) -> list[float]:
    """The ``3 (degree + 1)^2`` coefficients (index ``3 k + c``: basis function ``k``, channel ``c``) at which an SH
    colour ``c_max sigmoid(sum_k k_k Y_k(d))`` is ``c_0`` in every direction: band 0 at
    ``colour_bias(c_max, c_0) / Y_0``, the others 0 (all 0 at ``c_max = 1``).

    >>> [round(v, 3) for v in colour_start(0, 12.0)], colour_start(1, 1.0)[3:6]
    ([-11.115, -11.115, -11.115], [0.0, 0.0, 0.0])
    """
    return [colour_bias(c_max, c_0) / _C0] * 3 + [0.0] * (3 * num_coefficients(degree) - 3)


def _check_degree(degree: int) -> None:
    if not 0 <= degree <= MAX_DEGREE:
        raise ValueError(f"sh degree: must be in [0, {MAX_DEGREE}], got {degree}")


def sh_basis(d, degree: int) -> list:
    """The ``(degree + 1)^2`` real SH basis values at unit directions ``d``.

    Args:
        d: Array3f (M,) of unit vectors (or anything with ``.x, .y, .z`` of one Float type).
        degree: highest band L, 0 to 3.

    Returns:
        list of ``(L+1)^2`` Float (M,) (band 0 is a constant broadcast to M).

    Example (along +z only the m = 0 functions are non-zero)::

        >>> from drjit.llvm import Array3f
        >>> [round(v[0], 4) for v in sh_basis(Array3f(0.0, 0.0, 1.0), 1)]
        [0.2821, -0.0, 0.4886, -0.0]
    """
    _check_degree(degree)
    x, y, z = d.x, d.y, d.z
    out = [_C0 + 0.0 * x]
    if degree >= 1:
        out += [-_C1 * y, _C1 * z, -_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        out += [
            _C2[0] * xy,
            _C2[1] * yz,
            _C2[2] * (2.0 * zz - xx - yy),
            _C2[3] * xz,
            _C2[4] * (xx - yy),
        ]
    if degree >= 3:
        out += [
            _C3[0] * y * (3.0 * xx - yy),
            _C3[1] * xy * z,
            _C3[2] * y * (4.0 * zz - xx - yy),
            _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            _C3[4] * x * (4.0 * zz - xx - yy),
            _C3[5] * z * (xx - yy),
            _C3[6] * x * (xx - 3.0 * yy),
        ]
    return out
